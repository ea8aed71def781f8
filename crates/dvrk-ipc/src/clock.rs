//! The two clocks of a [`crate::Header`]: `CLOCK_MONOTONIC` (order, intervals) and
//! `CLOCK_REALTIME` (ROS time).

/// `CLOCK_REALTIME` in ns since the Unix epoch (0 if the clock is set before 1970). A vDSO call.
#[inline]
pub fn realtime_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_REALTIME always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_REALTIME, &mut ts) };
    if ts.tv_sec < 0 {
        return 0;
    }
    (ts.tv_sec as u64)
        .saturating_mul(1_000_000_000)
        .saturating_add(ts.tv_nsec as u64)
}

/// The `CLOCK_REALTIME` time of the instant `monotonic_ns` (a `CLOCK_MONOTONIC` reading in the
/// recent past): the current realtime minus the monotonic time elapsed since. Two vDSO reads,
/// no allocation; what the publisher puts in [`crate::Header::sample_realtime_ns`].
#[inline]
pub fn realtime_at(monotonic_ns: u64) -> u64 {
    let now_mono = crate::monotonic_ns();
    let now_real = realtime_ns();
    now_real.saturating_sub(now_mono.saturating_sub(monotonic_ns))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn realtime_at_matches_the_wall_clock() {
        let mono = crate::monotonic_ns();
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
