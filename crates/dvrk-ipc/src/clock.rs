//! The two clocks of a [`crate::Header`]: `CLOCK_MONOTONIC` (order, intervals) and
//! `CLOCK_REALTIME` (ROS time).

/// One reading of `clock`. A vDSO call, no allocation.
#[inline]
fn read(clock: libc::clockid_t) -> libc::timespec {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; both clocks used here always exist on Linux.
    unsafe { libc::clock_gettime(clock, &mut ts) };
    ts
}

/// `CLOCK_MONOTONIC` in ns (the clock the publisher stamps its headers with).
#[inline]
pub fn monotonic_ns() -> u64 {
    let ts = read(libc::CLOCK_MONOTONIC);
    (ts.tv_sec as u64) * 1_000_000_000 + ts.tv_nsec as u64
}

/// `CLOCK_REALTIME` in ns since the Unix epoch (0 if the clock is set before 1970).
#[inline]
pub fn realtime_ns() -> u64 {
    let ts = read(libc::CLOCK_REALTIME);
    if ts.tv_sec < 0 {
        return 0;
    }
    (ts.tv_sec as u64)
        .saturating_mul(1_000_000_000)
        .saturating_add(ts.tv_nsec as u64)
}

/// The `CLOCK_REALTIME` time of the instant `t_mono_ns` (a `CLOCK_MONOTONIC` reading in the
/// recent past): the current realtime minus the monotonic time elapsed since. Two vDSO reads,
/// no allocation. For a publisher that stamped its sample earlier; `serve` reads
/// [`realtime_ns`] right after its monotonic sample stamp instead.
#[inline]
pub fn realtime_at(t_mono_ns: u64) -> u64 {
    let now_mono = monotonic_ns();
    let now_real = realtime_ns();
    now_real.saturating_sub(now_mono.saturating_sub(t_mono_ns))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn realtime_at_matches_the_wall_clock() {
        let mono = monotonic_ns();
        let real = realtime_at(mono);
        let wall = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos() as u64;
        // Same instant up to the time between the reads (generous: shared, noisy machines).
        assert!(wall >= real, "{wall} < {real}");
        assert!(wall - real < 1_000_000_000, "{}", wall - real);
        // An instant 5 ms ago maps 5 ms back on the realtime clock.
        let earlier = realtime_at(mono - 5_000_000);
        let d = real as i64 - earlier as i64;
        assert!((d - 5_000_000).abs() < 1_000_000, "{d}");
    }
}
