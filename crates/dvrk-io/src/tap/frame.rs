//! Checked parsing of captured frames down to one UDP datagram: Ethernet II (with at most one
//! 802.1Q tag) or a cooked capture that starts at the IPv4 header (Linux `AF_PACKET` with
//! `SOCK_DGRAM`). Only unfragmented IPv4/UDP is accepted; everything else is a [`Skip`] reason,
//! never a panic.

use std::net::{Ipv4Addr, SocketAddrV4};

/// What a captured frame starts with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkType {
    /// Ethernet II header (14 bytes, or 18 with an 802.1Q tag): pcap `DLT_EN10MB`, or
    /// `AF_PACKET`/`SOCK_RAW` on an Ethernet or loopback device.
    Ethernet,
    /// The IPv4 header directly (`AF_PACKET`/`SOCK_DGRAM`, pcap `DLT_RAW`).
    Ip,
}

/// Why a frame was not turned into a datagram (normal traffic such as ARP lands here too).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Skip {
    /// Shorter than its headers say.
    Truncated,
    /// Not IPv4 (EtherType, or IP version).
    NotIpv4,
    /// IPv4 but not UDP.
    NotUdp,
    /// An IP fragment (the boards' datagrams fit in one frame, reference §3.1).
    Fragment,
    /// A UDP datagram to and from ports other than the boards' port.
    OtherPort,
    /// A board datagram that did not parse as a request or a reply.
    Malformed,
    /// A reply that no captured request explains (e.g. the capture started mid-transaction).
    Unpaired,
    /// A well-formed transaction that carries no feedback data (quadlet reads, writes).
    NoFeedback,
}

/// One UDP datagram of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Datagram<'a> {
    pub src: SocketAddrV4,
    pub dst: SocketAddrV4,
    pub payload: &'a [u8],
}

const ETHERTYPE_IPV4: u16 = 0x0800;
const ETHERTYPE_VLAN: u16 = 0x8100;
const IPPROTO_UDP: u8 = 17;

fn be16(b: &[u8], off: usize) -> Option<u16> {
    match b.get(off..off.checked_add(2)?) {
        Some(&[x, y]) => Some(u16::from_be_bytes([x, y])),
        _ => None,
    }
}

/// The UDP datagram in `frame`.
pub fn parse_frame(frame: &[u8], link: LinkType) -> Result<Datagram<'_>, Skip> {
    let ip = match link {
        LinkType::Ip => frame,
        LinkType::Ethernet => {
            let mut ethertype = be16(frame, 12).ok_or(Skip::Truncated)?;
            let mut off = 14;
            if ethertype == ETHERTYPE_VLAN {
                ethertype = be16(frame, 16).ok_or(Skip::Truncated)?;
                off = 18;
            }
            if ethertype != ETHERTYPE_IPV4 {
                return Err(Skip::NotIpv4);
            }
            frame.get(off..).ok_or(Skip::Truncated)?
        }
    };
    let &v_ihl = ip.first().ok_or(Skip::Truncated)?;
    if v_ihl >> 4 != 4 {
        return Err(Skip::NotIpv4);
    }
    let ihl = usize::from(v_ihl & 0x0F) * 4;
    if ihl < 20 || ip.len() < ihl {
        return Err(Skip::Truncated);
    }
    let total = usize::from(be16(ip, 2).ok_or(Skip::Truncated)?);
    if total < ihl || total > ip.len() {
        return Err(Skip::Truncated);
    }
    let frag = be16(ip, 6).ok_or(Skip::Truncated)?;
    // More-fragments flag or a nonzero fragment offset.
    if frag & 0x3FFF != 0 {
        return Err(Skip::Fragment);
    }
    if ip.get(9) != Some(&IPPROTO_UDP) {
        return Err(Skip::NotUdp);
    }
    let addr = |off: usize| -> Option<Ipv4Addr> {
        let b = ip.get(off..off + 4)?;
        Some(Ipv4Addr::new(b[0], b[1], b[2], b[3]))
    };
    let (src_ip, dst_ip) = (
        addr(12).ok_or(Skip::Truncated)?,
        addr(16).ok_or(Skip::Truncated)?,
    );
    let udp = ip.get(ihl..total).ok_or(Skip::Truncated)?;
    let src_port = be16(udp, 0).ok_or(Skip::Truncated)?;
    let dst_port = be16(udp, 2).ok_or(Skip::Truncated)?;
    let udp_len = usize::from(be16(udp, 4).ok_or(Skip::Truncated)?);
    if udp_len < 8 || udp_len > udp.len() {
        return Err(Skip::Truncated);
    }
    Ok(Datagram {
        src: SocketAddrV4::new(src_ip, src_port),
        dst: SocketAddrV4::new(dst_ip, dst_port),
        payload: udp.get(8..udp_len).ok_or(Skip::Truncated)?,
    })
}

