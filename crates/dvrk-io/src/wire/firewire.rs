//! Asynchronous FireWire packets as the dVRK sends them (reference §1.1 and §3.1).
//!
//! ```text
//! request  q0 = dest_id[31:16] | tl[15:10] | rt[9:8] | tcode[7:4] | pri[3:0]
//!          q1 = src_id[31:16]  | offset[47:32]
//!          q2 = offset[31:0]
//!          quadlet read   (16 B): q3 = header CRC
//!          quadlet write  (20 B): q3 = data, q4 = header CRC
//!          block read     (20 B): q3 = data_length<<16 | extended tcode, q4 = header CRC
//!          block write         : as block read, then data (padded to quadlets), data CRC
//! response q0 as request; q1 = src_id[31:16] | rcode[15:12]; q2 = reserved
//!          quadlet response (20 B): q3 = data, q4 = header CRC
//!          block response        : q3 = data_length<<16, q4 = header CRC, data, data CRC
//! ```
//! The header CRC covers every header quadlet before it (the quadlet-write data too, §9).
//! A node id is bus\[15:6\] | node\[5:0\]; the FPGA requires bus = 0x3FF (§3.1).

use super::{WireError, crc32_bzip2, get_be32, pad4, put_be32};

/// Local-bus part of a node id: bus number 0x3FF (reference §3.1).
pub const LOCAL_BUS: u16 = 0xFFC0;
/// Broadcast node number (reference §1.1, "over Ethernet the real node 0x3F is used").
pub const BROADCAST_NODE: u8 = 0x3F;
/// Source id the dVRK host puts in q1 of its requests (reference §3.1: q1 = 0xFFD0<<16 | ...).
pub const HOST_SOURCE_ID: u16 = 0xFFD0;
/// Largest block payload a FireWire packet carries here: 2048 − 24 bytes (reference §1.1).
pub const MAX_BLOCK_BYTES: usize = 2048 - 24;
/// Transaction labels are 6 bits (reference §3.1).
pub const LABEL_MASK: u8 = 0x3F;

/// Node id on the local bus for a 6-bit node number.
#[inline]
pub const fn node_id(node: u8) -> u16 {
    LOCAL_BUS | (node & 0x3F) as u16
}

/// Transaction codes used by the boards (reference §1.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Tcode {
    QuadletWrite = 0,
    BlockWrite = 1,
    QuadletRead = 4,
    BlockRead = 5,
    QuadletResponse = 6,
    BlockResponse = 7,
}

impl Tcode {
    /// Decodes a 4-bit tcode.
    pub const fn from_u8(v: u8) -> Result<Self, WireError> {
        Ok(match v {
            0 => Self::QuadletWrite,
            1 => Self::BlockWrite,
            4 => Self::QuadletRead,
            5 => Self::BlockRead,
            6 => Self::QuadletResponse,
            7 => Self::BlockResponse,
            tcode => return Err(WireError::UnknownTcode { tcode }),
        })
    }

    /// Bytes of header including the header CRC.
    pub const fn header_len(self) -> usize {
        match self {
            Self::QuadletRead => 16,
            _ => 20,
        }
    }

    /// True for the kinds followed by a data block and a data CRC.
    pub const fn has_block_data(self) -> bool {
        matches!(self, Self::BlockWrite | Self::BlockResponse)
    }

    /// True for responses (6, 7).
    pub const fn is_response(self) -> bool {
        matches!(self, Self::QuadletResponse | Self::BlockResponse)
    }
}

/// Checked view of one FireWire asynchronous packet.
#[derive(Clone, Copy, Debug)]
pub struct Packet<T: AsRef<[u8]>> {
    buf: T,
    tcode: Tcode,
    total_len: usize,
}

