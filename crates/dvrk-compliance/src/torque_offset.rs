//! The torque offset `tau_0(q)` of one joint (paper section 2, Table 1, and section 3).
//!
//! The paper measures the effort each of joints 1 and 2 needs with no external load by sweeping
//! the joint in 5-degree steps under position control; that effort is mostly the counterbalance
//! and is used as the internal torque `tau_int`. Here the sweep is a table over the joint's own
//! position, read between its points by a shape-preserving cubic ([`interpolate`]) and held
//! constant beyond its first and last points.
//!
//! Why not straight lines: the counterbalance's torque bends sharply near the middle of joint 1's
//! range (the 2017 sweep rises from 0.06 to 0.17 N·m between -0.1 and 0 rad, and the simulator's
//! `0.175 + 0.125 tanh(10 q)` models that). Between 5-degree points a chord misses such a curve
//! by up to 7.5 mN·m (the cubic by 2.9), and the error changes sign across the bend: as much as
//! the light contact the compensator is asked to see, taken for contact where it is not.

/// `tau_0(q)` from a table of strictly increasing `xs` and their `ys`: the monotone piecewise
/// cubic of Fritsch and Carlson (as MATLAB's `pchip`: node slopes the weighted harmonic mean of
/// the neighbouring chords, 0 where the data turns, one-sided three-point slopes at the ends),
/// which passes through every point, keeps a monotone stretch of the data monotone and never
/// overshoots it. Two points give the straight line; one, a constant; none, 0. Outside the table
/// and for a NaN `q`, the end value (the first one for NaN). Allocates nothing.
pub fn interpolate(xs: &[f64], ys: &[f64], q: f64) -> f64 {
    let n = xs.len().min(ys.len());
    let (xs, ys) = (&xs[..n], &ys[..n]);
    match segment(xs, ys, q) {
        Segment::Value(v) => v,
        Segment::Between(k) => hermite(
            xs,
            ys,
            k,
            node_slope(xs, ys, k),
            node_slope(xs, ys, k + 1),
            q,
        ),
    }
}

/// Where `q` falls in a table of `xs` (strictly increasing) and `ys` of one length.
enum Segment {
    /// Outside the table, a NaN `q` or an empty table: this value.
    Value(f64),
    /// Between points `k` and `k + 1`.
    Between(usize),
}

fn segment(xs: &[f64], ys: &[f64], q: f64) -> Segment {
    let (Some(&first), Some(&last)) = (ys.first(), ys.last()) else {
        return Segment::Value(0.0);
    };
    // Number of points at or below q: 0 = before the table (or NaN), len = after it.
    let i = xs.partition_point(|&x| x <= q);
    if i == 0 {
        Segment::Value(first)
    } else if i >= xs.len() {
        Segment::Value(last)
    } else {
        Segment::Between(i - 1)
    }
}

/// The cubic between points `k` and `k + 1` with node slopes `m0` and `m1`, at `q`.
#[inline]
fn hermite(xs: &[f64], ys: &[f64], k: usize, m0: f64, m1: f64, q: f64) -> f64 {
    let h = xs[k + 1] - xs[k];
    let t = (q - xs[k]) / h;
    let (t2, t3) = (t * t, t * t * t);
    (2.0 * t3 - 3.0 * t2 + 1.0) * ys[k]
        + (t3 - 2.0 * t2 + t) * h * m0
        + (-2.0 * t3 + 3.0 * t2) * ys[k + 1]
        + (t3 - t2) * h * m1
}

/// The shape-preserving cubic's slope at node `j` of a table of at least two points
/// ([`interpolate`]); it depends on the table only, so [`TorqueOffsetTable`] keeps them.
fn node_slope(xs: &[f64], ys: &[f64], j: usize) -> f64 {
    let n = xs.len();
    let width = |j: usize| xs[j + 1] - xs[j];
    let chord = |j: usize| (ys[j + 1] - ys[j]) / width(j);
    if n == 2 {
        return chord(0);
    }
    if j == 0 || j == n - 1 {
        // One-sided: the end chord and its neighbour, kept from turning or overshooting.
        let (a, b) = if j == 0 { (0, 1) } else { (n - 2, n - 3) };
        let (d0, d1, h0, h1) = (chord(a), chord(b), width(a), width(b));
        let m = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
        if m.signum() != d0.signum() || d0 == 0.0 {
            0.0
        } else if d0.signum() != d1.signum() && m.abs() > 3.0 * d0.abs() {
            3.0 * d0
        } else {
            m
        }
    } else {
        let (d0, d1) = (chord(j - 1), chord(j));
        if d0 * d1 <= 0.0 {
            0.0
        } else {
            let (h0, h1) = (width(j - 1), width(j));
            let (w0, w1) = (2.0 * h1 + h0, h1 + 2.0 * h0);
            (w0 + w1) / (w0 / d0 + w1 / d1)
        }
    }
}

