//! Ethernet/UDP framing of FireWire packets (reference §3.1).
//!
//! ```text
//! host -> FPGA : control[0] = flags (bit 0 NOFORWARD) | control[1] = host bus generation | request
//! FPGA -> host : response | 8 bytes extra data
//! extra data   : [0] flags  [1] FPGA bus generation  [2] reserved  [3] packet-error count
//!                [4..6] receive time (sysclk ticks, BE)  [6..8] total time (sysclk ticks, BE)
//! ```
//! A reply of only the 8 extra-data bytes means the packet was dropped (§3.1).

use super::WireError;
use super::firewire::{Packet, RequestRepr, ResponseRepr};

/// Length of the control word before a request (reference §3.1).
pub const CONTROL_LEN: usize = 2;
/// Length of the extra data after a response (reference §3.1).
pub const EXTRA_LEN: usize = 8;
/// Control-word flag: handle locally, do not forward to FireWire (reference §3.1).
pub const CONTROL_NOFORWARD: u8 = 0x01;

/// Extra-data flag bits (reference §3.1, "Extra data" table).
pub mod extra_flags {
    /// FireWire bus reset in progress.
    pub const BUS_RESET: u8 = 0x01;
    /// The request was dropped (bus reset, or generation mismatch on a forwarded packet).
    pub const PACKET_DROPPED: u8 = 0x02;
    /// FPGA internal error.
    pub const INTERNAL_ERROR: u8 = 0x04;
    /// Summary of Ethernet errors.
    pub const ETH_ERROR: u8 = 0x08;
    /// The request carried NOFORWARD.
    pub const NOFORWARD: u8 = 0x10;
    /// Ethernet port the request arrived on (2 bits).
    pub const SOURCE_PORT_MASK: u8 = 0x60;
}

/// The 2 bytes the host puts before every request.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ControlWord {
    pub flags: u8,
    /// The host's idea of the FireWire bus generation.
    pub bus_generation: u8,
}

impl ControlWord {
    pub const fn new(noforward: bool, bus_generation: u8) -> Self {
        Self {
            flags: if noforward { CONTROL_NOFORWARD } else { 0 },
            bus_generation,
        }
    }
    pub const fn noforward(&self) -> bool {
        self.flags & CONTROL_NOFORWARD != 0
    }
    pub fn parse(buf: &[u8]) -> Result<Self, WireError> {
        match buf {
            [flags, bus_generation, ..] => Ok(Self {
                flags: *flags,
                bus_generation: *bus_generation,
            }),
            _ => Err(WireError::Truncated {
                got: buf.len(),
                need: CONTROL_LEN,
            }),
        }
    }
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        match buf {
            [a, b, ..] => {
                *a = self.flags;
                *b = self.bus_generation;
                Ok(CONTROL_LEN)
            }
            _ => Err(WireError::BufferTooSmall {
                got: buf.len(),
                need: CONTROL_LEN,
            }),
        }
    }
}

/// The 8 bytes the FPGA appends to every response.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExtraData {
    pub flags: u8,
    /// The FPGA's FireWire bus generation.
    pub bus_generation: u8,
    /// Byte 2, not documented; kept so that emit(parse(x)) == x.
    pub reserved: u8,
    pub error_count: u8,
    pub receive_time_ticks: u16,
    pub total_time_ticks: u16,
}

impl ExtraData {
    /// Parses exactly the first 8 bytes of `buf`.
    pub fn parse(buf: &[u8]) -> Result<Self, WireError> {
        match buf {
            [f, g, r, e, rt0, rt1, tt0, tt1, ..] => Ok(Self {
                flags: *f,
                bus_generation: *g,
                reserved: *r,
                error_count: *e,
                receive_time_ticks: u16::from_be_bytes([*rt0, *rt1]),
                total_time_ticks: u16::from_be_bytes([*tt0, *tt1]),
            }),
            _ => Err(WireError::Truncated {
                got: buf.len(),
                need: EXTRA_LEN,
            }),
        }
    }
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, WireError> {
        let got = buf.len();
        let Some(out) = buf.get_mut(..EXTRA_LEN) else {
            return Err(WireError::BufferTooSmall {
                got,
                need: EXTRA_LEN,
            });
        };
        let r = self.receive_time_ticks.to_be_bytes();
        let t = self.total_time_ticks.to_be_bytes();
        out.copy_from_slice(&[
            self.flags,
            self.bus_generation,
            self.reserved,
            self.error_count,
            r[0],
            r[1],
            t[0],
            t[1],
        ]);
        Ok(EXTRA_LEN)
    }
    pub const fn bus_reset(&self) -> bool {
        self.flags & extra_flags::BUS_RESET != 0
    }
    pub const fn packet_dropped(&self) -> bool {
        self.flags & extra_flags::PACKET_DROPPED != 0
    }
    pub const fn internal_error(&self) -> bool {
        self.flags & extra_flags::INTERNAL_ERROR != 0
    }
    pub const fn ethernet_error(&self) -> bool {
        self.flags & extra_flags::ETH_ERROR != 0
    }
    pub const fn noforward(&self) -> bool {
        self.flags & extra_flags::NOFORWARD != 0
    }
    pub const fn source_port(&self) -> u8 {
        (self.flags & extra_flags::SOURCE_PORT_MASK) >> 5
    }
}