impl<T: AsRef<[u8]>> Packet<T> {
    /// Validates the tcode and that the buffer holds the whole packet (header, and for block
    /// write/response the data length given in q3, padded to quadlets, plus the data CRC).
    /// Extra trailing bytes are allowed; [`Packet::total_len`] says where the packet ends.
    pub fn new_checked(buf: T) -> Result<Self, WireError> {
        let b = buf.as_ref();
        let got = b.len();
        if got < 16 {
            return Err(WireError::Truncated { got, need: 16 });
        }
        let tcode = Tcode::from_u8((b[3] >> 4) & 0x0F)?;
        let mut need = tcode.header_len();
        if got < need {
            return Err(WireError::Truncated { got, need });
        }
        if tcode.has_block_data() {
            need += pad4((get_be32(b, 12) >> 16) as usize) + 4;
            if got < need {
                return Err(WireError::Truncated { got, need });
            }
        }
        Ok(Self {
            buf,
            tcode,
            total_len: need,
        })
    }

    #[inline]
    fn q(&self, i: usize) -> u32 {
        get_be32(self.buf.as_ref(), i * 4)
    }

    pub fn tcode(&self) -> Tcode {
        self.tcode
    }
    /// Destination node id (bus and node).
    pub fn dest_id(&self) -> u16 {
        (self.q(0) >> 16) as u16
    }
    /// Destination node number (6 bits).
    pub fn dest_node(&self) -> u8 {
        (self.q(0) >> 16) as u8 & 0x3F
    }
    /// Transaction label (6 bits).
    pub fn label(&self) -> u8 {
        (self.q(0) >> 10) as u8 & LABEL_MASK
    }
    /// Retry code (2 bits).
    pub fn retry(&self) -> u8 {
        (self.q(0) >> 8) as u8 & 0x3
    }
    /// Priority (4 bits).
    pub fn priority(&self) -> u8 {
        self.q(0) as u8 & 0x0F
    }
    /// Source node id (bus and node).
    pub fn src_id(&self) -> u16 {
        (self.q(1) >> 16) as u16
    }
    /// Source node number (6 bits).
    pub fn src_node(&self) -> u8 {
        (self.q(1) >> 16) as u8 & 0x3F
    }
    /// 48-bit destination offset (requests).
    pub fn offset(&self) -> u64 {
        (u64::from(self.q(1) & 0xFFFF) << 32) | u64::from(self.q(2))
    }
    /// Response code (responses; 0 = complete).
    pub fn rcode(&self) -> u8 {
        (self.q(1) >> 12) as u8 & 0x0F
    }
    /// q3: the data of a quadlet write or quadlet response.
    pub fn quadlet_data(&self) -> u32 {
        match self.tcode {
            Tcode::QuadletWrite | Tcode::QuadletResponse => self.q(3),
            _ => 0,
        }
    }
    /// Data length in bytes of block read/write/response (q3 bits 31–16).
    pub fn data_length(&self) -> u16 {
        match self.tcode {
            Tcode::BlockRead | Tcode::BlockWrite | Tcode::BlockResponse => (self.q(3) >> 16) as u16,
            _ => 0,
        }
    }
    /// Extended tcode of block packets (q3 bits 15–0).
    pub fn extended_tcode(&self) -> u16 {
        match self.tcode {
            Tcode::BlockRead | Tcode::BlockWrite | Tcode::BlockResponse => self.q(3) as u16,
            _ => 0,
        }
    }
    /// Header CRC as carried (the FPGA sends 0 in its responses, §3.1).
    pub fn header_crc(&self) -> u32 {
        get_be32(self.buf.as_ref(), self.tcode.header_len() - 4)
    }
    /// Header CRC computed over the header quadlets.
    pub fn computed_header_crc(&self) -> u32 {
        let b = self.buf.as_ref();
        b.get(..self.tcode.header_len() - 4).map_or(0, crc32_bzip2)
    }
    /// Block data (block write/response); empty for the other kinds.
    pub fn payload(&self) -> &[u8] {
        if !self.tcode.has_block_data() {
            return &[];
        }
        let start = self.tcode.header_len();
        let len = self.data_length() as usize;
        self.buf.as_ref().get(start..start + len).unwrap_or(&[])
    }
    /// Data CRC as carried (block write/response); 0 for the other kinds.
    pub fn data_crc(&self) -> u32 {
        if self.tcode.has_block_data() {
            get_be32(self.buf.as_ref(), self.total_len - 4)
        } else {
            0
        }
    }
    /// Data CRC computed over the padded data.
    pub fn computed_data_crc(&self) -> u32 {
        if !self.tcode.has_block_data() {
            return 0;
        }
        let start = self.tcode.header_len();
        self.buf
            .as_ref()
            .get(start..self.total_len - 4)
            .map_or(0, crc32_bzip2)
    }
    /// Bytes the packet occupies (header, data, data CRC).
    pub fn total_len(&self) -> usize {
        self.total_len
    }
    /// The packet's own bytes, without anything after it.
    pub fn as_bytes(&self) -> &[u8] {
        let b = self.buf.as_ref();
        b.get(..self.total_len).unwrap_or(b)
    }
    pub fn into_inner(self) -> T {
        self.buf
    }
}

