//! The torque offset `tau_0(q)` of one joint (paper section 2, Table 1, and section 3).
//!
//! The paper measures the effort each of joints 1 and 2 needs with no external load by sweeping
//! the joint in 5-degree steps under position control; that effort is mostly the counterbalance
//! and is used as the internal torque `tau_int`. Here the sweep is a piecewise-linear table over
//! the joint's own position, held constant beyond its first and last points.

/// A validated piecewise-linear table `tau_0(q)`.
///
/// Built by [`crate::ComplianceConfig::from_params`], which guarantees at least one point, equal
/// lengths, finite values and strictly increasing positions. Looking a value up allocates nothing.
#[derive(Clone, Debug, PartialEq)]
pub struct TorqueOffsetTable {
    position_rad: Box<[f64]>,
    effort_nm: Box<[f64]>,
}

impl TorqueOffsetTable {
    /// Takes already validated columns (see `params::validate_torque_offset`).
    pub(crate) fn from_validated(position_rad: Vec<f64>, effort_nm: Vec<f64>) -> Self {
        debug_assert!(!position_rad.is_empty() && position_rad.len() == effort_nm.len());
        debug_assert!(position_rad.windows(2).all(|w| w[0] < w[1]));
        Self {
            position_rad: position_rad.into_boxed_slice(),
            effort_nm: effort_nm.into_boxed_slice(),
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

    /// `tau_0(q)` in N·m: linear interpolation between the two surrounding points, the first or
    /// last effort outside the table. A NaN position gives the first effort.
    pub fn lookup(&self, position_rad: f64) -> f64 {
        let xs = &self.position_rad;
        let ys = &self.effort_nm;
        // Number of points at or below q: 0 = before the table, len = after it.
        let i = xs.partition_point(|&x| x <= position_rad);
        match (i.checked_sub(1), xs.get(i), ys.get(i)) {
            (Some(lo), Some(&x1), Some(&y1)) => {
                let (x0, y0) = (xs[lo], ys[lo]);
                y0 + (y1 - y0) * ((position_rad - x0) / (x1 - x0))
            }
            (Some(_), _, _) => ys[ys.len() - 1],
            (None, _, _) => ys[0],
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
    fn interpolates_between_points() {
        let t = table();
        // Halfway between -0.2 and 0: (0.5 + 0.1) / 2 = 0.3.
        assert!((t.lookup(-0.1) - 0.3).abs() < 1e-15);
        // A quarter of the way from 0 to 0.4: 0.1 + 0.25 * (-0.4) = 0.0.
        assert!((t.lookup(0.1) - 0.0).abs() < 1e-15);
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
