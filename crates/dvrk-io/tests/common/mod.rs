//! Test boards: a small register model answering the real protocol, built with the crate's own
//! wire emitters, reachable in-process ([`InProcLink`]) or over UDP on 127.0.0.1 ([`Responder`]).
//! It can misbehave in every way the port must catch ([`Fault`]).
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use dvrk_io::port::{Link, PortError};
use dvrk_io::wire::block::{hardware_version, status_bits};
use dvrk_io::wire::eth::extra_flags;
use dvrk_io::wire::firewire::{BROADCAST_NODE, node_id};
use dvrk_io::wire::hub::{HUB_ADDRESS, QUERY_ADDRESS};
use dvrk_io::wire::{
    Adc, BlockLayout, BoardKind, BoardStatus, EncoderPeriod, EncoderPosition, EthReply, EthRequest,
    ExtraData, FeedbackBlock, HubHeader, HubLayout, HubView, RequestKind, RequestRepr,
    ResponseKind, ResponseRepr, Tcode, Timestamp,
};

pub const PSM_CLASSIC_TOML: &str = include_str!("../../../../config/io/psm-classic.toml");

/// Reads a config as the application does: parse the text (here `toml`/`serde_json`, dev
/// dependencies), then let the crate validate it. The error is the parser's or the crate's.
pub fn io_from_toml(text: &str) -> Result<dvrk_io::IoConfig, String> {
    let params: dvrk_io::convert::IoParams = toml::from_str(text).map_err(|e| e.to_string())?;
    dvrk_io::IoConfig::from_params(params).map_err(|e| e.to_string())
}

