//! The predictive wait's model of the publisher: a period and a phase learnt from the samples'
//! publish times, and two adaptive margins around the predicted arrival. Pure arithmetic; the
//! subscription feeds it times and grades.
//!
//! The sidecar starts its cycles on an absolute-time grid (period P) and publishes each a
//! variable time later (its own wake-up lateness, the board read); after a stall longer than a
//! period it restarts the grid from the end of the late cycle. The model smooths P over the gaps
//! between consecutive cycles (leaving out stalls) and takes the grid's phase as the median
//! (`PHASE_QUANTILE_PERCENT`) of the last `WINDOW` arrivals projected onto the next cycle, so a
//! restarted grid is learnt within half of `WINDOW` cycles; the guard covers the earlier half of
//! the arrivals. (A low quantile, 10 %, was used before: under load the sidecar's arrivals
//! spread by more than the polling window allows after the prediction, an eighth of a period,
//! and most samples came after the window had closed: 7-20 % of waits on time instead of 77 %,
//! 2026-11-23 23:21 UTC.) The subscriber sets its timer `guard` before the prediction, so that its own timer
//! lateness still leaves it polling before the sample lands, and polls until `spin_after` past
//! the prediction before it goes back to sleep on the event.
//!
//! Both margins are stochastic quantile trackers. A late wake-up raises the guard by UP =
//! `GUARD_DOWN_NS * (100 - p) / p`, an on-time one lowers it by DOWN = `GUARD_DOWN_NS`, so it
//! settles where P(late) = DOWN / (UP + DOWN) = p %, 10 % by default
//! ([`PREDICTIVE_LATE_PERCENT`]): at the p90 of the timer's wake-up lateness and the arrivals'
//! jitter together, not at its far tail. A subscriber may aim elsewhere
//! (`SubscribeOptions::predictive_late_percent`): the Python native module aims at 25 %, where
//! the interpreter's own hand-off hides most of a later wake-up and the shorter polling saves
//! about two points of a core (dvrk-py, `PYTHON_PREDICTIVE_LATE_PERCENT`). The tail of a timer
//! on a VM is hundreds of µs, and a guard sized to it would poll for most of each period; a
//! late wake-up costs nothing worse than the cycle event, which the wait watches at the same
//! time. (The guard aimed at the
//! p80 before 2026-11-24: with one subscriber in five woken late, the late ones sat just below
//! the median and pulled it up, p50 3.1-5.3 µs instead of 2.8-4.7 µs for 1.5-2 points of CPU
//! more. It aimed at the p95 until 2026-11-28, when the event path's own hand-off halved (the
//! short time slice, `sys::request_short_slice`), which made a late wake-up cheaper: at the p90,
//! two alternating pairs of latency-harness runs gave 86-88 % of waits in time instead of 91 %,
//! the same p50 (Rust 3.6-5.2 against 3.2-3.7 µs, the Python native wait 6.7-7.6 against
//! 6.5-9.5 µs) and less CPU (Rust 6.8-7.1 against 8.4-8.9 %, Python native 9.3-10.5 against
//! 11.9-12.0 %).) `spin_after` settles where about 3 % of samples come after it (each of those
//! costs a whole window of polling).
//! Each is capped at `1 / MAX_MARGIN_DIVISOR` of the
//! period, which bounds the polling per cycle to half a period even for a publisher whose
//! timing is all over the place (its samples then come by the event, as they would without the
//! prediction; and once most waits are late, only one in `PROBE_EVERY` polls). The cap was an
//! eighth of a period until 2026-11-27: on the development VM a futex timeout fires 41-46 µs late
//! at p50 and 91-106 µs at p95 on a quiet machine (35 and 126-138 µs under load), and the
//! arrivals spread from 37 µs before the prediction to 99 µs after it (p5, p95), so a guard held
//! at 83 µs was late in most waits: 14-15% of them started polling in time at one subscriber,
//! and the wait's p50 was the event path's (24-31 µs). With a quarter period (three runs of the
//! latency harness): 75-89% in time, p50 5.7-6.5 µs against 5.4-5.7 µs spinning, at 13-16% of a
//! core (5.5-6.0% before).

