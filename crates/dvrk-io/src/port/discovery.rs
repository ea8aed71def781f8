//! Board discovery (reference §3.3).

use std::net::Ipv4Addr;
use std::time::Duration;

use super::eth::{EthPort, WriteAccess};
use super::{Link, Port, PortError};
use crate::wire::block::BoardStatus;
use crate::wire::{BlockLayout, BoardKind, WireError};

/// Board registers read at discovery (reference §1.2, channel 0).
pub mod reg {
    pub const STATUS: u16 = 0;
    pub const PHY_REQUEST: u16 = 1;
    pub const HARDWARE_VERSION: u16 = 4;
    pub const FIRMWARE_VERSION: u16 = 7;
    pub const IP_ADDRESS: u16 = 11;
    pub const ETHERNET_STATUS: u16 = 12;
    pub const GIT_DESCRIPTION: u16 = 15;
}

/// FPGA board generation from register 12 (reference §1.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FpgaGeneration {
    /// FireWire only (register 12 = 0).
    V1,
    /// One 100 Mb Ethernet port (bit 31 set).
    V2,
    /// Zynq, two 1 Gb ports (bits 31:30 = 01).
    V3,
    /// Any other value.
    Unknown,
}

impl FpgaGeneration {
    pub const fn from_ethernet_status(reg12: u32) -> Self {
        if reg12 == 0 {
            Self::V1
        } else if reg12 & 0x8000_0000 != 0 {
            Self::V2
        } else if reg12 >> 30 == 0b01 {
            Self::V3
        } else {
            Self::Unknown
        }
    }
}

/// How the host reaches the boards (reference §3.3 step 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EthMode {
    /// Hub is V3 with Rev ≥ 9: node = board id, each board unicast at its own IP.
    EthernetOnly,
    /// Everything goes to the hub, which forwards on FireWire (`udpfw`).
    Bridge,
}

/// What discovery learned about one board.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardInfo {
    pub board_id: u8,
    pub node: u8,
    pub kind: BoardKind,
    pub hardware_version: u32,
    pub firmware_version: u32,
    pub status: u32,
    /// Register 12 (Rev 5+), when read.
    pub ethernet_status: Option<u32>,
    /// Register 15 (Rev 8+), when read.
    pub git_description: Option<u32>,
}

impl BoardInfo {
    pub fn layout(&self) -> Result<BlockLayout, WireError> {
        BlockLayout::new(self.firmware_version, self.kind)
    }
    pub fn fpga_generation(&self) -> Option<FpgaGeneration> {
        self.ethernet_status
            .map(FpgaGeneration::from_ethernet_status)
    }
}

/// Outcome for one board id.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BoardProbe {
    #[default]
    NotProbed,
    Found(BoardInfo),
    /// No reply.
    Missing,
    /// Replied, but unusable (unknown hardware, unsupported firmware, id mismatch, ...).
    Failed(PortError),
}

/// Result of a discovery, indexed by board id.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Discovery {
    pub boards: [BoardProbe; 16],
    /// Set by the full §3.3 sequence; None for the read-only discovery.
    pub mode: Option<EthMode>,
    /// Board id of the directly connected hub (full sequence only).
    pub hub: Option<u8>,
}

impl Discovery {
    const fn empty() -> Self {
        Self {
            boards: [BoardProbe::NotProbed; 16],
            mode: None,
            hub: None,
        }
    }
    pub fn found(&self, board: u8) -> Option<BoardInfo> {
        match self.boards.get(board as usize) {
            Some(BoardProbe::Found(i)) => Some(*i),
            _ => None,
        }
    }
    /// The first problem among `expected` boards, as the typed error naming the board.
    pub fn check(&self, expected: &[u8]) -> Result<(), PortError> {
        for &b in expected {
            match self.boards.get(b as usize) {
                Some(BoardProbe::Found(_)) => {}
                Some(BoardProbe::Failed(e)) => return Err(*e),
                Some(_) => return Err(PortError::BoardMissing { board: b }),
                None => return Err(PortError::BoardOutOfRange { board: b }),
            }
        }
        Ok(())
    }
}

fn classify(
    board: u8,
    node: u8,
    hw: u32,
    fw: u32,
    status: u32,
    expect_id: Option<u8>,
) -> Result<BoardInfo, PortError> {
    let kind = BoardKind::from_hardware_version(hw).map_err(|_| PortError::UnknownHardware {
        board,
        hardware: hw,
    })?;
    if BlockLayout::new(fw, kind).is_err() {
        return Err(PortError::UnsupportedFirmware {
            board,
            firmware: fw,
        });
    }
    let got = BoardStatus::new(status, kind).board_id();
    if let Some(exp) = expect_id
        && got != exp
    {
        return Err(PortError::BoardIdMismatch {
            node,
            expected: exp,
            got,
        });
    }
    Ok(BoardInfo {
        board_id: got,
        node,
        kind,
        hardware_version: hw,
        firmware_version: fw,
        status,
        ethernet_status: None,
        git_description: None,
    })
}