/// As [`io_from_toml`], for a sawRobotIO1394 JSON v6 file.
pub fn io_from_saw_json(text: &str) -> Result<dvrk_io::IoConfig, String> {
    let file: dvrk_io::convert::SawFile =
        serde_json::from_str(&dvrk_io::convert::strip_json_comments(text))
            .map_err(|e| e.to_string())?;
    dvrk_io::IoConfig::from_saw_file(file, None).map_err(|e| e.to_string())
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    None,
    /// No reply at all.
    Silent,
    /// Reply cut to 20 bytes.
    Truncate,
    /// Reply with 4 extra bytes.
    Oversize,
    /// Block response tcode for a quadlet read (and the reverse).
    WrongTcode,
    /// Label + 1.
    WrongLabel,
    /// Source node + 1.
    WrongSource,
    /// Only the 8 extra-data bytes, flagged dropped.
    Dropped8,
    /// Full reply with the dropped flag.
    DroppedFlag,
    BusReset,
    InternalError,
    /// rcode 7 (address error).
    Rcode,
    /// Block response of a different length than asked.
    WrongLength,
    /// First a reply with an old label, then the right one.
    StaleThenGood,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Logged {
    pub node: u8,
    pub tcode: Tcode,
    pub addr: u64,
    pub len: u16,
    pub data: u32,
    pub noforward: bool,
}

#[derive(Clone, Debug)]
pub struct Board {
    pub id: u8,
    pub hw: u32,
    pub fw: u32,
    pub eth_status: u32,
    pub block: Vec<u8>,
    pub layout: BlockLayout,
}

impl Board {
    pub fn qla(id: u8, fw: u32) -> Self {
        let layout = BlockLayout::new(fw, BoardKind::Qla).unwrap();
        let mut b = Self {
            id,
            hw: hardware_version::QLA1,
            fw,
            eth_status: 0x4000_0000,
            block: vec![0; layout.len_bytes()],
            layout,
        };
        b.set_status(
            BoardStatus::board_id_bits(id)
                | status_bits::MV_GOOD
                | status_bits::POWER_ENABLE
                | status_bits::RELAY_FEEDBACK
                | status_bits::RELAY_COMMANDED
                | 0x0F00,
        );
        b.edit(|blk| blk.set_timestamp(Timestamp(49_151)));
        for ax in 0..4 {
            b.set_axis(ax, 0, 0x8000);
        }
        b
    }
    pub fn edit(&mut self, f: impl FnOnce(&mut FeedbackBlock<&mut [u8]>)) {
        let mut v = FeedbackBlock::new_checked(&mut self.block[..], self.layout).unwrap();
        f(&mut v);
    }
    pub fn view(&self) -> FeedbackBlock<&[u8]> {
        FeedbackBlock::new_checked(&self.block[..], self.layout).unwrap()
    }
    pub fn set_status(&mut self, raw: u32) {
        self.edit(|b| b.set_status(raw));
    }
    pub fn status(&self) -> u32 {
        self.view().status().raw
    }
    pub fn set_axis(&mut self, axis: usize, counts: i32, current_bits: u16) {
        let clk = self.layout.velocity_clock_hz();
        self.edit(|b| {
            b.set_encoder_position(axis, EncoderPosition::from_counts(counts))
                .unwrap();
            b.set_encoder_period(axis, EncoderPeriod::from_velocity(0.0, clk))
                .unwrap();
            b.set_adc(axis, Adc::new(0x8000, current_bits)).unwrap();
            let _ = b.set_motor_status(axis, 1 << 29);
        });
    }
    pub fn register(&self, addr: u16) -> Option<u32> {
        let v = self.view();
        Some(match addr {
            0 => v.status().raw,
            4 => self.hw,
            7 => self.fw,
            12 => self.eth_status,
            15 => 0x1234_5678,
            1..=15 => 0,
            a if a < 0x100 => {
                let ch = (a >> 4) as usize;
                let axis = ch.checked_sub(1)?;
                match a & 0xF {
                    0 => v.adc(axis)?.0,
                    5 => v.encoder_position(axis)?.0,
                    6 => v.encoder_period(axis)?.0,
                    12 => v.motor_status(axis).map_or(0, |m| m.raw),
                    _ => 0,
                }
            }
            _ => return None,
        })
    }
}

/// Writes quadlet `q` of a block through the public setters (timestamp, status, ... by group).
fn copy_quadlet(dst: &mut FeedbackBlock<&mut [u8]>, q: usize, raw: u32) {
    let l = dst.layout();
    let (m, e) = (l.num_motors(), l.num_encoders());
    match q {
        0 => dst.set_timestamp(Timestamp(raw)),
        1 => dst.set_status(raw),
        2 => dst.set_digital_io(dvrk_io::wire::DigitalIo(raw)),
        3 => dst.set_temperature(dvrk_io::wire::Temperature(raw)),
        q if q < 4 + m => dst.set_adc(q - 4, Adc(raw)).unwrap(),
        q if q < 4 + m + e => dst
            .set_encoder_position(q - 4 - m, EncoderPosition(raw))
            .unwrap(),
        q if q < 4 + m + 2 * e => dst
            .set_encoder_period(q - 4 - m - e, EncoderPeriod(raw))
            .unwrap(),
        q if q < 4 + m + 3 * e => dst
            .set_qtr1(q - 4 - m - 2 * e, dvrk_io::wire::Quarter(raw))
            .unwrap(),
        q if q < 4 + m + 4 * e => dst
            .set_qtr5(q - 4 - m - 3 * e, dvrk_io::wire::Quarter(raw))
            .unwrap(),
        q if q < 4 + m + 5 * e => dst.set_running(q - 4 - m - 4 * e, raw).unwrap(),
        q => dst.set_motor_status(q - 4 - m - 5 * e, raw).unwrap(),
    }
}

pub struct Boards {
    pub boards: Vec<Board>,
    pub log: Vec<Logged>,
    pub fault: Fault,
    pub query_mask: u16,
    pub query_seq: u16,
    pub generation: u8,
    /// Rev 9 Ethernet-only replies carry NOFORWARD in the extra data.
    pub echo_noforward: bool,
}

impl Boards {
    pub fn psm(fw: u32) -> Self {
        Self {
            boards: vec![Board::qla(6, fw), Board::qla(7, fw)],
            log: Vec::new(),
            fault: Fault::None,
            query_mask: 0,
            query_seq: 0,
            generation: 0,
            echo_noforward: true,
        }
    }
    pub fn board(&mut self, id: u8) -> &mut Board {
        self.boards.iter_mut().find(|b| b.id == id).unwrap()
    }
    fn board_ref(&self, node: u8) -> Option<&Board> {
        if node == BROADCAST_NODE {
            self.boards.first()
        } else {
            self.boards.iter().find(|b| b.id == node)
        }
    }
    pub fn count(&self, f: impl Fn(&Logged) -> bool) -> usize {
        self.log.iter().filter(|l| f(l)).count()
    }

    fn hub_bytes(&self) -> Vec<u8> {
        let mut ids: Vec<u8> = self
            .boards
            .iter()
            .map(|b| b.id)
            .filter(|id| self.query_mask & (1 << id) != 0)
            .collect();
        ids.sort_unstable();
        let pairs: Vec<(u8, BlockLayout)> = ids
            .iter()
            .map(|id| {
                (
                    *id,
                    self.boards.iter().find(|b| b.id == *id).unwrap().layout,
                )
            })
            .collect();
        let lay = HubLayout::new(&pairs).unwrap();
        let mut buf = vec![0u8; lay.len_bytes()];
        let mut v = HubView::new_checked(&mut buf[..], lay).unwrap();
        for (i, (id, l)) in pairs.iter().enumerate() {
            v.set_header(
                i,
                HubHeader::new(l.len_quadlets() as u8, self.query_seq, false, 100),
            )
            .unwrap();
            let src = &self.boards.iter().find(|b| b.id == *id).unwrap().block;
            let mut dst = v.block_mut(i).unwrap();
            for q in 0..l.len_quadlets() {
                let raw = u32::from_be_bytes(src[q * 4..q * 4 + 4].try_into().unwrap());
                copy_quadlet(&mut dst, q, raw);
            }
        }
        v.set_timing(1, 2);
        buf
    }

    /// Answers a quadlet read of `addr` at `node` with label `label` as if it had just arrived
    /// (to answer again, or with a [`Fault`] set for this one reply).
    pub fn answer_quadlet_read(&mut self, node: u8, addr: u16, label: u8) -> Vec<Vec<u8>> {
        let req = RequestRepr::host(node, label, u64::from(addr), RequestKind::QuadletRead);
        let mut buf = [0u8; 64];
        let cw = dvrk_io::wire::ControlWord::new(true, self.generation);
        let n = EthRequest::emit(&mut buf, cw, &req, &[]).unwrap();
        self.handle(&buf[..n])
    }

    /// Answers one request datagram; returns the reply datagrams (none, one or two).
    pub fn handle(&mut self, dgram: &[u8]) -> Vec<Vec<u8>> {
        let Ok(req) = EthRequest::parse(dgram) else {
            return vec![];
        };
        let Ok(r) = RequestRepr::parse(&req.packet) else {
            return vec![];
        };
        let node = (r.dest_id & 0x3F) as u8;
        let (len, data) = match r.kind {
            RequestKind::QuadletWrite { data } => (0, data),
            RequestKind::BlockRead { len } | RequestKind::BlockWrite { len } => (len, 0),
            RequestKind::QuadletRead => (0, 0),
        };
        self.log.push(Logged {
            node,
            tcode: r.kind.tcode(),
            addr: r.offset,
            len,
            data,
            noforward: req.control.noforward(),
        });
        let addr = r.offset as u16;
        let (kind, payload): (ResponseKind, Vec<u8>) = match r.kind {
            RequestKind::QuadletWrite { data } => {
                if addr == QUERY_ADDRESS {
                    self.query_seq = (data >> 16) as u16;
                    self.query_mask = data as u16;
                }
                return vec![];
            }
            RequestKind::BlockWrite { .. } => return vec![],
            RequestKind::QuadletRead => {
                let Some(v) = self.board_ref(node).and_then(|b| b.register(addr)) else {
                    return vec![];
                };
                (ResponseKind::Quadlet { data: v }, vec![])
            }
            RequestKind::BlockRead { len } => {
                let data = if addr == HUB_ADDRESS {
                    self.hub_bytes()
                } else if addr == 0 {
                    let Some(b) = self.board_ref(node) else {
                        return vec![];
                    };
                    b.block.clone()
                } else {
                    return vec![];
                };
                let mut data = data;
                data.resize(len as usize, 0);
                (ResponseKind::Block { len }, data)
            }
        };
        let src_node = self.board_ref(node).map_or(node, |b| b.id);
        let mut resp = ResponseRepr {
            dest_id: 0xFFD0,
            src_id: node_id(src_node),
            label: r.label,
            rcode: 0,
            kind,
        };
        let mut payload = payload;
        let mut extra = ExtraData {
            flags: if self.echo_noforward {
                extra_flags::NOFORWARD
            } else {
                0
            },
            bus_generation: self.generation,
            ..Default::default()
        };
        match self.fault {
            Fault::Silent => return vec![],
            Fault::WrongLabel => resp.label = (r.label + 1) & 0x3F,
            Fault::WrongSource => resp.src_id = node_id(src_node + 1),
            Fault::Rcode => resp.rcode = 7,
            Fault::WrongTcode => {
                resp.kind = match resp.kind {
                    ResponseKind::Quadlet { .. } => {
                        payload = vec![0; 4];
                        ResponseKind::Block { len: 4 }
                    }
                    ResponseKind::Block { .. } => {
                        payload.clear();
                        ResponseKind::Quadlet { data: 0 }
                    }
                }
            }
            Fault::WrongLength => {
                if let ResponseKind::Block { len } = resp.kind {
                    payload.truncate(len as usize - 4);
                    resp.kind = ResponseKind::Block { len: len - 4 };
                }
            }
            Fault::DroppedFlag => extra.flags |= extra_flags::PACKET_DROPPED,
            Fault::BusReset => extra.flags |= extra_flags::BUS_RESET,
            Fault::InternalError => extra.flags |= extra_flags::INTERNAL_ERROR,
            Fault::Dropped8 => {
                let mut out = vec![0u8; 8];
                extra.flags |= extra_flags::PACKET_DROPPED;
                EthReply::emit_dropped(&mut out, &extra).unwrap();
                return vec![out];
            }
            _ => {}
        }
        let mut out = vec![0u8; 4096];
        let n = EthReply::emit(&mut out, &resp, &payload, &extra).unwrap();
        out.truncate(n);
        match self.fault {
            Fault::Truncate => out.truncate(20),
            Fault::Oversize => out.extend_from_slice(&[0xAB; 4]),
            Fault::StaleThenGood => {
                let mut stale = out.clone();
                stale[2] = (stale[2] & 0x03) | (((r.label + 63) & 0x3F) << 2);
                return vec![stale, out];
            }
            _ => {}
        }
        vec![out]
    }
}

/// In-process link to [`Boards`].
pub struct InProcLink {
    pub boards: Boards,
    queue: VecDeque<Vec<u8>>,
}

impl InProcLink {
    pub fn new(boards: Boards) -> Self {
        Self {
            boards,
            queue: VecDeque::new(),
        }
    }
}

impl Link for InProcLink {
    fn send(&mut self, _dest_node: u8, datagram: &[u8]) -> Result<(), PortError> {
        let replies = self.boards.handle(datagram);
        self.queue.extend(replies);
        Ok(())
    }
    fn recv(&mut self, buf: &mut [u8]) -> Result<usize, PortError> {
        let d = self.queue.pop_front().ok_or(PortError::LINK_TIMEOUT)?;
        buf[..d.len()].copy_from_slice(&d);
        Ok(d.len())
    }
}

/// [`Boards`] behind a real UDP socket on 127.0.0.1 (ephemeral port), in a thread.
pub struct Responder {
    pub addr: SocketAddr,
    pub state: Arc<Mutex<Boards>>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl Responder {
    pub fn spawn(boards: Boards) -> Self {
        Self::spawn_at(boards, "127.0.0.1:0".parse().unwrap()).unwrap()
    }
    pub fn spawn_at(boards: Boards, at: SocketAddr) -> std::io::Result<Self> {
        let sock = UdpSocket::bind(at)?;
        sock.set_read_timeout(Some(Duration::from_millis(5)))
            .unwrap();
        let addr = sock.local_addr().unwrap();
        let state = Arc::new(Mutex::new(boards));
        let stop = Arc::new(AtomicBool::new(false));
        let (st, sp) = (state.clone(), stop.clone());
        let handle = std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while !sp.load(Ordering::Relaxed) {
                let Ok((n, from)) = sock.recv_from(&mut buf) else {
                    continue;
                };
                let replies = st.lock().unwrap().handle(&buf[..n]);
                for r in replies {
                    let _ = sock.send_to(&r, from);
                }
            }
        });
        Ok(Self {
            addr,
            state,
            stop,
            handle: Some(handle),
        })
    }
    pub fn set_fault(&self, f: Fault) {
        self.state.lock().unwrap().fault = f;
    }
    pub fn with<R>(&self, f: impl FnOnce(&mut Boards) -> R) -> R {
        f(&mut self.state.lock().unwrap())
    }
}

impl Drop for Responder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