/// Checked view of a host-to-FPGA datagram: control word, then a FireWire request.
#[derive(Clone, Copy, Debug)]
pub struct EthRequest<'a> {
    pub control: ControlWord,
    pub packet: Packet<&'a [u8]>,
}

impl<'a> EthRequest<'a> {
    /// Parses the control word and checks the FireWire packet after it. Trailing bytes after
    /// the packet are reported by [`EthRequest::trailing`].
    pub fn parse(datagram: &'a [u8]) -> Result<Self, WireError> {
        let control = ControlWord::parse(datagram)?;
        let rest = datagram.get(CONTROL_LEN..).unwrap_or(&[]);
        let packet = Packet::new_checked(rest)?;
        Ok(Self { control, packet })
    }
    /// Bytes after the FireWire packet (0 for a well-formed request).
    pub fn trailing(&self) -> usize {
        self.packet.into_inner().len() - self.packet.total_len()
    }
    /// Writes control word + request into `buf`; returns the datagram length.
    pub fn emit(
        buf: &mut [u8],
        control: ControlWord,
        req: &RequestRepr,
        payload: &[u8],
    ) -> Result<usize, WireError> {
        let got = buf.len();
        let need = CONTROL_LEN + req.buffer_len();
        if got < need {
            return Err(WireError::BufferTooSmall { got, need });
        }
        control.emit(buf)?;
        let n = req.emit(buf.get_mut(CONTROL_LEN..).unwrap_or(&mut []), payload)?;
        Ok(CONTROL_LEN + n)
    }
}

/// Checked view of an FPGA-to-host datagram: a FireWire response (absent when the FPGA
/// dropped the request) followed by the extra data.
#[derive(Clone, Copy, Debug)]
pub struct EthReply<'a> {
    /// `None` for an 8-byte reply: the request was dropped (§3.1).
    pub packet: Option<Packet<&'a [u8]>>,
    pub extra: ExtraData,
    /// Bytes between the end of the FireWire packet and the extra data (0 when well formed).
    pub excess: usize,
}

impl<'a> EthReply<'a> {
    /// Splits off the last 8 bytes as extra data and checks the FireWire packet before them.
    pub fn parse(datagram: &'a [u8]) -> Result<Self, WireError> {
        let len = datagram.len();
        if len < EXTRA_LEN {
            return Err(WireError::Truncated {
                got: len,
                need: EXTRA_LEN,
            });
        }
        let (fw, extra) = datagram.split_at(len - EXTRA_LEN);
        let extra = ExtraData::parse(extra)?;
        if fw.is_empty() {
            return Ok(Self {
                packet: None,
                extra,
                excess: 0,
            });
        }
        let packet = Packet::new_checked(fw).map_err(|e| match e {
            WireError::Truncated { got, need } => WireError::Truncated {
                got: got + EXTRA_LEN,
                need: need + EXTRA_LEN,
            },
            e => e,
        })?;
        Ok(Self {
            packet: Some(packet),
            extra,
            excess: fw.len() - packet.total_len(),
        })
    }
    /// Writes response + extra data into `buf`; returns the datagram length.
    pub fn emit(
        buf: &mut [u8],
        resp: &ResponseRepr,
        payload: &[u8],
        extra: &ExtraData,
    ) -> Result<usize, WireError> {
        let got = buf.len();
        let need = resp.buffer_len() + EXTRA_LEN;
        if got < need {
            return Err(WireError::BufferTooSmall { got, need });
        }
        let n = resp.emit(buf, payload)?;
        extra.emit(buf.get_mut(n..).unwrap_or(&mut []))?;
        Ok(n + EXTRA_LEN)
    }
    /// Writes the 8-byte "dropped" reply (extra data only).
    pub fn emit_dropped(buf: &mut [u8], extra: &ExtraData) -> Result<usize, WireError> {
        extra.emit(buf)
    }
}

#[cfg(test)]
mod tests {
    use super::super::firewire::{RequestKind, ResponseKind, Tcode};
    use super::*;