/// A validated table `tau_0(q)`, read as [`interpolate`] reads it, with the cubic's node
/// slopes computed once when it is built (at each lookup they cost 7 ns of a 74 ns correction,
/// benches/README.md).
///
/// Built by [`crate::ComplianceConfig::from_params`], which guarantees at least one point, equal
/// lengths, finite values and strictly increasing positions. Looking a value up allocates nothing.
#[derive(Clone, Debug, PartialEq)]
pub struct TorqueOffsetTable {
    position_rad: Box<[f64]>,
    effort_nm: Box<[f64]>,
    /// The cubic's slope (N·m/rad) at each point; empty for a one-point table.
    slope: Box<[f64]>,
}

impl TorqueOffsetTable {
    /// Takes already validated columns (see `params::validate_torque_offset`).
    pub(crate) fn from_validated(position_rad: Vec<f64>, effort_nm: Vec<f64>) -> Self {
        debug_assert!(!position_rad.is_empty() && position_rad.len() == effort_nm.len());
        debug_assert!(position_rad.windows(2).all(|w| w[0] < w[1]));
        let slope = if position_rad.len() >= 2 {
            (0..position_rad.len())
                .map(|j| node_slope(&position_rad, &effort_nm, j))
                .collect()
        } else {
            Vec::new()
        };
        Self {
            position_rad: position_rad.into_boxed_slice(),
            effort_nm: effort_nm.into_boxed_slice(),
            slope: slope.into_boxed_slice(),
        }
    }

    /// The table's joint positions (rad), strictly increasing.
    pub fn position_rad(&self) -> &[f64] {
        &self.position_rad
    }

    /// The table's efforts (N·m), one per position.
    pub fn effort_nm(&self) -> &[f64] {
        &self.effort_nm
    }

    /// How far (rad) `position_rad` lies outside the table's positions: 0 inside, NaN for a NaN
    /// position. Beyond the table `tau_0` is held at its end value, which is wrong by the
    /// counterbalance's slope times this distance. A one-point table is a constant offset by
    /// intent (no sweep): it has no outside, 0 everywhere.
    pub fn distance_outside(&self, position_rad: f64) -> f64 {
        let (first, last) = (
            self.position_rad[0],
            self.position_rad[self.position_rad.len() - 1],
        );
        if self.position_rad.len() == 1 {
            0.0
        } else if position_rad.is_nan() {
            f64::NAN
        } else {
            (first - position_rad).max(position_rad - last).max(0.0)
        }
    }