/// Reads hardware version, firmware version and status of one board; a timeout on the first
/// read means missing.
fn probe<P: Port>(port: &mut P, board: u8) -> BoardProbe {
    let hw = match port.read_quadlet(board, reg::HARDWARE_VERSION) {
        Ok(v) => v,
        Err(PortError::Timeout { .. }) => return BoardProbe::Missing,
        Err(e) => return BoardProbe::Failed(e),
    };
    let read = |port: &mut P, addr| port.read_quadlet(board, addr);
    let r =
        read(port, reg::FIRMWARE_VERSION).and_then(|fw| read(port, reg::STATUS).map(|st| (fw, st)));
    match r.and_then(|(fw, st)| classify(board, board, hw, fw, st, Some(board))) {
        Ok(info) => BoardProbe::Found(info),
        Err(e) => BoardProbe::Failed(e),
    }
}

/// Read-only discovery over any [`Port`]: hardware version, firmware version and status of each
/// expected board (quadlet reads only, no writes). Never fails; see [`Discovery::check`].
pub fn scan_boards<P: Port>(port: &mut P, expected: &[u8]) -> Discovery {
    let mut d = Discovery::empty();
    for &b in expected {
        if let Some(slot) = d.boards.get_mut(b as usize) {
            *slot = probe(port, b);
        }
    }
    d
}

impl<L: Link> EthPort<L> {
    /// Read-only discovery of the `expected` boards; a missing or unusable board is an error
    /// naming it ([`PortError::BoardMissing`], [`PortError::UnknownHardware`], ...).
    pub fn discover(&mut self, expected: &[u8]) -> Result<Discovery, PortError> {
        let d = scan_boards(self, expected);
        d.check(expected)?;
        Ok(d)
    }
}

impl<L: Link> WriteAccess<'_, L> {
    /// The dVRK's full Ethernet discovery (reference §3.3, `EthUdpPort::InitNodes` +
    /// `ScanNodes`), which writes:
    /// 1. broadcast-write the host IP to register 11 (byte order as the dVRK sends it: the
    ///    in-memory IPv4 address read as a little-endian quadlet, §9), then sleep `settle`
    ///    (the dVRK waits 200 ms);
    /// 2. read register 4 with broadcast + NOFORWARD; the directly connected hub answers;
    /// 3. broadcast-write 0 to the PHY request register (boards learn their node ids);
    /// 4. read the hub's registers 0, 7 and 12;
    /// 5. pick the mode: hub V3 with Rev ≥ 9 → Ethernet-only, else bridge (NOFORWARD off);
    /// 6. scan nodes 0–15 reading registers 4, 7, 12, 0 and 15 (15 only on Rev 8+); a node that
    ///    does not answer register 4 is absent. The node↔board map of the port is updated.
    ///
    /// Step 7 of the dVRK (bridge mode gap-count optimisation, a FireWire PHY write) is not done.
    pub fn init_nodes(
        &mut self,
        host_ip: Ipv4Addr,
        settle: Duration,
    ) -> Result<Discovery, PortError> {
        let ip_quadlet = u32::from_le_bytes(host_ip.octets());
        self.port.set_noforward(true);
        self.broadcast_write_quadlet(reg::IP_ADDRESS, ip_quadlet)?;
        if !settle.is_zero() {
            std::thread::sleep(settle);
        }
        let (hub_hw, hub_node) = self.port.broadcast_read_quadlet(reg::HARDWARE_VERSION)?;
        if BoardKind::from_hardware_version(hub_hw).is_err() {
            return Err(PortError::UnknownHardware {
                board: hub_node,
                hardware: hub_hw,
            });
        }
        self.broadcast_write_quadlet(reg::PHY_REQUEST, 0)?;
        let hub_status = self.port.read_quadlet_node(hub_node, reg::STATUS)?;
        let hub_fw = self
            .port
            .read_quadlet_node(hub_node, reg::FIRMWARE_VERSION)?;
        let hub_eth = self
            .port
            .read_quadlet_node(hub_node, reg::ETHERNET_STATUS)?;
        let mode =
            if FpgaGeneration::from_ethernet_status(hub_eth) == FpgaGeneration::V3 && hub_fw >= 9 {
                EthMode::EthernetOnly
            } else {
                EthMode::Bridge
            };
        self.port.set_noforward(mode == EthMode::EthernetOnly);
        let mut d = Discovery::empty();
        d.mode = Some(mode);
        for node in 0u8..16 {
            let hw = match self.port.read_quadlet_node(node, reg::HARDWARE_VERSION) {
                Ok(v) => v,
                Err(PortError::Timeout { .. }) => continue,
                Err(e) => return Err(e),
            };
            let fw = self.port.read_quadlet_node(node, reg::FIRMWARE_VERSION)?;
            let eth = self.port.read_quadlet_node(node, reg::ETHERNET_STATUS)?;
            let status = self.port.read_quadlet_node(node, reg::STATUS)?;
            let git = if fw >= 8 {
                Some(self.port.read_quadlet_node(node, reg::GIT_DESCRIPTION)?)
            } else {
                None
            };
            let id = BoardStatus::new(status, BoardKind::Qla).board_id();
            let probe = match classify(id, node, hw, fw, status, None) {
                Ok(mut info) => {
                    info.ethernet_status = Some(eth);
                    info.git_description = git;
                    self.port.set_node(id, node)?;
                    if node == hub_node {
                        d.hub = Some(id);
                    }
                    BoardProbe::Found(info)
                }
                Err(e) => BoardProbe::Failed(e),
            };
            if let Some(slot) = d.boards.get_mut(id as usize) {
                *slot = probe;
            }
        }
        if d.hub.is_none() {
            d.hub = Some(BoardStatus::new(hub_status, BoardKind::Qla).board_id());
        }
        self.port.set_hub_board(d.hub);
        Ok(d)
    }
}
