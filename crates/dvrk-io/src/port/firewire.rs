//! `FirewirePort`: the boards over FireWire through libraw1394 (feature `firewire`; needs
//! Debian's `libraw1394-dev`). Reference §1.1.
//!
//! libraw1394 builds and checks the asynchronous packets itself; what this port shares with the
//! Ethernet engine is everything above that: the register map, the fake-broadcast query
//! address, block-size limits ([`MAX_BLOCK_BYTES`]), big-endian quadlets, the feedback-block
//! and hub layouts ([`crate::wire`]) and the discovery checks. It cannot be exercised here (no
//! FireWire hardware in CI); it is built and clippy-checked with the feature.
//!
//! Read-only like the rest: unlike the dVRK host it does not write the PC's CSR STATE_CLEAR to
//! disable cycle-start packets (§1.1), and it never writes unless
//! [`FirewirePort::allow_writes`] is used. The dVRK's own process exits when another user has
//! `/dev/fwN` open, so start the sidecar after it (§8.3).

use std::ffi::{c_int, c_uint, c_void};
use std::ptr::NonNull;

use super::{Port, PortError, reg};
use crate::wire::firewire::MAX_BLOCK_BYTES;
use crate::wire::hub::{HUB_ADDRESS, QUERY_ADDRESS};
use crate::wire::{BoardKind, BoardStatus};

#[link(name = "raw1394")]
unsafe extern "C" {
    fn raw1394_new_handle_on_port(port: c_int) -> *mut c_void;
    fn raw1394_destroy_handle(handle: *mut c_void);
    fn raw1394_get_local_id(handle: *mut c_void) -> u16;
    fn raw1394_get_nodecount(handle: *mut c_void) -> c_int;
    fn raw1394_get_generation(handle: *mut c_void) -> c_uint;
    fn raw1394_read(
        handle: *mut c_void,
        node: u16,
        addr: u64,
        length: usize,
        buffer: *mut u32,
    ) -> c_int;
    fn raw1394_write(
        handle: *mut c_void,
        node: u16,
        addr: u64,
        length: usize,
        data: *mut u32,
    ) -> c_int;
}

/// Node that FireWire "fake broadcast" writes go to; every FPGA snoops them (§1.1).
const FAKE_BROADCAST_NODE: u16 = 0;

/// A libraw1394 handle on one FireWire port, with the node↔board map from a scan.
pub struct FirewirePort {
    handle: NonNull<c_void>,
    base_id: u16,
    node_of_board: [Option<u8>; 16],
    /// Board added last by the scan (highest node): the hub for broadcast reads (§3.4).
    hub_board: Option<u8>,
    buf: Box<[u32; MAX_BLOCK_BYTES / 4]>,
    query_allowed: bool,
    query_seq: u16,
    generation: u32,
}

impl FirewirePort {
    /// Opens FireWire port `port` (the `N` of the dVRK's `fw:N`) and scans the bus: every node
    /// below the PC (the root, highest node) is asked for hardware version and status
    /// (registers 4 and 0, quadlet reads only).
    pub fn open(port: u32) -> Result<Self, PortError> {
        let port = c_int::try_from(port).map_err(|_| PortError::Unsupported)?;
        // SAFETY: plain FFI call; a null return is handled.
        let raw = unsafe { raw1394_new_handle_on_port(port) };
        let handle =
            NonNull::new(raw).ok_or_else(|| PortError::from(std::io::Error::last_os_error()))?;
        // SAFETY: `handle` is a live handle from raw1394_new_handle_on_port.
        let (local, nodes, generation) = unsafe {
            (
                raw1394_get_local_id(handle.as_ptr()),
                raw1394_get_nodecount(handle.as_ptr()),
                raw1394_get_generation(handle.as_ptr()),
            )
        };
        let mut p = Self {
            handle,
            base_id: local & 0xFFC0,
            node_of_board: [None; 16],
            hub_board: None,
            buf: Box::new([0; MAX_BLOCK_BYTES / 4]),
            query_allowed: false,
            query_seq: 0,
            generation,
        };
        let boards = nodes.saturating_sub(1).clamp(0, 63) as u8;
        for node in 0..boards {
            let Ok(hw) = p.read_node_quadlet(node, reg::HARDWARE_VERSION) else {
                continue;
            };
            let Ok(kind) = BoardKind::from_hardware_version(hw) else {
                continue;
            };
            let Ok(status) = p.read_node_quadlet(node, reg::STATUS) else {
                continue;
            };
            let id = BoardStatus::new(status, kind).board_id();
            if let Some(slot) = p.node_of_board.get_mut(id as usize) {
                *slot = Some(node);
                p.hub_board = Some(id);
            }
        }
        Ok(p)
    }

