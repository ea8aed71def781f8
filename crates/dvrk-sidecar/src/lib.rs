//! The dvrk-sidecar service as a library: the binary's commands, and the per-cycle pipeline
//! that the benchmarks and end-to-end tests drive directly.
//!
//! `anyhow` is used here because this is the application layer (setup and commands); the
//! library crates below it have their own error enums.

pub mod bridge_cmd;
pub mod calib;
pub mod config;
pub mod console_follow;
pub mod crtk_standin;
pub mod cycle;
pub mod drive;
pub mod echo;
pub mod files;
pub mod formats;
pub mod fw_life;
pub mod offline;
pub mod out;
pub mod rt;
pub mod serve;
pub mod shape;
pub mod signals;
pub mod simcmd;
pub mod stats;
pub mod tap;
pub mod text;
pub mod watch;
