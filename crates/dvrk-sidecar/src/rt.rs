//! The clock and the real-time knobs of the loop thread, over libc.

use anyhow::{Result, bail};

use crate::config::RealtimeParams;

/// CLOCK_MONOTONIC in nanoseconds. One syscall-free vDSO call; never allocates.
#[inline]
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    (ts.tv_sec as u64) * 1_000_000_000 + ts.tv_nsec as u64
}

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

/// Applies CPU affinity, SCHED_FIFO and mlockall as configured. Each is an explicit request, so
/// a failure (usually missing privileges: LimitRTPRIO / LimitMEMLOCK) is an error, not a warning.
pub fn apply(rt: &RealtimeParams) -> Result<()> {
    if let Some(cpu) = rt.cpu {
        let ncpu = std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1);
        if cpu >= ncpu {
            bail!(
                "realtime.cpu = {cpu}: this machine has CPUs 0..{}",
                ncpu - 1
            );
        }
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