    /// From a dVRK port string `fw:N` (`fw` alone = port 0).
    pub fn from_port_string(s: &str) -> Result<Self, PortError> {
        let n = match s.strip_prefix("fw") {
            Some("") => 0,
            Some(rest) => rest
                .strip_prefix(':')
                .and_then(|r| r.parse().ok())
                .ok_or(PortError::Unsupported)?,
            None => return Err(PortError::Unsupported),
        };
        Self::open(n)
    }

    /// Node found for `board` by the scan.
    pub fn node_of(&self, board: u8) -> Option<u8> {
        self.node_of_board.get(board as usize).copied().flatten()
    }

    /// Bus generation seen at open (libraw1394 keeps it; a bus reset makes transactions fail).
    pub fn generation(&self) -> u32 {
        self.generation
    }

    /// The explicit write capability (writes refresh the watchdog, §4/§8).
    pub fn allow_writes(&mut self) -> FirewireWriteAccess<'_> {
        FirewireWriteAccess { port: self }
    }

    fn node(&self, board: u8) -> Result<u8, PortError> {
        if board > 15 {
            return Err(PortError::BoardOutOfRange { board });
        }
        self.node_of(board).ok_or(PortError::BoardMissing { board })
    }

    fn error(board: u8, addr: u16) -> PortError {
        let e = std::io::Error::last_os_error();
        match e.raw_os_error() {
            // Transaction timed out or the node did not answer.
            Some(code) if code == 110 || code == 11 => PortError::Timeout { board, addr },
            // Generation mismatch after a bus reset (ESTALE).
            Some(116) => PortError::BusReset {
                board,
                generation: 0,
            },
            _ => PortError::Io { kind: e.kind() },
        }
    }

    fn read_node_quadlet(&mut self, node: u8, addr: u16) -> Result<u32, PortError> {
        let mut q = 0u32;
        // SAFETY: live handle; `q` is a valid 4-byte buffer for the duration of the call.
        let r = unsafe {
            raw1394_read(
                self.handle.as_ptr(),
                self.base_id | u16::from(node),
                u64::from(addr),
                4,
                &mut q,
            )
        };
        if r != 0 {
            return Err(Self::error(node, addr));
        }
        // libraw1394 hands back bus (big-endian) order.
        Ok(u32::from_be_bytes(q.to_ne_bytes()))
    }

    fn write_node(&mut self, node_id: u16, addr: u16, data: &[u8]) -> Result<(), PortError> {
        let len = data.len();
        if len == 0 || !len.is_multiple_of(4) || len > MAX_BLOCK_BYTES {
            return Err(PortError::BlockSize {
                len,
                max: MAX_BLOCK_BYTES,
            });
        }
        for (i, c) in data.chunks_exact(4).enumerate() {
            if let (Some(slot), [a, b, cc, d]) = (self.buf.get_mut(i), c) {
                *slot = u32::from_ne_bytes([*a, *b, *cc, *d]);
            }
        }
        // SAFETY: live handle; `buf` holds at least `len` bytes.
        let r = unsafe {
            raw1394_write(
                self.handle.as_ptr(),
                node_id,
                u64::from(addr),
                len,
                self.buf.as_mut_ptr(),
            )
        };
        if r != 0 {
            return Err(Self::error((node_id & 0x3F) as u8, addr));
        }
        Ok(())
    }
}