    /// Reference §9, datagram 1 exactly as the dVRK host library sent it (label 1, see
    /// firewire.rs tests).
    static DISCOVERY_WRITE: [u8; 22] = [
        0x01, 0x00, 0xff, 0xff, 0x04, 0x00, 0xff, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x00, 0x0b, 0x01,
        0x00, 0x00, 0x7f, 0x11, 0xc0, 0x36, 0xd8,
    ];
    /// Reference §9, datagram 2.
    static DISCOVERY_READ: [u8; 18] = [
        0x01, 0x00, 0xff, 0xff, 0x08, 0x40, 0xff, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04, 0x58,
        0xff, 0xb1, 0x82,
    ];
    /// Extra data: NOFORWARD echoed, source port 1, generation 3, 2 errors, times 0x0102/0x0304.
    static EXTRA: [u8; 8] = [0x30, 0x03, 0x00, 0x02, 0x01, 0x02, 0x03, 0x04];

    #[test]
    fn deconstruct_discovery_datagrams() {
        let r = EthRequest::parse(&DISCOVERY_WRITE).unwrap();
        assert!(r.control.noforward());
        assert_eq!(r.control.bus_generation, 0);
        assert_eq!(r.packet.tcode(), Tcode::QuadletWrite);
        assert_eq!(r.packet.offset(), 11);
        assert_eq!(r.packet.quadlet_data(), 0x0100_007F);
        assert_eq!(r.packet.label(), 1);
        assert_eq!(r.trailing(), 0);
        let r = EthRequest::parse(&DISCOVERY_READ).unwrap();
        assert_eq!(r.packet.tcode(), Tcode::QuadletRead);
        assert_eq!(r.packet.label(), 2);
    }

    #[test]
    fn construct_discovery_datagrams() {
        let mut buf = [0u8; 64];
        let req = RequestRepr::host(0x3F, 1, 11, RequestKind::QuadletWrite { data: 0x0100_007F });
        let n = EthRequest::emit(&mut buf, ControlWord::new(true, 0), &req, &[]).unwrap();
        assert_eq!(&buf[..n], &DISCOVERY_WRITE[..]);
        let req = RequestRepr::host(0x3F, 2, 4, RequestKind::QuadletRead);
        let n = EthRequest::emit(&mut buf, ControlWord::new(true, 0), &req, &[]).unwrap();
        assert_eq!(&buf[..n], &DISCOVERY_READ[..]);
    }

    #[test]
    fn extra_data_round_trip() {
        let e = ExtraData::parse(&EXTRA).unwrap();
        assert_eq!(e.bus_generation, 3);
        assert_eq!(e.error_count, 2);
        assert_eq!(e.receive_time_ticks, 0x0102);
        assert_eq!(e.total_time_ticks, 0x0304);
        assert!(
            e.noforward()
                && !e.packet_dropped()
                && !e.bus_reset()
                && !e.internal_error()
                && !e.ethernet_error()
        );
        assert_eq!(e.source_port(), 1);
        let mut out = [0u8; 8];
        e.emit(&mut out).unwrap();
        assert_eq!(out, EXTRA);
    }

    #[test]
    fn reply_round_trip_and_dropped() {
        let resp = ResponseRepr {
            dest_id: 0xFFD0,
            src_id: 0xFFC6,
            label: 3,
            rcode: 0,
            kind: ResponseKind::Quadlet { data: 7 },
        };
        let extra = ExtraData::parse(&EXTRA).unwrap();
        let mut buf = [0u8; 64];
        let n = EthReply::emit(&mut buf, &resp, &[], &extra).unwrap();
        assert_eq!(n, 28);
        let r = EthReply::parse(&buf[..n]).unwrap();
        assert_eq!(ResponseRepr::parse(&r.packet.unwrap()).unwrap(), resp);
        assert_eq!(r.extra, extra);
        assert_eq!(r.excess, 0);

        let dropped = ExtraData {
            flags: extra_flags::PACKET_DROPPED,
            ..Default::default()
        };
        let n = EthReply::emit_dropped(&mut buf, &dropped).unwrap();
        let r = EthReply::parse(&buf[..n]).unwrap();
        assert!(r.packet.is_none());
        assert!(r.extra.packet_dropped());
    }

    #[test]
    fn reply_errors() {
        assert_eq!(
            EthReply::parse(&[0; 7]).unwrap_err(),
            WireError::Truncated { got: 7, need: 8 }
        );
        // 12 bytes: 4 of FireWire + 8 extra.
        assert_eq!(
            EthReply::parse(&[0; 12]).unwrap_err(),
            WireError::Truncated { got: 12, need: 24 }
        );
        assert_eq!(
            ControlWord::parse(&[1]).unwrap_err(),
            WireError::Truncated { got: 1, need: 2 }
        );
        assert_eq!(
            EthRequest::parse(&DISCOVERY_READ[..10]).unwrap_err(),
            WireError::Truncated { got: 8, need: 16 }
        );
    }
}
