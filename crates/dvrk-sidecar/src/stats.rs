//! Loop statistics kept without allocation after construction: a fixed-bucket duration
//! histogram (for the p99 of the 1 Hz summary) and plain counters.

/// Histogram of durations with 1 µs buckets up to `MAX_US`, plus one overflow bucket.
pub struct DurationHistogram {
    buckets: Box<[u32]>,
    count: u64,
    max_ns: u64,
}

const MAX_US: usize = 20_000;

impl Default for DurationHistogram {
    fn default() -> Self {
        Self::new()
    }
}

impl DurationHistogram {
    /// Allocates the buckets once.
    pub fn new() -> Self {
        Self {
            buckets: vec![0; MAX_US + 1].into_boxed_slice(),
            count: 0,
            max_ns: 0,
        }
    }

    /// Records one duration. No allocation, no branches beyond a clamp.
    #[inline]
    pub fn record(&mut self, ns: u64) {
        let us = ((ns / 1_000) as usize).min(MAX_US);
        if let Some(b) = self.buckets.get_mut(us) {
            *b = b.saturating_add(1);
        }
        self.count += 1;
        self.max_ns = self.max_ns.max(ns);
    }

    pub fn count(&self) -> u64 {
        self.count
    }

    pub fn max_ns(&self) -> u64 {
        self.max_ns
    }

    /// The upper edge (ns) of the bucket holding quantile `q` (0..=1); `None` when empty.
    pub fn quantile_ns(&self, q: f64) -> Option<u64> {
        if self.count == 0 {
            return None;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (us, &n) in self.buckets.iter().enumerate() {
            seen += u64::from(n);
            if seen >= rank {
                return Some(if us == MAX_US {
                    self.max_ns
                } else {
                    (us as u64 + 1) * 1_000
                });
            }
        }
        Some(self.max_ns)
    }

    /// Clears for the next summary window (no allocation).
    pub fn reset(&mut self) {
        self.buckets.iter_mut().for_each(|b| *b = 0);
        self.count = 0;
        self.max_ns = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_come_from_the_recorded_distribution() {
        let mut h = DurationHistogram::new();
        assert_eq!(h.quantile_ns(0.99), None);
        // 990 samples at 10.5 µs and 10 at 300 µs: p50 is in the 10 µs bucket, p99 too,
        // p99.9 in the 300 µs bucket.
        for _ in 0..990 {
            h.record(10_500);
        }
        for _ in 0..10 {
            h.record(300_200);
        }
        assert_eq!(h.count(), 1000);
        assert_eq!(h.quantile_ns(0.5), Some(11_000));
        assert_eq!(h.quantile_ns(0.99), Some(11_000));
        assert_eq!(h.quantile_ns(0.999), Some(301_000));
        assert_eq!(h.max_ns(), 300_200);
        h.record(5_000_000_000);
        assert_eq!(
            h.quantile_ns(1.0),
            Some(5_000_000_000),
            "overflow bucket reports the max"
        );
        h.reset();
        assert_eq!(h.count(), 0);
        assert_eq!(h.quantile_ns(0.5), None);
    }
}