/// Samples learnt before the prediction is used.
pub const LEARN_SAMPLES: u32 = 16;
/// Starting guard.
const GUARD_INIT_NS: f64 = 50_000.0;
/// Least guard.
const GUARD_MIN_NS: f64 = 2_000.0;
const GUARD_DOWN_NS: f64 = 1_000.0;
/// The share of predicted waits (percent) whose wake-up may come after the sample, by default:
/// the guard rises by `GUARD_DOWN_NS * (100 - p) / p` on a late one (9 µs at 10 %).
pub const PREDICTIVE_LATE_PERCENT: u8 = 10;
/// The range a subscriber's late share is taken within (percent): beyond half of the waits late
/// the prediction would be the event path with extra wake-ups.
pub const PREDICTIVE_LATE_PERCENT_RANGE: core::ops::RangeInclusive<u8> = 1..=50;
/// Least and starting polling time after the predicted arrival.
const SPIN_AFTER_MIN_NS: f64 = 20_000.0;
const SPIN_AFTER_UP_NS: f64 = 30_000.0;
const SPIN_AFTER_DOWN_NS: f64 = 1_000.0;
/// Guard and spin-after are each at most this fraction of the period (see the module doc).
const MAX_MARGIN_DIVISOR: f64 = 4.0;
/// Recent arrivals whose median gives the phase: short, because the publisher restarts
/// its grid after every stall longer than a period (often, on a loaded PC).
const WINDOW: usize = 16;
/// The period is the mean of the gaps measured so far (the nominal period counting as one),
/// then a running mean over about this many gaps. Every arrival is projected up to `WINDOW`
/// periods ahead, so the estimate's noise is multiplied by up to 16: with a weight of 1/64 and
/// ±50 µs of arrival jitter it wandered by ±10 µs (661-676 µs for 666.7 µs, 2026-11-23), which put
/// the prediction about 100 µs early and the polling window closed before most samples came.
const PERIOD_GAPS: f64 = 1024.0;
/// The quantile (percent) of recent arrivals that is predicted.
const PHASE_QUANTILE_PERCENT: usize = 50;
/// Below this share of predictive waits that started polling in time (a running mean over
/// about `HIT_RATE_WAITS` graded waits), polling is skipped in all but one wait of
/// `PROBE_EVERY`: a publisher whose cycles come too irregularly to be predicted (a loaded PC
/// restarting its grid every few cycles) had each wait poll through its whole window, up to a
/// quarter period, and find the sample late anyway (13% of a core for the event path's
/// latency, 2026-11-26, load 4-6). Those waits sleep on the wake-up as the event path does;
/// the probes keep measuring, and the polling comes back once they are mostly on time.
const MIN_HIT_RATE: f64 = 0.25;
const HIT_RATE_WAITS: f64 = 16.0;
const PROBE_EVERY: u32 = 8;

#[derive(Debug, Clone)]
pub struct Predictor {
    nominal_ns: f64,
    period_ns: f64,
    /// Gaps averaged into `period_ns` since the last restart.
    period_gaps: f64,
    /// The newest samples (seq, ns), a ring of `filled` entries.
    recent: [(u64, u64); WINDOW],
    filled: usize,
    next: usize,
    /// Predicted arrival of the sample after the newest, ns.
    prediction_ns: u64,
    observed: u32,
    guard_ns: f64,
    spin_after_ns: f64,
    /// Running share of graded waits that were on time.
    hit_rate: f64,
    /// Waits since the last one that polled while the hit rate is low.
    skipped: u32,
    /// What a late wake-up adds to the guard (ns).
    guard_up_ns: f64,
}

impl Predictor {
    #[cfg(test)]
    pub fn new(nominal_period_ns: u64) -> Self {
        Self::with_late_percent(nominal_period_ns, PREDICTIVE_LATE_PERCENT)
    }