impl Drop for FirewirePort {
    fn drop(&mut self) {
        // SAFETY: the handle is live and destroyed exactly once.
        unsafe { raw1394_destroy_handle(self.handle.as_ptr()) }
    }
}

impl Port for FirewirePort {
    fn read_quadlet(&mut self, board: u8, addr: u16) -> Result<u32, PortError> {
        let node = self.node(board)?;
        self.read_node_quadlet(node, addr).map_err(|e| match e {
            PortError::Timeout { addr, .. } => PortError::Timeout { board, addr },
            e => e,
        })
    }

    fn read_block(&mut self, board: u8, addr: u16, out: &mut [u8]) -> Result<(), PortError> {
        let len = out.len();
        if len == 0 || !len.is_multiple_of(4) || len > MAX_BLOCK_BYTES {
            return Err(PortError::BlockSize {
                len,
                max: MAX_BLOCK_BYTES,
            });
        }
        let node = self.node(board)?;
        // SAFETY: live handle; `buf` (aligned quadlets) holds MAX_BLOCK_BYTES >= len bytes.
        let r = unsafe {
            raw1394_read(
                self.handle.as_ptr(),
                self.base_id | u16::from(node),
                u64::from(addr),
                len,
                self.buf.as_mut_ptr(),
            )
        };
        if r != 0 {
            return Err(Self::error(board, addr));
        }
        for (c, q) in out.chunks_exact_mut(4).zip(self.buf.iter()) {
            c.copy_from_slice(&q.to_ne_bytes());
        }
        Ok(())
    }

    /// Fake-broadcast quadlet write of (seq<<16 | mask) to node 0 at 0x1800 (Rev 7+, §1.1),
    /// a wait of 10 + 5·Nb µs (§3.4), then a block read of the hub memory on the board the scan
    /// added last. Refused until enabled through [`FirewireWriteAccess::enable_broadcast_query`].
    fn broadcast_query_hub_read(
        &mut self,
        board_mask: u16,
        out: &mut [u8],
    ) -> Result<(), PortError> {
        if !self.query_allowed {
            return Err(PortError::QueryNotAllowed);
        }
        let hub = self.hub_board.ok_or(PortError::BoardMissing { board: 0 })?;
        self.query_seq = self.query_seq.wrapping_add(1);
        let q = ((u32::from(self.query_seq) << 16) | u32::from(board_mask)).to_be_bytes();
        self.write_node(self.base_id | FAKE_BROADCAST_NODE, QUERY_ADDRESS, &q)?;
        std::thread::sleep(std::time::Duration::from_micros(
            10 + 5 * u64::from(board_mask.count_ones()),
        ));
        self.read_block(hub, HUB_ADDRESS, out)
    }
}

/// The write capability of a [`FirewirePort`].
pub struct FirewireWriteAccess<'a> {
    port: &'a mut FirewirePort,
}

impl FirewireWriteAccess<'_> {
    pub fn write_quadlet(&mut self, board: u8, addr: u16, data: u32) -> Result<(), PortError> {
        let node = self.port.node(board)?;
        let id = self.port.base_id | u16::from(node);
        self.port.write_node(id, addr, &data.to_be_bytes())
    }
    pub fn write_block(&mut self, board: u8, addr: u16, data: &[u8]) -> Result<(), PortError> {
        let node = self.port.node(board)?;
        let id = self.port.base_id | u16::from(node);
        self.port.write_node(id, addr, data)
    }
    pub fn enable_broadcast_query(&mut self) {
        self.port.query_allowed = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn port_strings() {
        assert!(matches!(
            FirewirePort::from_port_string("udp:1.2.3.4"),
            Err(PortError::Unsupported)
        ));
        assert!(matches!(
            FirewirePort::from_port_string("fw:x"),
            Err(PortError::Unsupported)
        ));
    }

    #[test]
    fn opening_a_port_that_does_not_exist_is_an_error() {
        // No FireWire hardware here: libraw1394 returns no handle; this must be an error.
        assert!(FirewirePort::open(63).is_err());
    }
}
