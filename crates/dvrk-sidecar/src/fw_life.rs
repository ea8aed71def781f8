//! On FireWire the service follows the console's life cycle. sawRobotIO1394 refuses to start
//! while another process holds the FireWire device open, so the service must hold it only while
//! the console does:
//! 1. before opening the port it waits until another process holds `/dev/fwN` (the console
//!    started);
//! 2. while it reads, a thread looks once a second; when no other process has held the device
//!    for [`RELEASE_AFTER`], the console has exited: the loop ends, the port is closed, and the
//!    service waits again (step 1), so the console can be restarted at any time.
//!
//! Who holds the device is read from `/proc/PID/fd`, which shows only the processes of this
//! account (or every process to root): the console must run under the service's account, as
//! deploy/install.sh sets it up.

use std::path::{Path, PathBuf};
use std::time::Duration;

use tracing::{info, warn};

use crate::signals::StopFlag;

/// How long the device must have no other holder before the service lets it go.
pub const RELEASE_AFTER: Duration = Duration::from_secs(1);
/// How often holders are looked for.
const POLL: Duration = Duration::from_millis(250);

/// Process ids other than `except` with a file descriptor open on `dev` that this process may
/// inspect. Setup and housekeeping only: it reads directories and allocates.
pub fn holders(dev: &Path, except: u32) -> Vec<u32> {
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    let mut found = Vec::new();
    for p in procs.flatten() {
        let Some(pid) = p.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        if pid == except {
            continue;
        }
        let Ok(fds) = std::fs::read_dir(p.path().join("fd")) else {
            continue;
        };
        if fds
            .flatten()
            .any(|fd| std::fs::read_link(fd.path()).is_ok_and(|t| t == dev))
        {
            found.push(pid);
        }
    }
    found
}

/// The device of FireWire port `n`.
pub fn device(n: u32) -> PathBuf {
    PathBuf::from(format!("/dev/fw{n}"))
}

/// Waits until another process holds `dev`; false when stopped first. Logs once, then every
/// 10 s, and tells systemd (`STATUS=`).
pub fn wait_for_console(dev: &Path, stop: &StopFlag) -> bool {
    let me = std::process::id();
    let mut waited = Duration::ZERO;
    let mut next_log = Duration::ZERO;
    loop {
        if stop.raised() {
            return false;
        }
        let h = holders(dev, me);
        if !h.is_empty() {
            info!(device = %dev.display(), console_pids = ?h, "the console holds the FireWire device: opening it");
            return true;
        }
        // The unit is Type=notify with a watchdog: waiting for the console (for hours, maybe)
        // is a normal state, not a start-up that hangs.
        let _ = sd_notify::notify(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Watchdog,
        ]);
        if waited >= next_log {
            let status = format!(
                "waiting for the dVRK console to open {} (the service opens it after the console, \
                 which refuses to start while another process holds it; the console must run \
                 under this service's account to be seen)",
                dev.display()
            );
            warn!("{status}");
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&status)]);
            next_log = waited + Duration::from_secs(10);
        }
        std::thread::sleep(POLL);
        waited += POLL;
    }
}

/// Starts the thread that raises the returned flag when no other process has held `dev` for
/// [`RELEASE_AFTER`], or when `stop` is raised; the loop runs on that flag.
pub fn watch_release(dev: PathBuf, stop: StopFlag) -> std::io::Result<StopFlag> {
    let release = StopFlag::manual();
    let r = release.clone();
    std::thread::Builder::new()
        .name("fw-release".into())
        .spawn(move || {
            let me = std::process::id();
            let mut alone = Duration::ZERO;
            while !stop.raised() && !r.raised() {
                std::thread::sleep(POLL);
                if holders(&dev, me).is_empty() {
                    alone += POLL;
                    if alone >= RELEASE_AFTER {
                        info!(device = %dev.display(), "the console closed the FireWire device: releasing it");
                        break;
                    }
                } else {
                    alone = Duration::ZERO;
                }
            }
            r.raise();
        })?;
    Ok(release)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A real process holding a file open is found; after it exits it is not.
    #[test]
    fn a_process_holding_the_device_is_found_and_gone_after_it_exits() {
        let dir = std::env::temp_dir().join(format!("dvrk-fw-life-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let dev = dir.join("fw9");
        std::fs::write(&dev, b"").unwrap();
        let me = std::process::id();
        assert!(holders(&dev, me).is_empty());
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .stdin(std::fs::File::open(&dev).unwrap())
            .spawn()
            .unwrap();
        let pid = child.id();
        let mut seen = false;
        for _ in 0..200 {
            if holders(&dev, me).contains(&pid) {
                seen = true;
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(seen, "the child holding {} was not found", dev.display());
        // This process's own descriptors do not count.
        let own = std::fs::File::open(&dev).unwrap();
        child.kill().unwrap();
        child.wait().unwrap();
        assert!(holders(&dev, me).is_empty());
        drop(own);
    }

    /// The release flag rises once nobody else holds the device, and waiting ends on a stop.
    #[test]
    fn release_is_raised_when_the_holder_goes() {
        let dir = std::env::temp_dir().join(format!("dvrk-fw-release-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let dev = dir.join("fw8");
        std::fs::write(&dev, b"").unwrap();
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .stdin(std::fs::File::open(&dev).unwrap())
            .spawn()
            .unwrap();
        let stop = StopFlag::manual();
        assert!(wait_for_console(&dev, &stop));
        let release = watch_release(dev.clone(), stop.clone()).unwrap();
        std::thread::sleep(RELEASE_AFTER * 2);
        assert!(!release.raised(), "released while the holder still runs");
        child.kill().unwrap();
        child.wait().unwrap();
        let mut raised = false;
        for _ in 0..100 {
            if release.raised() {
                raised = true;
                break;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        assert!(raised, "not released after the holder exited");
        let stopped = StopFlag::manual();
        stopped.raise();
        assert!(!wait_for_console(&dev, &stopped));
    }
}
