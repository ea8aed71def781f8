//! The clock and the real-time knobs of the loop thread, over libc.

use anyhow::{Result, bail};

use crate::config::RealtimeParams;

/// CLOCK_MONOTONIC in nanoseconds, the clock of the message headers. One syscall-free vDSO
/// call; never allocates.
pub use dvrk_ipc::monotonic_ns;

/// Sleeps until CLOCK_MONOTONIC reaches `t_ns` (absolute, so no drift accumulates).
#[inline]
pub fn sleep_until_ns(t_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if rc != libc::EINTR {
            return;
        }
    }
}

/// Whether this process may use `cpu` (it is in the affinity mask it was started with).
fn cpu_allowed(cpu: usize) -> bool {
    if cpu >= libc::CPU_SETSIZE as usize {
        return false;
    }
    // SAFETY: a zeroed cpu_set_t is a valid empty set, filled by the kernel; CPU_ISSET stays
    // within its bounds because cpu < CPU_SETSIZE.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            return false;
        }
        libc::CPU_ISSET(cpu, &set)
    }
}

/// The soft limit of `resource`, `None` when unlimited.
fn soft_limit(resource: libc::__rlimit_resource_t) -> Option<u64> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `r` is a valid, writable rlimit.
    let rc = unsafe { libc::getrlimit(resource, &mut r) };
    if rc != 0 || r.rlim_cur == libc::RLIM_INFINITY {
        None
    } else {
        Some(r.rlim_cur)
    }
}

/// Whether the process has `cap` in its effective set (from /proc/self/status; false when that
/// cannot be read).
fn has_capability(cap: u32) -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("CapEff:"))
                .and_then(|v| u64::from_str_radix(v.trim(), 16).ok())
        })
        .is_some_and(|eff| eff & (1u64 << cap) != 0)
}

const CAP_IPC_LOCK: u32 = 14;
const CAP_SYS_NICE: u32 = 23;

/// Checks, without changing anything, that [`apply`] can do what `rt` asks: the CPU exists and
/// is in this process's affinity mask, the priority is a SCHED_FIFO priority that this process
/// may use (CAP_SYS_NICE or RLIMIT_RTPRIO), and mlockall is permitted (CAP_IPC_LOCK or an
/// unlimited RLIMIT_MEMLOCK). `check-config` runs it, and `serve` before its loop.
pub fn check(rt: &RealtimeParams) -> Result<()> {
    if let Some(cpu) = rt.cpu
        && !cpu_allowed(cpu)
    {
        let ncpu = std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1);
        bail!(
            "realtime.cpu = {cpu}: not a CPU this process may run on (this machine has CPUs              0..{})",
            ncpu - 1
        );
    }
    if let Some(prio) = rt.fifo_priority {
        // SAFETY: plain syscalls without pointers.
        let (lo, hi) = unsafe {
            (
                libc::sched_get_priority_min(libc::SCHED_FIFO),
                libc::sched_get_priority_max(libc::SCHED_FIFO),
            )
        };
        if prio < lo || prio > hi {
            bail!("realtime.fifo_priority = {prio}: SCHED_FIFO priorities are {lo}..={hi}");
        }
        let allowed = has_capability(CAP_SYS_NICE)
            || soft_limit(libc::RLIMIT_RTPRIO).is_none_or(|l| l >= prio as u64);
        if !allowed {
            bail!(
                "realtime.fifo_priority = {prio}: not permitted (RLIMIT_RTPRIO is {}; give the                  service LimitRTPRIO={prio} or CAP_SYS_NICE)",
                soft_limit(libc::RLIMIT_RTPRIO).unwrap_or(0)
            );
        }
    }
    if rt.mlockall && !has_capability(CAP_IPC_LOCK) && soft_limit(libc::RLIMIT_MEMLOCK).is_some() {
        bail!(
            "realtime.mlockall = true: not permitted (RLIMIT_MEMLOCK is {} bytes; give the              service LimitMEMLOCK=infinity or CAP_IPC_LOCK)",
            soft_limit(libc::RLIMIT_MEMLOCK).unwrap_or(0)
        );
    }
    Ok(())
}

/// Applies CPU affinity, SCHED_FIFO and mlockall as configured. Each is an explicit request, so
/// a failure (usually missing privileges: LimitRTPRIO / LimitMEMLOCK) is an error, not a warning.
pub fn apply(rt: &RealtimeParams) -> Result<()> {
    check(rt)?;
    if let Some(cpu) = rt.cpu {
        // SAFETY: a zeroed cpu_set_t is a valid empty set; CPU_SET stays within its bounds
        // because cpu < ncpu <= CPU_SETSIZE.
        let rc = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
        };
        if rc != 0 {
            bail!(
                "realtime.cpu = {cpu}: sched_setaffinity failed: {}",
                std::io::Error::last_os_error()
            );
        }
    }
    if let Some(prio) = rt.fifo_priority {
        let param = libc::sched_param {
            sched_priority: prio,
        };
        // SAFETY: `param` is a valid sched_param for SCHED_FIFO.
        let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        if rc != 0 {
            bail!(
                "realtime.fifo_priority = {prio}: sched_setscheduler(SCHED_FIFO) failed: {} \
                 (needs CAP_SYS_NICE or LimitRTPRIO)",
                std::io::Error::last_os_error()
            );
        }
    }
    if rt.mlockall {
        // SAFETY: plain syscall with valid flags.
        let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
        if rc != 0 {
            bail!(
                "realtime.mlockall = true: mlockall failed: {} (needs LimitMEMLOCK=infinity)",
                std::io::Error::last_os_error()
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_clock_advances_and_sleep_until_reaches_its_deadline() {
        let t0 = monotonic_ns();
        let deadline = t0 + 2_000_000;
        sleep_until_ns(deadline);
        let t1 = monotonic_ns();
        assert!(
            t1 >= deadline,
            "woke at {t1}, before the deadline {deadline}"
        );
    }

    #[test]
    fn check_refuses_what_apply_would_refuse_without_changing_anything() {
        let e = check(&RealtimeParams {
            cpu: Some(999),
            fifo_priority: None,
            mlockall: false,
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("realtime.cpu = 999"), "{e}");
        let e = check(&RealtimeParams {
            cpu: None,
            fifo_priority: Some(100),
            mlockall: false,
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("realtime.fifo_priority = 100"), "{e}");
        assert!(e.contains("1..=99"), "{e}");
        // CPU 0 always exists and is in the mask.
        check(&RealtimeParams {
            cpu: Some(0),
            fifo_priority: None,
            mlockall: false,
        })
        .unwrap();
    }

    #[test]
    fn an_impossible_cpu_is_a_clear_error() {
        let rt = RealtimeParams {
            cpu: Some(100_000),
            fifo_priority: None,
            mlockall: false,
        };
        let e = apply(&rt).unwrap_err().to_string();
        assert!(e.contains("realtime.cpu = 100000"), "{e}");
    }
}
