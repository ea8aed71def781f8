//! The predictive wait's model of the publisher: a period and a phase learnt from the samples'
//! publish times, and two adaptive margins around the predicted arrival. Pure arithmetic; the
//! subscription feeds it times and grades.
//!
//! The sidecar starts its cycles on an absolute-time grid (period P) and publishes each a
//! variable time later (its own wake-up lateness, the board read). The model estimates P over the
//! longest baseline it has (from the first sample it learnt to the newest) and the grid's phase
//! as the *earliest* arrival over the last `WINDOW` samples, so arrivals come at or after the
//! prediction. The subscriber sets its timer `guard` before the prediction, so that its own timer
//! lateness still leaves it polling before the sample lands, and polls until `spin_after` past
//! the prediction before it goes back to sleep on the event.
//!
//! Both margins are stochastic quantile trackers: a late wake-up raises the guard by
//! `GUARD_UP_NS`, an on-time one lowers it by `GUARD_DOWN_NS`, so it settles where
//! P(late) = DOWN / (UP + DOWN), about 3 %. Each is capped at `1 / MAX_MARGIN_DIVISOR` of the
//! period, which bounds the polling per cycle to a quarter period even for a publisher whose
//! timing is all over the place (its samples then come by the event, as they would without the
//! prediction).

/// Samples learnt before the prediction is used.
pub const LEARN_SAMPLES: u32 = 16;
/// Starting guard.
const GUARD_INIT_NS: f64 = 50_000.0;
/// Least guard.
const GUARD_MIN_NS: f64 = 5_000.0;
const GUARD_UP_NS: f64 = 30_000.0;
const GUARD_DOWN_NS: f64 = 1_000.0;
/// Least and starting polling time after the predicted arrival.
const SPIN_AFTER_MIN_NS: f64 = 20_000.0;
const SPIN_AFTER_UP_NS: f64 = 30_000.0;
const SPIN_AFTER_DOWN_NS: f64 = 1_000.0;
/// Guard and spin-after are each at most this fraction of the period.
const MAX_MARGIN_DIVISOR: f64 = 8.0;
/// Recent arrivals whose earliest gives the phase.
const WINDOW: usize = 128;

#[derive(Debug, Clone)]
pub struct Predictor {
    nominal_ns: f64,
    period_ns: f64,
    /// The first sample of this publisher that was learnt (seq, ns).
    anchor: (u64, u64),
    /// The newest samples (seq, ns), a ring of `filled` entries.
    recent: [(u64, u64); WINDOW],
    filled: usize,
    next: usize,
    /// Predicted arrival of the sample after the newest, ns.
    prediction_ns: u64,
    observed: u32,
    guard_ns: f64,
    spin_after_ns: f64,
}

impl Predictor {
    pub fn new(nominal_period_ns: u64) -> Self {
        let p = nominal_period_ns.max(1) as f64;
        Self {
            nominal_ns: p,
            period_ns: p,
            anchor: (0, 0),
            recent: [(0, 0); WINDOW],
            filled: 0,
            next: 0,
            prediction_ns: 0,
            observed: 0,
            guard_ns: GUARD_INIT_NS.min(p / MAX_MARGIN_DIVISOR),
            spin_after_ns: SPIN_AFTER_MIN_NS,
        }
    }

    pub fn ready(&self) -> bool {
        self.observed >= LEARN_SAMPLES
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns as u64
    }

    pub fn guard_ns(&self) -> u64 {
        self.guard_ns as u64
    }

    pub fn spin_after_ns(&self) -> u64 {
        self.spin_after_ns as u64
    }

    /// Predicted arrival (ns) of the sample after the newest one observed.
    pub fn next_arrival_ns(&self) -> u64 {
        self.prediction_ns
    }

    fn restart(&mut self, seq: u64, t_ns: u64) {
        self.period_ns = self.nominal_ns;
        self.anchor = (seq, t_ns);
        self.filled = 0;
        self.next = 0;
        self.observed = 0;
    }

