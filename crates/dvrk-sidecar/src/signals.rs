//! The binary owns SIGTERM and SIGINT (iceoryx2's own handling is disabled): both set one flag
//! that the loops poll.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};

/// A stop request raised by SIGTERM or SIGINT.
#[derive(Clone)]
pub struct StopFlag(Arc<AtomicBool>);

impl StopFlag {
    /// Installs the handlers for SIGTERM and SIGINT.
    pub fn install() -> Result<Self> {
        let flag = Arc::new(AtomicBool::new(false));
        for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
            signal_hook::flag::register(sig, Arc::clone(&flag))
                .with_context(|| format!("installing the handler for signal {sig}"))?;
        }
        Ok(StopFlag(flag))
    }

    /// True once a stop was requested.
    pub fn raised(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// The flag itself, for APIs that take an `AtomicBool`.
    pub fn as_atomic(&self) -> &AtomicBool {
        &self.0
    }
}

impl StopFlag {
    /// A flag no signal raises: raised only by [`StopFlag::raise`] (e.g. the FireWire port's
    /// release when the console exits, crate::fw_life).
    pub fn manual() -> Self {
        StopFlag(Arc::new(AtomicBool::new(false)))
    }

    /// Raises the flag.
    pub fn raise(&self) {
        self.0.store(true, Ordering::Relaxed);
    }
}
