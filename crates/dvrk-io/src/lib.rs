//! dvrk-io: read-only access to dVRK controller boards (FPGA1394 + QLA, DQLA, dRAC) and
//! conversion of their raw bits to joint positions, velocities and efforts in SI units.
//!
//! - [`wire`]: pure, checked views and emitters for the board protocol.
//! - [`port`]: the read-only [`port::Port`] trait, the Ethernet protocol engine
//!   [`port::EthPort`] over a datagram [`port::Link`] (UDP, or dvrk-sim's in-process
//!   emulator), the explicit write capability, discovery, and test doubles.
//! - [`convert`]: conversion config ([`IoConfig`], from TOML or sawRobotIO1394 JSON v6) and
//!   the pure raw-to-SI functions producing an [`ArmSample`].
//! - [`reader`]: [`ArmReader`], one call per cycle, in shared or exclusive access mode.
//! - [`tap`]: [`TapDecoder`], the pure decoder of a passive tap of the console's own traffic.
//!
//! Facts and constants come from `shared/reference/dvrk-board-protocol.md`; doc comments cite
//! its sections as "reference §N".
//!
//! ```no_run
//! use dvrk_io::{AccessMode, ArmReader, ArmSample, IoConfig, UdpPort};
//! use dvrk_io::convert::IoParams;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // The application reads and parses the file (here with the `toml` crate); this crate
//! // validates it and never touches text formats or files itself.
//! let params: IoParams = toml::from_str(&std::fs::read_to_string("config/io/psm-classic.toml")?)?;
//! let cfg = IoConfig::from_params(params)?;
//! let mut port = UdpPort::open_udp("169.254.0.100:1394".parse()?)?;
//! port.discover(cfg.board_ids())?; // read-only: hardware, firmware, status of boards 6 and 7
//! let mut reader = ArmReader::new(port, cfg, AccessMode::Shared);
//! let mut sample = ArmSample::default();
//! let t_ns = 0; // the caller's CLOCK_MONOTONIC, once per cycle
//! if reader.read(t_ns, &mut sample).is_ok() {
//!     println!("yaw {} rad, insertion {} m", sample.position[0], sample.position[2]);
//! }
//! # Ok(())
//! # }
//! ```

// Index loops over the fixed 7-joint / 4x4 arrays read more clearly than zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod convert;
mod exact;
pub mod plausibility;
pub mod port;
pub mod tap;
pub mod wire;

pub use convert::{
    ArmSample, AxisHealth, BoardHealth, IoConfig, IoConfigError, MAX_BOARDS, NUM_JOINTS,
};
pub use port::{EthPort, Link, Port, PortError, UdpLink, UdpPort, WriteAccess};
pub use reader::{AccessMode, ArmReader, ReadError};
pub use tap::{LinkType, TapDecoder, TapEvent};
pub mod reader;