    /// The newest sample `seq` landed (was published) at `t_ns`.
    pub fn observe(&mut self, seq: u64, t_ns: u64) {
        if self.observed == 0 {
            self.restart(seq, t_ns);
        } else if let Some(&(last_seq, last_t)) = self.newest()
            && (seq <= last_seq || t_ns <= last_t)
        {
            // A new publisher (seq starts again) or a clock oddity: learn afresh.
            self.restart(seq, t_ns);
        }
        let late = t_ns as f64 - self.prediction_ns as f64;
        let graded = self.ready() && self.newest().is_some_and(|&(s, _)| seq == s + 1);
        let (a_seq, a_t) = self.anchor;
        if seq - a_seq >= u64::from(LEARN_SAMPLES) {
            // The grid is exact; only the two ends' publish delays blur this, divided by n.
            self.period_ns = (t_ns - a_t) as f64 / (seq - a_seq) as f64;
        }
        self.recent[self.next] = (seq, t_ns);
        self.next = (self.next + 1) % WINDOW;
        self.filled = (self.filled + 1).min(WINDOW);
        let target = seq + 1;
        self.prediction_ns = self.recent[..self.filled]
            .iter()
            .map(|&(s, t)| t as f64 + (target - s) as f64 * self.period_ns)
            .fold(f64::INFINITY, f64::min)
            .max(0.0) as u64;
        self.observed = self.observed.saturating_add(1);
        if graded {
            let cap = self.period_ns / MAX_MARGIN_DIVISOR;
            if late > self.spin_after_ns {
                self.spin_after_ns = (self.spin_after_ns + SPIN_AFTER_UP_NS).min(cap);
            } else {
                self.spin_after_ns =
                    (self.spin_after_ns - SPIN_AFTER_DOWN_NS).max(SPIN_AFTER_MIN_NS);
            }
        }
    }

    fn newest(&self) -> Option<&(u64, u64)> {
        (self.filled > 0).then(|| &self.recent[(self.next + WINDOW - 1) % WINDOW])
    }

    /// Whether polling had started before the sample landed.
    pub fn graded(&mut self, on_time: bool) {
        let max = (self.period_ns / MAX_MARGIN_DIVISOR).max(GUARD_MIN_NS);
        if on_time {
            self.guard_ns = (self.guard_ns - GUARD_DOWN_NS).max(GUARD_MIN_NS);
        } else {
            self.guard_ns = (self.guard_ns + GUARD_UP_NS).min(max);
        }
    }

    /// Polling ended without a sample: allow more time after the prediction.
    pub fn missed(&mut self) {
        self.spin_after_ns =
            (self.spin_after_ns + SPIN_AFTER_UP_NS).min(self.period_ns / MAX_MARGIN_DIVISOR);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: u64 = 666_667;

    /// A deterministic spread of publish delays after the grid, 20..=80 µs.
    fn delay(k: u64) -> u64 {
        20_000 + (k * 7919 % 61) * 1_000
    }

    #[test]
    fn learns_a_period_that_differs_from_the_nominal_one() {
        let real = 1_000_000u64; // 1 kHz publisher, told 1.5 kHz
        let mut p = Predictor::new(P);
        let t0 = 5_000_000_000u64;
        for k in 0..2000 {
            p.observe(k + 1, t0 + k * real + delay(k));
        }
        assert!(p.ready());
        let err = (p.period_ns() as f64 - real as f64).abs();
        assert!(err < 500.0, "period {} vs {real}", p.period_ns());
    }

    #[test]
    fn predicts_the_floor_of_the_arrivals_not_their_mean() {
        let mut p = Predictor::new(P);
        let t0 = 1_000_000_000u64;
        for k in 0..3000 {
            p.observe(k + 1, t0 + k * P + delay(k));
        }
        // Next grid point 3000, whose earliest arrival is 20 µs after it.
        let floor = t0 + 3000 * P + 20_000;
        let pred = p.next_arrival_ns() as i64;
        assert!(
            (pred - floor as i64).abs() < 2_000,
            "predicted {pred}, floor {floor}"
        );
        // Samples never come much before the prediction.
        for k in 3000..3100 {
            let t = t0 + k * P + delay(k);
            assert!(t as i64 >= p.next_arrival_ns() as i64 - 2_000, "seq {k}");
            p.observe(k + 1, t);
        }
    }

    #[test]
    fn guard_rises_on_late_wake_ups_and_decays_when_on_time() {
        let mut p = Predictor::new(P);
        let g0 = p.guard_ns();
        p.graded(false);
        assert!(p.guard_ns() > g0);
        for _ in 0..10_000 {
            p.graded(true);
        }
        assert_eq!(p.guard_ns(), GUARD_MIN_NS as u64);
        for _ in 0..10_000 {
            p.graded(false);
        }
        assert_eq!(p.guard_ns(), P / 8, "capped at an eighth of a period");
    }

    #[test]
    fn a_restarted_publisher_is_learnt_afresh() {
        let mut p = Predictor::new(P);
        for k in 0..100 {
            p.observe(1000 + k, 1_000_000_000 + k * P);
        }
        assert!(p.ready());
        p.observe(1, 9_000_000_000);
        assert!(!p.ready(), "seq went back: a new publisher");
    }
}