    /// A predictor whose guard settles where `late_percent` of the predicted waits wake up after
    /// the sample (taken within [`PREDICTIVE_LATE_PERCENT_RANGE`]): fewer late ones cost more polling.
    pub fn with_late_percent(nominal_period_ns: u64, late_percent: u8) -> Self {
        let late = f64::from(late_percent.clamp(
            *PREDICTIVE_LATE_PERCENT_RANGE.start(),
            *PREDICTIVE_LATE_PERCENT_RANGE.end(),
        ));
        let p = nominal_period_ns.max(1) as f64;
        Self {
            nominal_ns: p,
            period_ns: p,
            period_gaps: 0.0,
            recent: [(0, 0); WINDOW],
            filled: 0,
            next: 0,
            prediction_ns: 0,
            observed: 0,
            guard_ns: GUARD_INIT_NS.min(p / MAX_MARGIN_DIVISOR),
            spin_after_ns: SPIN_AFTER_MIN_NS,
            hit_rate: 1.0,
            skipped: 0,
            guard_up_ns: GUARD_DOWN_NS * (100.0 - late) / late,
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

    fn restart(&mut self) {
        self.period_ns = self.nominal_ns;
        self.period_gaps = 0.0;
        self.filled = 0;
        self.next = 0;
        self.observed = 0;
    }

    /// The newest sample `seq` landed (was published) at `t_ns`.
    pub fn observe(&mut self, seq: u64, t_ns: u64) {
        if self.observed == 0 {
            self.restart();
        } else if let Some(&(last_seq, last_t)) = self.newest()
            && (seq <= last_seq || t_ns <= last_t)
        {
            // A new publisher (seq starts again) or a clock oddity: learn afresh.
            self.restart();
        }
        let late = t_ns as f64 - self.prediction_ns as f64;
        let newest = self.newest().copied();
        let graded = self.ready() && newest.is_some_and(|(s, _)| seq == s + 1);
        if let Some((last_seq, last_t)) = newest
            && seq == last_seq + 1
        {
            // Consecutive cycles are one period apart on the publisher's grid; a longer gap is a
            // stall after which the publisher restarts its grid, and is left out.
            // Catch-up cycles after a short stall come back to back: only gaps near the nominal
            // period measure it (the consumer's nominal period must be right within 20 %).
            let d = (t_ns - last_t) as f64;
            let nominal = self.nominal_ns;
            if (0.8 * nominal..=1.2 * nominal).contains(&d) {
                self.period_gaps = (self.period_gaps + 1.0).min(PERIOD_GAPS);
                self.period_ns += (d - self.period_ns) / (self.period_gaps + 1.0);
            }
        }
        self.recent[self.next] = (seq, t_ns);
        self.next = (self.next + 1) % WINDOW;
        self.filled = (self.filled + 1).min(WINDOW);
        let target = seq + 1;
        // Each recent arrival projected onto the next grid point; the prediction is their median
        // (robust to the outliers at both ends; the guard covers the earlier half).
        let mut projected = [0.0f64; WINDOW];
        for (p, &(s, t)) in projected.iter_mut().zip(&self.recent[..self.filled]) {
            *p = t as f64 + (target - s) as f64 * self.period_ns;
        }
        let projected = &mut projected[..self.filled];
        let k = (self.filled * PHASE_QUANTILE_PERCENT) / 100;
        let (_, at, _) = projected.select_nth_unstable_by(k, f64::total_cmp);
        self.prediction_ns = at.max(0.0) as u64;
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

    /// Whether the coming wait should poll: always while most waits poll in time, else one
    /// wait in `PROBE_EVERY` (see `MIN_HIT_RATE`).
    pub fn poll_this_wait(&mut self) -> bool {
        if self.hit_rate >= MIN_HIT_RATE {
            self.skipped = 0;
            return true;
        }
        self.skipped += 1;
        if self.skipped >= PROBE_EVERY {
            self.skipped = 0;
            return true;
        }
        false
    }

    /// The running share of graded waits that started polling in time.
    #[cfg(test)]
    pub fn hit_rate(&self) -> f64 {
        self.hit_rate
    }

    fn score(&mut self, on_time: bool) {
        let x = if on_time { 1.0 } else { 0.0 };
        self.hit_rate += (x - self.hit_rate) / HIT_RATE_WAITS;
    }

    /// Whether polling had started before the sample landed.
    pub fn graded(&mut self, on_time: bool) {
        self.score(on_time);
        let max = (self.period_ns / MAX_MARGIN_DIVISOR).max(GUARD_MIN_NS);
        if on_time {
            self.guard_ns = (self.guard_ns - GUARD_DOWN_NS).max(GUARD_MIN_NS);
        } else {
            self.guard_ns = (self.guard_ns + self.guard_up_ns).min(max);
        }
    }

    /// Polling ended without a sample: allow more time after the prediction.
    pub fn missed(&mut self) {
        self.score(false);
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
        let real = 700_000u64; // 5 % slower than the nominal period
        let mut p = Predictor::new(P);
        let t0 = 5_000_000_000u64;
        for k in 0..2000 {
            p.observe(k + 1, t0 + k * real + delay(k));
        }
        // A stall and a burst of catch-up cycles do not disturb it.
        let t1 = t0 + 2000 * real + 5_000_000;
        for k in 0..5 {
            p.observe(2001 + k, t1 + k * 50_000);
        }
        assert!(p.ready());
        let err = (p.period_ns() as f64 - real as f64).abs();
        assert!(err < 500.0, "period {} vs {real}", p.period_ns());
    }

    #[test]
    fn predicts_the_median_of_the_recent_arrivals() {
        let mut p = Predictor::new(P);
        let t0 = 1_000_000_000u64;
        for k in 0..3000 {
            p.observe(k + 1, t0 + k * P + delay(k));
        }
        // Next grid point 3000, whose delays are spread 20..=80 µs: the median is 50 µs.
        let mid = t0 + 3000 * P + 50_000;
        let pred = p.next_arrival_ns() as i64;
        assert!(
            (pred - mid as i64).abs() < 8_000,
            "predicted {pred}, median {mid}"
        );
        // About half of the samples come before the prediction.
        let mut early = 0;
        for k in 3000..3610 {
            let t = t0 + k * P + delay(k);
            early += u32::from((t as i64) < p.next_arrival_ns() as i64);
            p.observe(k + 1, t);
        }
        assert!((230..=380).contains(&early), "{early} of 610 early");
    }

    #[test]
    fn the_period_estimate_does_not_wander_with_the_arrival_jitter() {
        // Publish delays 0..120 µs after an exact grid, pseudo-random: every arrival is projected
        // up to 16 periods ahead, so a period off by 1 µs misplaces the prediction by 16 µs.
        let mut p = Predictor::new(P);
        let mut x = 12345u64;
        let mut worst = 0.0f64;
        for k in 0..20_000u64 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let delay = (x >> 33) % 120_000;
            p.observe(k + 1, 1_000_000_000 + k * P + delay);
            if k >= 2000 {
                worst = worst.max((p.period_ns() as f64 - P as f64).abs());
            }
        }
        assert!(worst < 300.0, "period off by up to {worst} ns");
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
        assert_eq!(p.guard_ns(), P / 4, "capped at a quarter of a period");
    }

    /// The share of late wake-ups when the lateness is drawn as described below.
    fn late_share(mut p: Predictor) -> f64 {
        let mut x = 99u64;
        let mut late = 0u32;
        let n = 200_000u32;
        for k in 0..2 * n {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let r = (x >> 33) % 1000;
            let lateness = if r < 100 {
                r * 1_500
            } else {
                5_000 + (r % 40) * 1_000
            };
            let on_time = lateness <= p.guard_ns();
            if k >= n {
                late += u32::from(!on_time);
            }
            p.graded(on_time);
        }
        f64::from(late) / f64::from(n)
    }

    #[test]
    fn guard_settles_where_one_wake_up_in_ten_is_late() {
        // Wake-up lateness plus arrival jitter, pseudo-random with a long tail: 5..45 µs mostly,
        // one in ten up to 150 µs (the guard is capped at a quarter of a period, 167 µs).
        let frac = late_share(Predictor::new(P));
        assert!((0.075..=0.13).contains(&frac), "{:.1} % late", frac * 100.0);
    }

    #[test]
    fn a_subscriber_may_aim_at_another_late_share() {
        let frac = late_share(Predictor::with_late_percent(P, 25));
        assert!((0.21..=0.29).contains(&frac), "{:.1} % late", frac * 100.0);
        // Out of range: taken at the range's ends.
        let frac = late_share(Predictor::with_late_percent(P, 0));
        assert!(frac < 0.02, "{:.1} % late", frac * 100.0);
        let frac = late_share(Predictor::with_late_percent(P, 200));
        assert!((0.45..=0.55).contains(&frac), "{:.1} % late", frac * 100.0);
    }

    #[test]
    fn polling_pauses_while_waits_are_late_and_comes_back_with_the_probes() {
        let mut p = Predictor::new(P);
        assert!((0..100).all(|_| p.poll_this_wait()), "polls while on time");
        for _ in 0..64 {
            p.graded(false);
        }
        let polled = (0..80).filter(|_| p.poll_this_wait()).count();
        assert_eq!(
            polled,
            80 / PROBE_EVERY as usize,
            "one probe in {PROBE_EVERY}"
        );
        // Probes on time bring the polling back.
        let mut waits = 0;
        while !(0..PROBE_EVERY).all(|_| p.poll_this_wait()) {
            p.graded(true);
            waits += 1;
            assert!(waits < 100, "never came back");
        }
        assert!(p.hit_rate() >= MIN_HIT_RATE);
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