/// What a request asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RequestKind {
    QuadletRead,
    QuadletWrite {
        data: u32,
    },
    /// Block read of `len` bytes.
    BlockRead {
        len: u16,
    },
    /// Block write of `len` bytes (the data is passed to `emit` separately).
    BlockWrite {
        len: u16,
    },
}

impl RequestKind {
    pub const fn tcode(self) -> Tcode {
        match self {
            Self::QuadletRead => Tcode::QuadletRead,
            Self::QuadletWrite { .. } => Tcode::QuadletWrite,
            Self::BlockRead { .. } => Tcode::BlockRead,
            Self::BlockWrite { .. } => Tcode::BlockWrite,
        }
    }
}

/// High-level form of a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RequestRepr {
    pub dest_id: u16,
    pub src_id: u16,
    pub label: u8,
    /// 48-bit offset; the boards use only the low 16 bits (reference §1.2).
    pub offset: u64,
    pub kind: RequestKind,
}

impl RequestRepr {
    /// A request from the host ([`HOST_SOURCE_ID`]) to `node` on the local bus.
    pub const fn host(node: u8, label: u8, offset: u64, kind: RequestKind) -> Self {
        Self {
            dest_id: node_id(node),
            src_id: HOST_SOURCE_ID,
            label: label & LABEL_MASK,
            offset,
            kind,
        }
    }

    /// Parses a checked packet; a response tcode is an error.
    pub fn parse<T: AsRef<[u8]>>(p: &Packet<T>) -> Result<Self, WireError> {
        let kind = match p.tcode() {
            Tcode::QuadletRead => RequestKind::QuadletRead,
            Tcode::QuadletWrite => RequestKind::QuadletWrite {
                data: p.quadlet_data(),
            },
            Tcode::BlockRead => RequestKind::BlockRead {
                len: p.data_length(),
            },
            Tcode::BlockWrite => RequestKind::BlockWrite {
                len: p.data_length(),
            },
            t => return Err(WireError::UnexpectedTcode { tcode: t as u8 }),
        };
        Ok(Self {
            dest_id: p.dest_id(),
            src_id: p.src_id(),
            label: p.label(),
            offset: p.offset(),
            kind,
        })
    }

    /// Bytes `emit` writes.
    pub const fn buffer_len(&self) -> usize {
        match self.kind {
            RequestKind::BlockWrite { len } => 20 + pad4(len as usize) + 4,
            k => k.tcode().header_len(),
        }
    }