    /// `tau_0(q)` in N·m: [`interpolate`] between the table's points, the first or last effort
    /// outside the table. A NaN position gives the first effort.
    pub fn lookup(&self, position_rad: f64) -> f64 {
        let (xs, ys) = (&self.position_rad[..], &self.effort_nm[..]);
        match segment(xs, ys, position_rad) {
            Segment::Value(v) => v,
            Segment::Between(k) => {
                hermite(xs, ys, k, self.slope[k], self.slope[k + 1], position_rad)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> TorqueOffsetTable {
        // A small sweep: -0.2 rad -> 0.5 N·m, 0 -> 0.1 N·m, 0.4 rad -> -0.3 N·m.
        TorqueOffsetTable::from_validated(vec![-0.2, 0.0, 0.4], vec![0.5, 0.1, -0.3])
    }

    #[test]
    fn distance_outside_is_zero_inside_and_grows_beyond_either_end() {
        let t = table();
        assert_eq!(t.distance_outside(-0.2), 0.0);
        assert_eq!(t.distance_outside(0.1), 0.0);
        assert_eq!(t.distance_outside(0.4), 0.0);
        assert!((t.distance_outside(-0.25) - 0.05).abs() < 1e-12);
        assert!((t.distance_outside(0.5) - 0.1).abs() < 1e-12);
        assert!(t.distance_outside(f64::NAN).is_nan());
        let constant = TorqueOffsetTable::from_validated(vec![0.0], vec![-0.125]);
        assert_eq!(constant.distance_outside(2.0), 0.0);
    }

    #[test]
    fn interpolates_between_points_without_leaving_them() {
        let t = table();
        // A monotone table: between its points the curve stays between them and keeps falling.
        let mut last = t.lookup(-0.2);
        for i in 1..=600 {
            let q = -0.2 + f64::from(i) * 0.001;
            let v = t.lookup(q);
            assert!(v <= last + 1e-15, "rises at {q}: {v} after {last}");
            assert!((-0.3..=0.5).contains(&v), "{q}: {v}");
            last = v;
        }
        // Two points: the straight line.
        let two = TorqueOffsetTable::from_validated(vec![0.0, 0.4], vec![0.1, -0.3]);
        assert!((two.lookup(0.1) - 0.0).abs() < 1e-15);
        // Where the data turns, the curve has a flat top at the turning point: no overshoot.
        let peak = TorqueOffsetTable::from_validated(vec![0.0, 1.0, 2.0], vec![0.0, 1.0, 0.0]);
        for i in 0..=200 {
            let v = peak.lookup(f64::from(i) * 0.01);
            assert!((0.0..=1.0).contains(&v), "{v}");
        }
    }

    #[test]
    fn a_counterbalance_bend_sampled_every_five_degrees_is_followed() {
        // The simulator's joint 1 (and the shape of the 2017 sweep): a chord between 5-degree
        // points misses it by 7.5 mN·m; the cubic by 2.9 (the bend is about one step wide, so
        // no curve through these points does much better without overshooting).
        let f = |q: f64| 0.175 + 0.125 * (10.0 * q).tanh();
        let step = 5f64.to_radians();
        let xs: Vec<f64> = (-9..=9).map(|i| f64::from(i) * step).collect();
        let ys: Vec<f64> = xs.iter().map(|&q| f(q)).collect();
        let t = TorqueOffsetTable::from_validated(xs.clone(), ys.clone());
        let (mut worst, mut worst_chord) = (0.0f64, 0.0f64);
        for i in 0..=1000 {
            let q = -0.7 + 1.4 * f64::from(i) / 1000.0;
            worst = worst.max((t.lookup(q) - f(q)).abs());
            let k = xs.partition_point(|&x| x <= q) - 1;
            let chord = ys[k] + (ys[k + 1] - ys[k]) * (q - xs[k]) / (xs[k + 1] - xs[k]);
            worst_chord = worst_chord.max((chord - f(q)).abs());
        }
        assert!(worst_chord > 7e-3, "{worst_chord}");
        assert!(
            worst < 0.4 * worst_chord,
            "cubic misses by {worst} N·m (chords: {worst_chord})"
        );
        assert!(worst < 3e-3, "cubic misses by {worst} N·m");
    }

    #[test]
    fn the_table_reads_as_interpolate_does_with_its_slopes_kept() {
        // Uneven steps, a turn, a flat stretch, two-point and one-point tables: the kept node
        // slopes must give exactly the per-call cubic everywhere, outside and NaN included.
        let cases: [(Vec<f64>, Vec<f64>); 4] = [
            (
                vec![-1.0, -0.7, -0.1, 0.0, 0.05, 0.4, 0.9],
                vec![0.3, 0.31, 0.2, 0.2, 0.25, -0.1, 0.6],
            ),
            (vec![-0.2, 0.0, 0.4], vec![0.5, 0.1, -0.3]),
            (vec![0.0, 0.4], vec![0.1, -0.3]),
            (vec![0.3], vec![0.25]),
        ];
        for (xs, ys) in cases {
            let t = TorqueOffsetTable::from_validated(xs.clone(), ys.clone());
            for i in 0..=2400 {
                let q = -1.2 + 2.4 * f64::from(i) / 2400.0;
                assert_eq!(
                    t.lookup(q).to_bits(),
                    interpolate(&xs, &ys, q).to_bits(),
                    "q = {q}, table {xs:?}"
                );
            }
            for q in xs.iter().copied().chain([f64::NAN]) {
                assert_eq!(t.lookup(q).to_bits(), interpolate(&xs, &ys, q).to_bits());
            }
        }
    }

    #[test]
    fn exact_points_return_their_effort() {
        let t = table();
        assert_eq!(t.lookup(-0.2), 0.5);
        assert_eq!(t.lookup(0.0), 0.1);
        assert_eq!(t.lookup(0.4), -0.3);
    }

    #[test]
    fn held_constant_beyond_the_ends() {
        let t = table();
        assert_eq!(t.lookup(-3.0), 0.5);
        assert_eq!(t.lookup(3.0), -0.3);
        assert_eq!(t.lookup(f64::NEG_INFINITY), 0.5);
        assert_eq!(t.lookup(f64::INFINITY), -0.3);
        assert_eq!(t.lookup(f64::NAN), 0.5);
    }

    #[test]
    fn single_point_is_constant() {
        let t = TorqueOffsetTable::from_validated(vec![0.3], vec![0.25]);
        for q in [-1.0, 0.3, 2.0] {
            assert_eq!(t.lookup(q), 0.25);
        }
    }
}