/// Builds an IPv4/UDP packet (no options, checksums 0 = "none" for UDP) around `payload`
/// into `buf`, optionally behind an Ethernet II header; returns its length. For tests and
/// for recording frames; `None` when `buf` is too small or the payload too long.
pub fn emit_frame(
    buf: &mut [u8],
    link: LinkType,
    src: SocketAddrV4,
    dst: SocketAddrV4,
    payload: &[u8],
) -> Option<usize> {
    let l2 = match link {
        LinkType::Ethernet => 14,
        LinkType::Ip => 0,
    };
    let total = 20 + 8 + payload.len();
    let total16 = u16::try_from(total).ok()?;
    let out = buf.get_mut(..l2 + total)?;
    if l2 > 0 {
        out[..12].fill(0);
        out[12..14].copy_from_slice(&ETHERTYPE_IPV4.to_be_bytes());
    }
    let ip = &mut out[l2..];
    ip[0] = 0x45;
    ip[1] = 0;
    ip[2..4].copy_from_slice(&total16.to_be_bytes());
    ip[4..8].fill(0);
    ip[8] = 64;
    ip[9] = IPPROTO_UDP;
    ip[10..12].fill(0);
    ip[12..16].copy_from_slice(&src.ip().octets());
    ip[16..20].copy_from_slice(&dst.ip().octets());
    let mut sum: u32 = 0;
    for k in (0..20).step_by(2) {
        sum += u32::from(u16::from_be_bytes([ip[k], ip[k + 1]]));
    }
    while sum > 0xFFFF {
        sum = (sum & 0xFFFF) + (sum >> 16);
    }
    ip[10..12].copy_from_slice(&(!(sum as u16)).to_be_bytes());
    let udp = &mut ip[20..];
    udp[0..2].copy_from_slice(&src.port().to_be_bytes());
    udp[2..4].copy_from_slice(&dst.port().to_be_bytes());
    udp[4..6].copy_from_slice(&((8 + payload.len()) as u16).to_be_bytes());
    udp[6..8].fill(0);
    udp[8..].copy_from_slice(payload);
    Some(l2 + total)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn a(s: &str) -> SocketAddrV4 {
        s.parse().unwrap()
    }

    #[test]
    fn round_trip_both_link_types() {
        for link in [LinkType::Ethernet, LinkType::Ip] {
            let mut buf = [0u8; 128];
            let n = emit_frame(
                &mut buf,
                link,
                a("127.0.0.1:40000"),
                a("127.0.0.7:1394"),
                b"hello",
            )
            .unwrap();
            let d = parse_frame(&buf[..n], link).unwrap();
            assert_eq!(d.src, a("127.0.0.1:40000"));
            assert_eq!(d.dst, a("127.0.0.7:1394"));
            assert_eq!(d.payload, b"hello");
        }
    }

    #[test]
    fn every_truncation_is_a_skip_not_a_panic() {
        let mut buf = [0u8; 128];
        let n = emit_frame(
            &mut buf,
            LinkType::Ethernet,
            a("1.2.3.4:5"),
            a("6.7.8.9:1394"),
            &[1, 2, 3, 4],
        )
        .unwrap();
        for cut in 0..n {
            assert!(
                parse_frame(&buf[..cut], LinkType::Ethernet).is_err(),
                "cut {cut}"
            );
        }
    }

    #[test]
    fn non_udp_non_ipv4_and_fragments_are_named() {
        let mut buf = [0u8; 64];
        let n = emit_frame(
            &mut buf,
            LinkType::Ethernet,
            a("1.2.3.4:5"),
            a("6.7.8.9:1394"),
            &[],
        )
        .unwrap();
        let mut arp = buf;
        arp[12..14].copy_from_slice(&0x0806u16.to_be_bytes());
        assert_eq!(
            parse_frame(&arp[..n], LinkType::Ethernet),
            Err(Skip::NotIpv4)
        );
        let mut tcp = buf;
        tcp[14 + 9] = 6;
        assert_eq!(
            parse_frame(&tcp[..n], LinkType::Ethernet),
            Err(Skip::NotUdp)
        );
        let mut frag = buf;
        frag[14 + 6] = 0x20; // more fragments
        assert_eq!(
            parse_frame(&frag[..n], LinkType::Ethernet),
            Err(Skip::Fragment)
        );
    }
}