    /// Writes the request with its CRCs into `buf` and returns its length. `payload` is the
    /// block-write data (its length must equal the header's); it must be empty otherwise.
    pub fn emit(&self, buf: &mut [u8], payload: &[u8]) -> Result<usize, WireError> {
        let expected = match self.kind {
            RequestKind::BlockWrite { len } => len as usize,
            _ => 0,
        };
        if payload.len() != expected {
            return Err(WireError::PayloadLength {
                got: payload.len(),
                expected,
            });
        }
        let need = self.buffer_len();
        let Some(out) = buf.get_mut(..need) else {
            return Err(WireError::BufferTooSmall {
                got: buf.len(),
                need,
            });
        };
        let tcode = self.kind.tcode();
        put_be32(
            out,
            0,
            (u32::from(self.dest_id) << 16)
                | (u32::from(self.label & LABEL_MASK) << 10)
                | ((tcode as u32) << 4),
        );
        put_be32(
            out,
            4,
            (u32::from(self.src_id) << 16) | ((self.offset >> 32) as u32 & 0xFFFF),
        );
        put_be32(out, 8, self.offset as u32);
        let hlen = tcode.header_len();
        match self.kind {
            RequestKind::QuadletRead => {}
            RequestKind::QuadletWrite { data } => put_be32(out, 12, data),
            RequestKind::BlockRead { len } | RequestKind::BlockWrite { len } => {
                put_be32(out, 12, u32::from(len) << 16)
            }
        }
        let hcrc = crc32_bzip2(&out[..hlen - 4]);
        put_be32(out, hlen - 4, hcrc);
        if let RequestKind::BlockWrite { .. } = self.kind {
            finish_block(out, hlen, payload);
        }
        Ok(need)
    }
}

/// Copies `payload` after the header, zero-pads it to quadlets and appends the data CRC.
fn finish_block(out: &mut [u8], hlen: usize, payload: &[u8]) {
    let padded = pad4(payload.len());
    if let Some(d) = out.get_mut(hlen..hlen + padded) {
        d.fill(0);
        if let Some(dd) = d.get_mut(..payload.len()) {
            dd.copy_from_slice(payload);
        }
        let dcrc = crc32_bzip2(d);
        put_be32(out, hlen + padded, dcrc);
    }
}

/// What a response carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResponseKind {
    Quadlet {
        data: u32,
    },
    /// Block response of `len` bytes (the data is passed to `emit` separately).
    Block {
        len: u16,
    },
}

/// High-level form of a response.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResponseRepr {
    pub dest_id: u16,
    pub src_id: u16,
    pub label: u8,
    /// 0 = complete.
    pub rcode: u8,
    pub kind: ResponseKind,
}

impl ResponseRepr {
    /// Parses a checked packet; a request tcode is an error.
    pub fn parse<T: AsRef<[u8]>>(p: &Packet<T>) -> Result<Self, WireError> {
        let kind = match p.tcode() {
            Tcode::QuadletResponse => ResponseKind::Quadlet {
                data: p.quadlet_data(),
            },
            Tcode::BlockResponse => ResponseKind::Block {
                len: p.data_length(),
            },
            t => return Err(WireError::UnexpectedTcode { tcode: t as u8 }),
        };
        Ok(Self {
            dest_id: p.dest_id(),
            src_id: p.src_id(),
            label: p.label(),
            rcode: p.rcode(),
            kind,
        })
    }

    /// Bytes `emit` writes.
    pub const fn buffer_len(&self) -> usize {
        match self.kind {
            ResponseKind::Quadlet { .. } => 20,
            ResponseKind::Block { len } => 20 + pad4(len as usize) + 4,
        }
    }

    /// Writes the response with its CRCs (the real FPGA sends 0 instead, §3.1; the host does not
    /// check them) and returns its length. `payload` is the block data, empty for a quadlet.
    pub fn emit(&self, buf: &mut [u8], payload: &[u8]) -> Result<usize, WireError> {
        let expected = match self.kind {
            ResponseKind::Block { len } => len as usize,
            ResponseKind::Quadlet { .. } => 0,
        };
        if payload.len() != expected {
            return Err(WireError::PayloadLength {
                got: payload.len(),
                expected,
            });
        }
        let need = self.buffer_len();
        let Some(out) = buf.get_mut(..need) else {
            return Err(WireError::BufferTooSmall {
                got: buf.len(),
                need,
            });
        };
        let tcode = match self.kind {
            ResponseKind::Quadlet { .. } => Tcode::QuadletResponse,
            ResponseKind::Block { .. } => Tcode::BlockResponse,
        };
        put_be32(
            out,
            0,
            (u32::from(self.dest_id) << 16)
                | (u32::from(self.label & LABEL_MASK) << 10)
                | ((tcode as u32) << 4),
        );
        put_be32(
            out,
            4,
            (u32::from(self.src_id) << 16) | (u32::from(self.rcode & 0x0F) << 12),
        );
        put_be32(out, 8, 0);
        match self.kind {
            ResponseKind::Quadlet { data } => put_be32(out, 12, data),
            ResponseKind::Block { len } => put_be32(out, 12, u32::from(len) << 16),
        }
        let hcrc = crc32_bzip2(&out[..16]);
        put_be32(out, 16, hcrc);
        if let ResponseKind::Block { .. } = self.kind {
            finish_block(out, 20, payload);
        }
        Ok(need)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference §9, datagram 2 without its control word: quadlet read of register 4 (hardware
    /// version) from broadcast node 0x3F, label 2, as the dVRK host library sent it.
    static QREAD_BYTES: [u8; 16] = [
        0xff, 0xff, 0x08, 0x40, 0xff, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04, 0x58, 0xff, 0xb1,
        0x82,
    ];
    /// Reference §9, datagram 1 without its control word: quadlet write of 127.0.0.1 to
    /// register 11 (IP address), broadcast. q0 = 0xFFFF0400 carries label 1 (0x0400 >> 10);
    /// the reference's table says "tl 0", which does not match its own bytes.
    static QWRITE_BYTES: [u8; 20] = [
        0xff, 0xff, 0x04, 0x00, 0xff, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x00, 0x0b, 0x01, 0x00, 0x00,
        0x7f, 0x11, 0xc0, 0x36, 0xd8,
    ];

    fn crc_be(b: &[u8]) -> [u8; 4] {
        crc32_bzip2(b).to_be_bytes()
    }

    /// Block read of 128 bytes at address 0 from node 6, label 5.
    fn bread_bytes() -> Vec<u8> {
        let mut v = vec![
            0xff, 0xc6, 0x14, 0x50, 0xff, 0xd0, 0x00, 0x00, 0, 0, 0, 0, 0x00, 0x80, 0x00, 0x00,
        ];
        let c = crc_be(&v);
        v.extend_from_slice(&c);
        v
    }

    /// Block write of 6 bytes (padded to 8) at 0x1000 to node 2, label 63.
    fn bwrite_bytes() -> Vec<u8> {
        let mut v = vec![
            0xff, 0xc2, 0xfc, 0x10, 0xff, 0xd0, 0x00, 0x00, 0x00, 0x00, 0x10, 0x00, 0x00, 0x06,
            0x00, 0x00,
        ];
        let c = crc_be(&v);
        v.extend_from_slice(&c);
        let data = [1u8, 2, 3, 4, 5, 6, 0, 0];
        v.extend_from_slice(&data);
        v.extend_from_slice(&crc_be(&data));
        v
    }

    /// Quadlet response from node 7 to the host, label 9, data 0x514C4131 ("QLA1").
    fn qresp_bytes() -> Vec<u8> {
        let mut v = vec![
            0xff, 0xd0, 0x24, 0x60, 0xff, 0xc7, 0x00, 0x00, 0, 0, 0, 0, 0x51, 0x4c, 0x41, 0x31,
        ];
        let c = crc_be(&v);
        v.extend_from_slice(&c);
        v
    }

    /// Block response from node 6, label 1, 8 bytes.
    fn bresp_bytes() -> Vec<u8> {
        let mut v = vec![
            0xff, 0xd0, 0x04, 0x70, 0xff, 0xc6, 0x00, 0x00, 0, 0, 0, 0, 0x00, 0x08, 0x00, 0x00,
        ];
        let c = crc_be(&v);
        v.extend_from_slice(&c);
        let data = [0xde, 0xad, 0xbe, 0xef, 0x01, 0x02, 0x03, 0x04];
        v.extend_from_slice(&data);
        v.extend_from_slice(&crc_be(&data));
        v
    }

    #[test]
    fn deconstruct_quadlet_read() {
        let p = Packet::new_checked(&QREAD_BYTES[..]).unwrap();
        assert_eq!(p.tcode(), Tcode::QuadletRead);
        assert_eq!(p.dest_id(), 0xFFFF);
        assert_eq!(p.dest_node(), BROADCAST_NODE);
        assert_eq!(p.label(), 2);
        assert_eq!(p.src_id(), HOST_SOURCE_ID);
        assert_eq!(p.offset(), 4);
        assert_eq!(p.header_crc(), 0x58ff_b182);
        assert_eq!(p.computed_header_crc(), 0x58ff_b182);
        assert_eq!(p.total_len(), 16);
        assert!(p.payload().is_empty());
    }

    #[test]
    fn construct_quadlet_read() {
        let r = RequestRepr::host(BROADCAST_NODE, 2, 4, RequestKind::QuadletRead);
        let mut buf = [0u8; 32];
        let n = r.emit(&mut buf, &[]).unwrap();
        assert_eq!(&buf[..n], &QREAD_BYTES[..]);
        assert_eq!(
            RequestRepr::parse(&Packet::new_checked(&buf[..n]).unwrap()).unwrap(),
            r
        );
    }

    #[test]
    fn quadlet_write_round_trip() {
        let p = Packet::new_checked(&QWRITE_BYTES[..]).unwrap();
        let r = RequestRepr::parse(&p).unwrap();
        assert_eq!(
            r,
            RequestRepr::host(0x3F, 1, 11, RequestKind::QuadletWrite { data: 0x0100_007F })
        );
        let mut buf = [0u8; 20];
        assert_eq!(r.emit(&mut buf, &[]).unwrap(), 20);
        assert_eq!(buf, QWRITE_BYTES);
    }

    #[test]
    fn block_read_round_trip() {
        let bytes = bread_bytes();
        let p = Packet::new_checked(&bytes[..]).unwrap();
        assert_eq!(p.tcode(), Tcode::BlockRead);
        assert_eq!(p.data_length(), 128);
        assert_eq!(p.dest_node(), 6);
        assert_eq!(p.label(), 5);
        let r = RequestRepr::parse(&p).unwrap();
        assert_eq!(
            r,
            RequestRepr::host(6, 5, 0, RequestKind::BlockRead { len: 128 })
        );
        let mut buf = [0u8; 20];
        r.emit(&mut buf, &[]).unwrap();
        assert_eq!(&buf[..], &bytes[..]);
    }

    #[test]
    fn block_write_round_trip() {
        let bytes = bwrite_bytes();
        let p = Packet::new_checked(&bytes[..]).unwrap();
        assert_eq!(p.tcode(), Tcode::BlockWrite);
        assert_eq!(p.label(), 63);
        assert_eq!(p.offset(), 0x1000);
        assert_eq!(p.payload(), &[1, 2, 3, 4, 5, 6]);
        assert_eq!(p.data_crc(), p.computed_data_crc());
        assert_eq!(p.total_len(), 32);
        let r = RequestRepr::parse(&p).unwrap();
        let mut buf = [0u8; 32];
        assert_eq!(r.emit(&mut buf, &[1, 2, 3, 4, 5, 6]).unwrap(), 32);
        assert_eq!(&buf[..], &bytes[..]);
    }

    #[test]
    fn quadlet_response_round_trip() {
        let bytes = qresp_bytes();
        let p = Packet::new_checked(&bytes[..]).unwrap();
        assert_eq!(p.tcode(), Tcode::QuadletResponse);
        assert_eq!(p.src_node(), 7);
        assert_eq!(p.label(), 9);
        assert_eq!(p.rcode(), 0);
        assert_eq!(p.quadlet_data(), 0x514C_4131);
        let r = ResponseRepr::parse(&p).unwrap();
        assert_eq!(
            r,
            ResponseRepr {
                dest_id: 0xFFD0,
                src_id: 0xFFC7,
                label: 9,
                rcode: 0,
                kind: ResponseKind::Quadlet { data: 0x514C_4131 }
            }
        );
        let mut buf = [0u8; 20];
        r.emit(&mut buf, &[]).unwrap();
        assert_eq!(&buf[..], &bytes[..]);
    }

    #[test]
    fn block_response_round_trip() {
        let bytes = bresp_bytes();
        let p = Packet::new_checked(&bytes[..]).unwrap();
        assert_eq!(p.tcode(), Tcode::BlockResponse);
        assert_eq!(p.payload(), &[0xde, 0xad, 0xbe, 0xef, 1, 2, 3, 4]);
        let r = ResponseRepr::parse(&p).unwrap();
        let mut buf = [0u8; 32];
        assert_eq!(r.emit(&mut buf, p.payload()).unwrap(), 32);
        assert_eq!(&buf[..], &bytes[..]);
    }

    #[test]
    fn truncated_and_unknown() {
        assert_eq!(
            Packet::new_checked(&QREAD_BYTES[..15]).unwrap_err(),
            WireError::Truncated { got: 15, need: 16 }
        );
        assert_eq!(
            Packet::new_checked(&QWRITE_BYTES[..19]).unwrap_err(),
            WireError::Truncated { got: 19, need: 20 }
        );
        let b = bresp_bytes();
        assert_eq!(
            Packet::new_checked(&b[..31]).unwrap_err(),
            WireError::Truncated { got: 31, need: 32 }
        );
        let mut bad = QREAD_BYTES;
        bad[3] = 0x20; // tcode 2 (write response): not used by the boards
        assert_eq!(
            Packet::new_checked(&bad[..]).unwrap_err(),
            WireError::UnknownTcode { tcode: 2 }
        );
    }

    #[test]
    fn emit_checks_lengths() {
        let r = RequestRepr::host(1, 0, 0, RequestKind::BlockWrite { len: 8 });
        let mut small = [0u8; 20];
        assert_eq!(
            r.emit(&mut small, &[0; 8]).unwrap_err(),
            WireError::BufferTooSmall { got: 20, need: 32 }
        );
        assert_eq!(
            r.emit(&mut [0u8; 64], &[0; 4]).unwrap_err(),
            WireError::PayloadLength {
                got: 4,
                expected: 8
            }
        );
        let q = ResponseRepr {
            dest_id: 0,
            src_id: 0,
            label: 0,
            rcode: 0,
            kind: ResponseKind::Quadlet { data: 0 },
        };
        assert_eq!(
            q.emit(&mut [0u8; 64], &[1]).unwrap_err(),
            WireError::PayloadLength {
                got: 1,
                expected: 0
            }
        );
    }

    #[test]
    fn wrong_direction_is_an_error() {
        let p = Packet::new_checked(&QREAD_BYTES[..]).unwrap();
        assert_eq!(
            ResponseRepr::parse(&p).unwrap_err(),
            WireError::UnexpectedTcode { tcode: 4 }
        );
        let b = qresp_bytes();
        let p = Packet::new_checked(&b[..]).unwrap();
        assert_eq!(
            RequestRepr::parse(&p).unwrap_err(),
            WireError::UnexpectedTcode { tcode: 6 }
        );
    }
}
