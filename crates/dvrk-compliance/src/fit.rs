//! Parameter fitting from calibration data (paper sections 3-4).
//!
//! Input is a list of [`DataRow`]s, one averaged step of a calibration procedure each, the same
//! rows the calibration CSV file holds. Two fits exist:
//!
//! - [`fit_clamp`] / [`fit_joint`]: the clamp-beam experiment. Per joint and insertion depth,
//!   `tau_ext = effort - torque_offset`, a least-squares line of `tau_ext` against the joint
//!   position for each branch (direction of motion, or sign of the load: see below), stiffness =
//!   mean of the two slopes, backlash = half the horizontal gap between the two lines at
//!   `tau_ext = 0`. Across depths, 1/K(L) is a least-squares
//!   cubic of stiffness against insertion and the backlash is the mean over depths.
//! - [`fit_torque_offset`]: the unloaded sweep, averaged per angle into a tau_0(q) table, with how
//!   much it varies with depth.
//!
//! # Which rows go into which line, which are left out, and why
//!
//! Eq. 1 says the joint angle leads the shaft by `delta` on one side of the play or the other,
//! plus `K * tau_ext`. Which side the shaft is pressed against depends on the mechanism, and two
//! kinds of clamp data exist:
//!
//! - **Hysteresis by direction of motion** (the paper's Fig. 5, and the real 2017 recordings):
//!   each direction of motion traces its own straight line over the whole torque range, the two
//!   lines parallel and offset. Rows are split by direction of motion (*motion split*). Right
//!   after a reversal the torque is still reversing: for a joint travel of about the full
//!   horizontal gap between the lines (`2 * delta` for a play) it lies between the two lines, on
//!   neither. So, per run of rows moving one way (a *segment*), the rows whose position is less
//!   than the current gap estimate away from the reversal point (the position of the last row
//!   before the segment) are left out. The first segment of a depth is treated the same way from
//!   its first row, because the side the shaft rests on when a depth starts is unknown.
//! - **A dead zone** (a play whose shaft side is set by the load alone, as dvrk-sim models it):
//!   both directions of motion trace the same curve, a line of slope 1/K for `tau_ext > 0`
//!   crossing zero at `q_tip + delta`, a flat zero inside the play, and a parallel line for
//!   `tau_ext < 0` crossing at `q_tip - delta`. Lines per direction of motion cannot see this
//!   (both directions give the same line, the gap is zero); the rows are split by the sign of
//!   `tau_ext` instead (*load split*, the two branches of Eq. 1). Left out are rows inside the
//!   play (position strictly between the two zero crossings), rows whose |tau_ext| is within
//!   3 residual RMS of zero, whose side is only noise, and rows within a play's width of the play
//!   that are off their side's line by more than that. The last are the flat part: it lies at the
//!   torque offset's error at that depth, not at zero, so the zero crossings bound the play only
//!   up to that error over the stiffness (on the simulator's joint 1, whose internal torque is
//!   steepest near the clamp's pose, keeping them made the play 0.5% smaller).
//!
//! - **A dead zone behind a motor with friction** (an arm whose controller stops a stuck motor
//!   short of its setpoint: each row measures the load plus up to the friction, in the direction
//!   the row moved): the load split's two lines and one torque `friction_nm * direction` on every
//!   row, fitted together (*load split with friction*, [`Branches::LoadFriction`]). Neither plain
//!   split describes such data: on a console stand-in's arm of 2.5 mrad play and 20 mN·m
//!   friction the motion split won, and gave stiffnesses 6-8% low and half the play. It nests
//!   both plain splits, so it never explains data worse; it is chosen only when it explains a
//!   joint's rows better by [`FRICTION_SPLIT_MARGIN`] (on the 2017 recordings it comes to 0.85
//!   of the motion split's residual, and the motion split stays).
//!
//! [`BranchRule::Auto`] (the default) fits both plain splits and keeps the one whose lines explain
//! the data better: the smaller median, over every row, of the distance from the row's torque to
//! its own branch line (the same rows count for both splits, and the median ignores the minority of
//! turnaround or play rows). The kind of hysteresis belongs to the mechanism, not to one depth, so
//! [`fit_joint`] makes the choice once per joint from the scores summed over its depths (one depth
//! of the 2017 file alone is a near tie; over its 14 depths, with its torque-offset sweep, the
//! motion split's median residuals sum to 0.29 N·m, the load split's to 1.04). A depth where the
//! chosen split cannot be fitted but the other can uses the other. On dead-zone data the load split
//! fits exactly. The result says which one was used ([`DepthFit::branches`]).
//!
//! Neither set of left-out rows is known before the lines are, so both fits iterate: a fit with
//! every row, then the exclusion that fit implies, refit, until the set of left-out rows stops
//! changing (at most [`FitOptions::max_transition_iterations`] rounds). Rows with direction 0
//! (stationary) are never in a motion line but still mark where a segment starts. How many rows
//! were left out is reported per depth ([`DepthFit::excluded`]).
//!
//! # Direction of motion
//!
//! A row's direction comes from its `direction` column. When every row of a depth says 0 (files
//! that do not record it, such as the dVRK 2017 layout), it comes from the sign of the position
//! change from the previous row of the same depth, in recorded order. A change smaller than
//! [`FitOptions::direction_step_fraction`] of the depth's median step is noise (for example the
//! second sample the 2017 procedure records at each turnaround, at the same setpoint) and keeps the
//! previous direction; rows before the first real change take the first direction seen.
//!
//! # Settling samples
//!
//! A row whose insertion differs from the median insertion of its depth by more than
//! [`FitOptions::insertion_tolerance_m`] was recorded while joint 3 was still moving to the depth
//! (the 2017 files start with one such row) and is dropped before anything else.

use nalgebra::{DMatrix, DVector};

/// One averaged step of a calibration procedure: one line of the calibration CSV file
/// `joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DataRow {
    /// Paper joint number: 1 (yaw) or 2 (pitch).
    pub joint: u8,
    /// Insertion depth index within the procedure (0-based).
    pub depth_index: u32,
    /// Joint 3 position L (m).
    pub insertion_m: f64,
    /// Position of the joint under test (rad).
    pub position_rad: f64,
    /// Measured effort of the joint under test (N·m).
    pub effort_nm: f64,
    /// tau_0 in effect at this position when recorded (N·m). Ignored by the torque-offset fit,
    /// whose samples are the unloaded efforts themselves.
    pub torque_offset_nm: f64,
    /// Direction of motion: +1, -1, or 0 (stationary / not recorded).
    pub direction: i8,
}

impl DataRow {
    /// External torque, `effort - torque_offset` (N·m).
    pub fn tau_ext_nm(&self) -> f64 {
        self.effort_nm - self.torque_offset_nm
    }
}

/// Knobs of the fits. `Default` gives the values documented on each field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Minimum rows per direction line at one depth (default 5).
    pub min_points_per_direction: usize,
    /// Position changes smaller than this fraction of the depth's median step carry no direction
    /// (default 0.25). Also the angle-grouping tolerance of the torque-offset table.
    pub direction_step_fraction: f64,
    /// Rows further than this from their depth's median insertion are settling samples and are
    /// dropped (default 0.002 m).
    pub insertion_tolerance_m: f64,
    /// Rounds of the turnaround / play exclusion (default 10).
    pub max_transition_iterations: usize,
    /// How rows are split into the two lines (default [`BranchRule::Auto`]).
    pub branches: BranchRule,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            min_points_per_direction: 5,
            direction_step_fraction: 0.25,
            insertion_tolerance_m: 0.002,
            max_transition_iterations: 10,
            branches: BranchRule::Auto,
        }
    }
}

/// Why a fit failed. Each names the joint (paper number) and, where it applies, the depth index
/// and the offending value. No partial result is returned with an error.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FitError {
    #[error("joint {joint}: no data rows")]
    NoData { joint: u8 },
    #[error("joint {joint} must be 1 or 2")]
    BadJoint { joint: u8 },
    #[error("joint {joint} depth {depth_index} row {row}: {field} is not finite")]
    NonFinite {
        joint: u8,
        depth_index: u32,
        row: usize,
        field: &'static str,
    },
    #[error(
        "joint {joint} depth {depth_index}: {got} usable points moving in direction {direction:+}, need at least {need}"
    )]
    TooFewPoints {
        joint: u8,
        depth_index: u32,
        direction: i8,
        got: usize,
        need: usize,
    },
    #[error(
        "joint {joint} depth {depth_index}: the joint only moved in direction {direction:+}; the clamp procedure must reverse"
    )]
    SingleDirection {
        joint: u8,
        depth_index: u32,
        direction: i8,
    },
    #[error(
        "joint {joint} depth {depth_index}: all positions moving in direction {direction:+} are equal, no line can be fitted"
    )]
    DegeneratePositions {
        joint: u8,
        depth_index: u32,
        direction: i8,
    },
    #[error(
        "joint {joint} depth {depth_index}: the direction {direction:+} line has slope {slope_nm_per_rad} N·m/rad; stiffness must be positive"
    )]
    NonPositiveStiffness {
        joint: u8,
        depth_index: u32,
        direction: i8,
        slope_nm_per_rad: f64,
    },
    #[error("joint {joint}: {got} distinct insertion depths, a cubic 1/K(L) needs at least {need}")]
    TooFewDepths { joint: u8, got: usize, need: usize },
    #[error(
        "joint {joint}: the fitted cubic 1/K(L) is {value_nm_per_rad} N·m/rad at L = {insertion_m} m, inside the depth range; it must stay > 0"
    )]
    CubicNotPositive {
        joint: u8,
        insertion_m: f64,
        value_nm_per_rad: f64,
    },
    #[error("joint {joint}: torque-offset sweep covers {got} distinct angles, need at least 2")]
    TooFewAngles { joint: u8, got: usize },
}

/// A least-squares line `tau_ext = slope * q + intercept`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Line {
    /// N·m/rad.
    pub slope: f64,
    /// N·m.
    pub intercept: f64,
    /// Rows the line was fitted to.
    pub points: usize,
    /// Root-mean-square residual (N·m).
    pub residual_rms_nm: f64,
}

impl Line {
    /// Position where the line crosses `tau_ext = 0` (rad).
    pub fn zero_crossing_rad(&self) -> f64 {
        -self.intercept / self.slope
    }

    /// tau_ext on the line at `q` (N·m).
    pub fn at(&self, q: f64) -> f64 {
        self.slope * q + self.intercept
    }
}

/// Result at one insertion depth of one joint.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthFit {
    pub joint: u8,
    pub depth_index: u32,
    /// Mean insertion of the rows kept (m).
    pub insertion_m: f64,
    /// `[+ line, - line]`: rows moving + / - (motion split) or with tau_ext > 0 / < 0 (load split).
    pub lines: [Line; 2],
    /// Mean of the two slopes (N·m/rad).
    pub stiffness_nm_per_rad: f64,
    /// Half the horizontal gap between the two lines at tau_ext = 0 (rad, >= 0).
    pub backlash_rad: f64,
    /// Signed gap `zero(-) - zero(+)` (rad). A play gives a negative gap (the `+` line crosses
    /// zero to the right); friction-like hysteresis, where the torque leads the motion, a positive
    /// one.
    pub hysteresis_gap_rad: f64,
    /// Which split the lines come from.
    pub branches: Branches,
    /// The motor friction taken out of the rows (N·m; [`Branches::LoadFriction`] only, else 0):
    /// a row moving `+` measured the load plus this much.
    pub friction_nm: f64,
    /// Rows in the two line fits.
    pub points: usize,
    /// Rows left out: turnaround transitions (motion split) or rows inside the play (load split).
    pub excluded: usize,
    /// Rows dropped as settling samples (insertion off the depth).
    pub dropped_settling: usize,
    /// Rows with no direction (stationary), not in a line.
    pub stationary: usize,
    /// Whether the directions were derived from position changes.
    pub directions_derived: bool,
}

/// Result for one joint over all depths.
#[derive(Clone, Debug, PartialEq)]
pub struct JointFit {
    pub joint: u8,
    /// Ascending depth index.
    pub depths: Vec<DepthFit>,
    /// 1/K(L) = c3 L^3 + c2 L^2 + c1 L + c0, `[c3, c2, c1, c0]` (N·m/rad, L in m).
    pub inverse_compliance_nm_per_rad: [f64; 4],
    /// Mean backlash over depths (rad).
    pub backlash_rad: f64,
    /// The relative scatter (1 sigma) of the per-depth backlashes around their mean,
    /// `std / mean` with `n - 1` degrees of freedom; `None` with one depth or a zero mean.
    /// Written to the parameter file as `backlash_rel_sigma`.
    pub backlash_rel_sigma: Option<f64>,
    /// Coefficient of determination of the cubic against the per-depth stiffnesses.
    pub r_squared: f64,
    /// The relative scatter (1 sigma) of the per-depth `1/K` around the cubic,
    /// `sqrt(sum(((k_i - cubic(L_i)) / cubic(L_i))^2) / (n - 4))`; `None` with 4 depths (no
    /// degree of freedom left). Written to the parameter file as `inverse_compliance_rel_sigma`.
    pub rel_sigma: Option<f64>,
    /// `[min, max]` insertion of the depths (m): where the cubic is valid.
    pub insertion_range_m: [f64; 2],
}

/// The relative scatter of `k` around the cubic `c` at `l` (see [`JointFit::rel_sigma`]).
pub fn relative_scatter(c: &[f64; 4], l: &[f64], k: &[f64]) -> Option<f64> {
    let n = l.len().min(k.len());
    if n <= 4 {
        return None;
    }
    let ss: f64 = l
        .iter()
        .zip(k)
        .map(|(&l, &k)| {
            let fit = eval_cubic(c, l);
            ((k - fit) / fit).powi(2)
        })
        .sum();
    let r = (ss / (n - 4) as f64).sqrt();
    r.is_finite().then_some(r)
}

/// The sample standard deviation of `values` over their `mean`, `None` with fewer than two
/// values or a mean that is not positive (see [`JointFit::backlash_rel_sigma`]).
pub fn relative_spread(values: impl ExactSizeIterator<Item = f64>, mean: f64) -> Option<f64> {
    let n = values.len();
    if n < 2 || mean.is_nan() || mean <= 0.0 {
        return None;
    }
    let ss: f64 = values.map(|v| (v - mean).powi(2)).sum();
    let r = (ss / (n - 1) as f64).sqrt() / mean;
    r.is_finite().then_some(r)
}

/// Evaluates `c3 L^3 + c2 L^2 + c1 L + c0` (Horner).
pub fn eval_cubic(c: &[f64; 4], l: f64) -> f64 {
    ((c[0] * l + c[1]) * l + c[2]) * l + c[3]
}

/// The minimum of the cubic on `[a, b]` and where it is: `(L, value)`. Checks both ends and every
/// stationary point inside, so it is exact, not sampled.
pub fn cubic_min_on(c: &[f64; 4], range: [f64; 2]) -> (f64, f64) {
    let [a, b] = range;
    let mut best = (a, eval_cubic(c, a));
    let mut consider = |l: f64| {
        if l >= a && l <= b {
            let v = eval_cubic(c, l);
            if v < best.1 {
                best = (l, v);
            }
        }
    };
    consider(b);
    // derivative 3 c3 L^2 + 2 c2 L + c1
    let (qa, qb, qc) = (3.0 * c[0], 2.0 * c[1], c[2]);
    if qa.abs() > f64::MIN_POSITIVE {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            let s = disc.sqrt();
            consider((-qb + s) / (2.0 * qa));
            consider((-qb - s) / (2.0 * qa));
        }
    } else if qb.abs() > f64::MIN_POSITIVE {
        consider(-qc / qb);
    }
    best
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

fn check_finite(rows: &[DataRow]) -> Result<(), FitError> {
    for (i, r) in rows.iter().enumerate() {
        let fields = [
            ("insertion_m", r.insertion_m),
            ("position_rad", r.position_rad),
            ("effort_nm", r.effort_nm),
            ("torque_offset_nm", r.torque_offset_nm),
        ];
        for (field, v) in fields {
            if !v.is_finite() {
                return Err(FitError::NonFinite {
                    joint: r.joint,
                    depth_index: r.depth_index,
                    row: i,
                    field,
                });
            }
        }
    }
    Ok(())
}

/// Drops settling rows (insertion off the depth's median). Returns the kept rows, in order.
fn drop_settling(rows: &[DataRow], tolerance_m: f64) -> Vec<DataRow> {
    let mut l: Vec<f64> = rows.iter().map(|r| r.insertion_m).collect();
    let m = median(&mut l);
    rows.iter()
        .copied()
        .filter(|r| (r.insertion_m - m).abs() <= tolerance_m)
        .collect()
}

/// Directions of motion of rows of one depth, in order; see the module docs. Uses the `direction`
/// column unless every row says 0. Returns `(directions, derived)`.
pub fn label_directions(rows: &[DataRow], step_fraction: f64) -> (Vec<i8>, bool) {
    if rows.iter().any(|r| r.direction != 0) {
        return (rows.iter().map(|r| r.direction.signum()).collect(), false);
    }
    let mut steps: Vec<f64> = rows
        .windows(2)
        .map(|w| (w[1].position_rad - w[0].position_rad).abs())
        .collect();
    let threshold = (step_fraction * median(&mut steps)).max(f64::MIN_POSITIVE);
    let mut dirs = vec![0i8; rows.len()];
    let mut current = 0i8;
    for i in 1..rows.len() {
        let dq = rows[i].position_rad - rows[i - 1].position_rad;
        if dq.abs() > threshold {
            current = if dq > 0.0 { 1 } else { -1 };
        }
        dirs[i] = current;
    }
    let first = dirs.iter().copied().find(|&d| d != 0).unwrap_or(0);
    for d in dirs.iter_mut() {
        if *d == 0 {
            *d = first;
        } else {
            break;
        }
    }
    (dirs, true)
}

/// Marks the rows left out as turnaround transitions for a gap of `gap_rad` (see module docs).
fn transition_mask(rows: &[DataRow], dirs: &[i8], gap_rad: f64, out: &mut [bool]) {
    out.iter_mut().for_each(|x| *x = false);
    let mut i = 0;
    while i < rows.len() {
        if dirs[i] == 0 {
            i += 1;
            continue;
        }
        let dir = dirs[i];
        let q_ref = if i > 0 {
            rows[i - 1].position_rad
        } else {
            rows[i].position_rad
        };
        let mut j = i;
        let mut in_transition = true;
        while j < rows.len() && dirs[j] == dir {
            if in_transition && (rows[j].position_rad - q_ref).abs() < gap_rad {
                out[j] = true;
            } else {
                in_transition = false;
            }
            j += 1;
        }
        i = j;
    }
}

fn fit_line(points: impl Iterator<Item = (f64, f64)> + Clone) -> Option<Line> {
    let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
    for (x, y) in points.clone() {
        n += 1;
        sx += x;
        sy += y;
    }
    if n < 2 {
        return None;
    }
    let (mx, my) = (sx / n as f64, sy / n as f64);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (x, y) in points.clone() {
        sxx += (x - mx) * (x - mx);
        sxy += (x - mx) * (y - my);
    }
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let ss: f64 = points
        .map(|(x, y)| {
            let r = y - (slope * x + intercept);
            r * r
        })
        .sum();
    Some(Line {
        slope,
        intercept,
        points: n,
        residual_rms_nm: (ss / n as f64).sqrt(),
    })
}

/// How the rows of one depth are split into the two lines.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BranchRule {
    /// Fit both and keep the one whose lines explain the data better (smaller median residual
    /// over all rows). See the module docs.
    #[default]
    Auto,
    /// Lines by direction of motion (paper Fig. 5), turnaround transitions left out.
    Motion,
    /// Lines by the sign of tau_ext (the two branches of Eq. 1), rows inside the play left out.
    Load,
    /// The load split with one motor friction torque `f * direction` on every row
    /// ([`Branches::LoadFriction`]), whatever the scores say.
    LoadFriction,
}

/// Which split a [`DepthFit`] used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Branches {
    Motion,
    Load,
    /// The load split with the motor's friction taken out: the two lines of the play's sides
    /// and one torque `friction_nm * direction` on every row (see [`DepthFit::friction_nm`]).
    LoadFriction,
}

/// How much better (median residual, as a share of the better plain split's) the load split
/// with friction must explain a joint's rows to be chosen over the plain splits. It nests
/// both of them in what it can describe, so it never fits worse: a motion hysteresis alone (the
/// 2017 recordings) is described as well by a friction as by the motion lines, and the
/// margin keeps the paper's reading of such data. On data of a play and a motor friction
/// both (a console stand-in's arm of 2.5 mrad play and 20 mN·m friction), the plain splits
/// leave residuals of about the friction, this one the noise.
pub const FRICTION_SPLIT_MARGIN: f64 = 0.5;

/// A reading whose hysteresis scatters by more than this over the depths (1 sigma over the
/// mean, see [`hysteresis_spread`]) is not the mechanism's, which is the same at every depth.
/// With [`BranchRule::Auto`], such a plain reading gives way to the load split with friction
/// when that one's hysteresis holds and its score is the lower, whatever
/// [`FRICTION_SPLIT_MARGIN`] says. On a simulated arm whose motors stick at twice their sliding
/// friction, joint 2's scores were 0.37 (motion), 0.48 (load) and 0.31 (with friction), as
/// close as the 2017 recordings' 0.29 and 0.25. The motion reading's play fell from 2.98 to
/// 0.06 mrad over the depths (scatter 87%), 1/K 8.4% low; with friction, 1.54 mrad (truth 1.7)
/// and 1/K within 3.9%. The 2017 recordings' motion reading is a friction hysteresis whose
/// torque holds within 9%, so they keep it.
pub const HYSTERESIS_SPREAD_LIMIT: f64 = 0.25;

/// How much a joint's hysteresis scatters over its depths, given each depth's `(gap, stiffness)`
/// (rad, N·m/rad; [`DepthFit::hysteresis_gap_rad`] and [`DepthFit::stiffness_nm_per_rad`]):
/// the relative sample deviation of a play's half-width when the mean gap is negative (a play,
/// the same at every depth), of the half-gap times the stiffness when it is positive (a
/// friction in the transmission: a torque, whose gap falls as the shaft stiffens). `None` with
/// fewer than two depths.
pub fn hysteresis_spread(depths: &[(f64, f64)]) -> Option<f64> {
    let n = depths.len().max(1) as f64;
    let friction = depths.iter().map(|d| d.0).sum::<f64>() / n > 0.0;
    let values: Vec<f64> = depths
        .iter()
        .map(|&(gap, k)| 0.5 * gap.abs() * if friction { k } else { 1.0 })
        .collect();
    let mean = values.iter().sum::<f64>() / n;
    relative_spread(values.into_iter(), mean)
}

struct BranchFit {
    lines: [Line; 2],
    excluded: usize,
    /// The motor friction taken out of every row (N·m, `LoadFriction` only; 0 otherwise).
    friction_nm: f64,
}

impl BranchFit {
    fn pooled_rms_nm(&self) -> f64 {
        let [a, b] = self.lines;
        let ss = a.residual_rms_nm.powi(2) * a.points as f64
            + b.residual_rms_nm.powi(2) * b.points as f64;
        (ss / (a.points + b.points) as f64).sqrt()
    }

    /// The line of side `side` (+1: the `+` line, -1: the `-` line), none for no side.
    fn line(&self, side: i8) -> Option<Line> {
        match side {
            1 => Some(self.lines[0]),
            -1 => Some(self.lines[1]),
            _ => None,
        }
    }

    /// Median over every row with a side of |tau_ext - its side's line|: the same rows count for
    /// both splits, left out or not, and the median ignores the minority of turnaround or play
    /// rows that neither line describes.
    fn median_abs_residual_nm(
        &self,
        rows: &[DataRow],
        dirs: &[i8],
        side: impl Fn(&DataRow, usize) -> i8,
    ) -> f64 {
        let mut r: Vec<f64> = rows
            .iter()
            .enumerate()
            .filter_map(|(i, row)| {
                let line = self.line(side(row, i))?;
                let friction = self.friction_nm * f64::from(dirs[i]);
                Some((row.tau_ext_nm() - friction - line.at(row.position_rad)).abs())
            })
            .collect();
        median(&mut r)
    }
}

fn load_side(row: &DataRow) -> i8 {
    side_of(row.tau_ext_nm())
}

/// The side of the play a load `t` (N·m) presses the shaft against: +1, -1, or 0 for none.
fn side_of(t: f64) -> i8 {
    if t > 0.0 {
        1
    } else if t < 0.0 {
        -1
    } else {
        0
    }
}

/// Fits `+` and `-` lines to the rows whose `side` is +1 / -1 and not excluded.
fn fit_sides(
    rows: &[DataRow],
    side: &[i8],
    excluded: &[bool],
    joint: u8,
    depth_index: u32,
    opts: &FitOptions,
) -> Result<[Line; 2], FitError> {
    let need = opts.min_points_per_direction.max(2);
    let fit_one = |dir: i8| -> Result<Line, FitError> {
        let pts = rows
            .iter()
            .zip(side.iter())
            .zip(excluded.iter())
            .filter(move |((_, s), ex)| **s == dir && !**ex)
            .map(|((r, _), _)| (r.position_rad, r.tau_ext_nm()));
        let got = pts.clone().count();
        if got < need {
            return Err(FitError::TooFewPoints {
                joint,
                depth_index,
                direction: dir,
                got,
                need,
            });
        }
        let line = fit_line(pts).ok_or(FitError::DegeneratePositions {
            joint,
            depth_index,
            direction: dir,
        })?;
        if line.slope <= 0.0 || !line.slope.is_finite() {
            return Err(FitError::NonPositiveStiffness {
                joint,
                depth_index,
                direction: dir,
                slope_nm_per_rad: line.slope,
            });
        }
        Ok(line)
    };
    Ok([fit_one(1)?, fit_one(-1)?])
}

/// Motion branches: the turnaround rule of the module docs, iterated to a fixed point.
fn fit_motion(
    rows: &[DataRow],
    dirs: &[i8],
    joint: u8,
    depth_index: u32,
    opts: &FitOptions,
) -> Result<BranchFit, FitError> {
    let mut excluded = vec![false; rows.len()];
    let mut lines = fit_sides(rows, dirs, &excluded, joint, depth_index, opts)?;
    let mut next = vec![false; rows.len()];
    for _ in 0..opts.max_transition_iterations {
        let gap = (lines[1].zero_crossing_rad() - lines[0].zero_crossing_rad()).abs();
        transition_mask(rows, dirs, gap, &mut next);
        if next == excluded {
            break;
        }
        lines = fit_sides(rows, dirs, &next, joint, depth_index, opts)?;
        std::mem::swap(&mut excluded, &mut next);
    }
    Ok(BranchFit {
        lines,
        excluded: excluded.iter().filter(|&&e| e).count(),
        friction_nm: 0.0,
    })
}

/// Rows whose |tau_ext| is within this many pooled residual RMS of zero have no reliable side in
/// the load split.
const LOAD_BAND_SIGMAS: f64 = 3.0;

/// Load branches: side = sign of tau_ext. Left out: rows whose |tau_ext| is within
/// [`LOAD_BAND_SIGMAS`] residual RMS of zero (their sign is noise), rows whose position lies
/// inside the play (strictly between the zero crossings of the `-` and `+` lines, when the `+`
/// line crosses to the right), and rows within the play's width of it that are off their own
/// side's line by more than that band (the play's flat part, off zero by the torque offset's
/// error); iterated to a fixed point.
///
/// With `friction`, every row's torque also holds `friction_nm * direction` (a motor friction
/// that the arm's last motion sets the sign of: a controller that stops a stuck arm short of
/// its setpoint measures the load plus up to the friction), fitted with the two lines in one
/// least-squares problem; the sides and the band then come from the torque without it, and rows
/// without a direction are left out.
fn fit_load(
    rows: &[DataRow],
    dirs: &[i8],
    friction: bool,
    joint: u8,
    depth_index: u32,
    opts: &FitOptions,
) -> Result<BranchFit, FitError> {
    let fit = |side: &[i8], excluded: &[bool]| -> Result<([Line; 2], f64), FitError> {
        if friction {
            fit_sides_friction(rows, side, dirs, excluded, joint, depth_index, opts)
        } else {
            Ok((
                fit_sides(rows, side, excluded, joint, depth_index, opts)?,
                0.0,
            ))
        }
    };
    let unusable = |s: i8, d: i8| s == 0 || (friction && d == 0);
    let mut side: Vec<i8> = rows.iter().map(load_side).collect();
    let mut excluded: Vec<bool> = side
        .iter()
        .zip(dirs)
        .map(|(&s, &d)| unusable(s, d))
        .collect();
    let (lines, friction_nm) = fit(&side, &excluded)?;
    let mut fit_now = BranchFit {
        lines,
        excluded: 0,
        friction_nm,
    };
    for _ in 0..opts.max_transition_iterations {
        let lines = fit_now.lines;
        let (lo, hi) = (lines[1].zero_crossing_rad(), lines[0].zero_crossing_rad());
        let band = LOAD_BAND_SIGMAS * fit_now.pooled_rms_nm();
        let load = |r: &DataRow, d: i8| r.tau_ext_nm() - fit_now.friction_nm * f64::from(d);
        let next_side: Vec<i8> = rows
            .iter()
            .zip(dirs)
            .map(|(r, &d)| side_of(load(r, d)))
            .collect();
        // The play's flat part lies at the torque offset's error at this depth, not at zero, so
        // the zero crossings bound the play only up to that error over the stiffness: near the
        // play, a row that is off its own side's line by more than the band is on the flat part.
        let width = (hi - lo).max(0.0);
        let off_line = |r: &DataRow, s: i8, d: i8| {
            lo - width < r.position_rad
                && r.position_rad < hi + width
                && fit_now
                    .line(s)
                    .is_some_and(|line| (load(r, d) - line.at(r.position_rad)).abs() > band)
        };
        let next: Vec<bool> = rows
            .iter()
            .zip(next_side.iter().zip(dirs))
            .map(|(r, (&s, &d))| {
                unusable(s, d)
                    || load(r, d).abs() <= band
                    || (lo < r.position_rad && r.position_rad < hi)
                    || off_line(r, s, d)
            })
            .collect();
        if next == excluded && next_side == side {
            break;
        }
        let (lines, friction_nm) = fit(&next_side, &next)?;
        fit_now.lines = lines;
        fit_now.friction_nm = friction_nm;
        excluded = next;
        side = next_side;
    }
    fit_now.excluded = excluded.iter().filter(|&&e| e).count();
    Ok(fit_now)
}

/// The `+` and `-` lines of [`fit_sides`] and a friction torque `f * direction` on every row,
/// in one least-squares problem over the rows whose `side` is +1 / -1 and not excluded.
fn fit_sides_friction(
    rows: &[DataRow],
    side: &[i8],
    dirs: &[i8],
    excluded: &[bool],
    joint: u8,
    depth_index: u32,
    opts: &FitOptions,
) -> Result<([Line; 2], f64), FitError> {
    let need = opts.min_points_per_direction.max(2);
    let used: Vec<usize> = (0..rows.len())
        .filter(|&i| !excluded[i] && side[i] != 0 && dirs[i] != 0)
        .collect();
    for dir in [1i8, -1] {
        let got = used.iter().filter(|&&i| side[i] == dir).count();
        if got < need {
            return Err(FitError::TooFewPoints {
                joint,
                depth_index,
                direction: dir,
                got,
                need,
            });
        }
    }
    // Columns: + intercept, + slope, - intercept, - slope, friction. Positions are centred on
    // their mean, so that the columns are of like size.
    let q0 = used.iter().map(|&i| rows[i].position_rad).sum::<f64>() / used.len() as f64;
    let x = DMatrix::from_fn(used.len(), 5, |r, c| {
        let i = used[r];
        let plus = side[i] == 1;
        let q = rows[i].position_rad - q0;
        match c {
            0 => f64::from(u8::from(plus)),
            1 => f64::from(u8::from(plus)) * q,
            2 => f64::from(u8::from(!plus)),
            3 => f64::from(u8::from(!plus)) * q,
            _ => f64::from(dirs[i]),
        }
    });
    let y = DVector::from_iterator(used.len(), used.iter().map(|&i| rows[i].tau_ext_nm()));
    let degenerate = FitError::DegeneratePositions {
        joint,
        depth_index,
        direction: 0,
    };
    let b = x
        .clone()
        .svd(true, true)
        .solve(&y, 1e-12)
        .map_err(|_| degenerate)?;
    if b.iter().any(|v| !v.is_finite()) {
        return Err(degenerate);
    }
    let residual = &y - &x * &b;
    let line = |dir: i8, c: usize| -> Result<Line, FitError> {
        let slope = b[c + 1];
        if slope <= 0.0 || !slope.is_finite() {
            return Err(FitError::NonPositiveStiffness {
                joint,
                depth_index,
                direction: dir,
                slope_nm_per_rad: slope,
            });
        }
        let (n, ss) = used
            .iter()
            .enumerate()
            .filter(|&(_, &i)| side[i] == dir)
            .fold((0usize, 0.0), |(n, ss), (r, _)| {
                (n + 1, ss + residual[r] * residual[r])
            });
        Ok(Line {
            slope,
            intercept: b[c] - slope * q0,
            points: n,
            residual_rms_nm: (ss / n as f64).sqrt(),
        })
    };
    Ok(([line(1, 0)?, line(-1, 2)?], b[4]))
}

/// Both candidate fits of one depth, before the choice between them.
struct Candidates {
    joint: u8,
    depth_index: u32,
    insertion_m: f64,
    dropped_settling: usize,
    stationary: usize,
    directions_derived: bool,
    motion: Result<(BranchFit, f64), FitError>,
    load: Result<(BranchFit, f64), FitError>,
    load_friction: Result<(BranchFit, f64), FitError>,
}

fn candidates(rows: &[DataRow], opts: &FitOptions) -> Result<Candidates, FitError> {
    let Some(first) = rows.first() else {
        return Err(FitError::NoData { joint: 0 });
    };
    let (joint, depth_index) = (first.joint, first.depth_index);
    check_finite(rows)?;
    let kept = drop_settling(rows, opts.insertion_tolerance_m);
    let (dirs, directions_derived) = label_directions(&kept, opts.direction_step_fraction);
    for dir in [1i8, -1] {
        if !dirs.contains(&dir) {
            return Err(FitError::SingleDirection {
                joint,
                depth_index,
                direction: -dir,
            });
        }
    }
    let skip = Err(FitError::NoData { joint });
    let motion = if matches!(opts.branches, BranchRule::Load | BranchRule::LoadFriction) {
        skip
    } else {
        fit_motion(&kept, &dirs, joint, depth_index, opts).map(|m| {
            let score = m.median_abs_residual_nm(&kept, &dirs, |_, i| dirs[i]);
            (m, score)
        })
    };
    let load_fit = |friction: bool| {
        let wanted = match opts.branches {
            BranchRule::Auto => true,
            BranchRule::Motion => false,
            BranchRule::Load => !friction,
            BranchRule::LoadFriction => friction,
        };
        if !wanted {
            return Err(FitError::NoData { joint });
        }
        fit_load(&kept, &dirs, friction, joint, depth_index, opts).map(|l| {
            // each row on the side its load (friction taken out) puts it
            let f = l.friction_nm;
            let score = l.median_abs_residual_nm(&kept, &dirs, |r, i| {
                side_of(r.tau_ext_nm() - f * f64::from(dirs[i]))
            });
            (l, score)
        })
    };
    let load = load_fit(false);
    let load_friction = load_fit(true);
    Ok(Candidates {
        joint,
        depth_index,
        insertion_m: kept.iter().map(|r| r.insertion_m).sum::<f64>() / kept.len() as f64,
        dropped_settling: rows.len() - kept.len(),
        stationary: dirs.iter().filter(|&&d| d == 0).count(),
        directions_derived,
        motion,
        load,
        load_friction,
    })
}

/// The depth result for split `want`, or another split if `want` could not be fitted there
/// (the plain ones first); with none, the error of `want`.
fn finish(c: Candidates, want: Branches) -> Result<DepthFit, FitError> {
    let (motion, load, load_friction) = (c.motion, c.load, c.load_friction);
    let (branches, fit) = match want {
        Branches::Motion => match (motion, load, load_friction) {
            (Ok((m, _)), _, _) => (Branches::Motion, m),
            (Err(_), Ok((l, _)), _) => (Branches::Load, l),
            (Err(_), Err(_), Ok((f, _))) => (Branches::LoadFriction, f),
            (Err(e), Err(_), Err(_)) => return Err(e),
        },
        Branches::Load => match (load, motion, load_friction) {
            (Ok((l, _)), _, _) => (Branches::Load, l),
            (Err(_), Ok((m, _)), _) => (Branches::Motion, m),
            (Err(_), Err(_), Ok((f, _))) => (Branches::LoadFriction, f),
            (Err(e), Err(_), Err(_)) => return Err(e),
        },
        Branches::LoadFriction => match (load_friction, motion, load) {
            (Ok((f, _)), _, _) => (Branches::LoadFriction, f),
            (Err(_), Ok((m, _)), _) => (Branches::Motion, m),
            (Err(_), Err(_), Ok((l, _))) => (Branches::Load, l),
            (Err(e), Err(_), Err(_)) => return Err(e),
        },
    };
    let lines = fit.lines;
    let gap = lines[1].zero_crossing_rad() - lines[0].zero_crossing_rad();
    Ok(DepthFit {
        joint: c.joint,
        depth_index: c.depth_index,
        insertion_m: c.insertion_m,
        lines,
        stiffness_nm_per_rad: 0.5 * (lines[0].slope + lines[1].slope),
        backlash_rad: 0.5 * gap.abs(),
        hysteresis_gap_rad: gap,
        branches,
        friction_nm: fit.friction_nm,
        points: lines[0].points + lines[1].points,
        excluded: fit.excluded,
        dropped_settling: c.dropped_settling,
        stationary: c.stationary,
        directions_derived: c.directions_derived,
    })
}

/// The split `opts` asks for; with [`BranchRule::Auto`], from the residual scores (median
/// residuals, summed over depths): the better plain split, or the load split with friction
/// when it is better than that by [`FRICTION_SPLIT_MARGIN`]. A score of `None` could not be
/// fitted.
fn preferred(
    opts: &FitOptions,
    motion_score: f64,
    load_score: f64,
    friction_score: Option<f64>,
) -> Branches {
    match opts.branches {
        BranchRule::Motion => Branches::Motion,
        BranchRule::Load => Branches::Load,
        BranchRule::LoadFriction => Branches::LoadFriction,
        BranchRule::Auto => {
            let (plain, best) = if load_score < motion_score {
                (Branches::Load, load_score)
            } else {
                (Branches::Motion, motion_score)
            };
            match friction_score {
                Some(f) if f < FRICTION_SPLIT_MARGIN * best => Branches::LoadFriction,
                _ => plain,
            }
        }
    }
}

/// Fits the two lines at one depth of one joint (see the module docs for the rules). `rows` are
/// that depth's rows in recorded order (all with the same joint). With [`BranchRule::Auto`] the
/// split is chosen from this depth alone; [`fit_joint`] chooses once per joint.
pub fn fit_depth(rows: &[DataRow], opts: &FitOptions) -> Result<DepthFit, FitError> {
    let c = candidates(rows, opts)?;
    let friction = c.load_friction.as_ref().ok().map(|(_, f)| *f);
    let want = match (&c.motion, &c.load) {
        _ if opts.branches == BranchRule::LoadFriction => Branches::LoadFriction,
        (Ok((_, m)), Ok((_, l))) => preferred(opts, *m, *l, friction),
        (Ok(_), Err(_)) => Branches::Motion,
        _ => Branches::Load,
    };
    finish(c, want)
}

/// Least-squares cubic through `(insertion_m[i], stiffness[i])`, solved by QR on an insertion
/// axis centred on the mean and scaled to [-1, 1] (the raw Vandermonde matrix of L ~ 0.1 m has a
/// condition number near 1e6), then expanded back to raw coefficients `[c3, c2, c1, c0]`.
/// Returns the coefficients and r².
pub fn fit_inverse_compliance(
    joint: u8,
    insertion_m: &[f64],
    stiffness_nm_per_rad: &[f64],
) -> Result<([f64; 4], f64), FitError> {
    let n = insertion_m.len().min(stiffness_nm_per_rad.len());
    let mut distinct: Vec<f64> = insertion_m[..n].to_vec();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    if distinct.len() < 4 {
        return Err(FitError::TooFewDepths {
            joint,
            got: distinct.len(),
            need: 4,
        });
    }
    let mean = insertion_m[..n].iter().sum::<f64>() / n as f64;
    let scale = insertion_m[..n]
        .iter()
        .map(|l| (l - mean).abs())
        .fold(0.0, f64::max);
    let v = DMatrix::from_fn(n, 4, |i, k| {
        ((insertion_m[i] - mean) / scale).powi(k as i32)
    });
    let y = DVector::from_column_slice(&stiffness_nm_per_rad[..n]);
    let qr = v.qr();
    let r = qr.r();
    let r00 = r[(0, 0)].abs();
    if (0..4).any(|k| r[(k, k)].abs() <= 1e-12 * r00) {
        return Err(FitError::TooFewDepths {
            joint,
            got: distinct.len(),
            need: 4,
        });
    }
    let qtb = qr.q().transpose() * &y;
    let a = r
        .solve_upper_triangular(&qtb)
        .ok_or(FitError::TooFewDepths {
            joint,
            got: distinct.len(),
            need: 4,
        })?;
    // p(L) = sum_k a_k ((L - m)/s)^k = sum_k a_k s^-k sum_j C(k,j) L^j (-m)^(k-j)
    const BINOM: [[f64; 4]; 4] = [
        [1.0, 0.0, 0.0, 0.0],
        [1.0, 1.0, 0.0, 0.0],
        [1.0, 2.0, 1.0, 0.0],
        [1.0, 3.0, 3.0, 1.0],
    ];
    let mut raw = [0.0f64; 4]; // raw[j] = coefficient of L^j
    for k in 0..4 {
        let ak = a[k] / scale.powi(k as i32);
        for j in 0..=k {
            raw[j] += ak * BINOM[k][j] * (-mean).powi((k - j) as i32);
        }
    }
    let c = [raw[3], raw[2], raw[1], raw[0]];
    let ybar = y.mean();
    let (mut ss_res, mut ss_tot) = (0.0, 0.0);
    for i in 0..n {
        let e = stiffness_nm_per_rad[i] - eval_cubic(&c, insertion_m[i]);
        ss_res += e * e;
        ss_tot += (stiffness_nm_per_rad[i] - ybar).powi(2);
    }
    let r_squared = if ss_tot > 0.0 {
        1.0 - ss_res / ss_tot
    } else if ss_res <= f64::EPSILON {
        1.0
    } else {
        0.0
    };
    Ok((c, r_squared))
}

fn check_joint(joint: u8) -> Result<(), FitError> {
    if joint == 1 || joint == 2 {
        Ok(())
    } else {
        Err(FitError::BadJoint { joint })
    }
}

/// Rows of `joint` grouped by depth index (ascending), each group in recorded order.
fn group_by_depth(rows: &[DataRow], joint: u8) -> Vec<Vec<DataRow>> {
    let mut indices: Vec<u32> = rows
        .iter()
        .filter(|r| r.joint == joint)
        .map(|r| r.depth_index)
        .collect();
    indices.sort_unstable();
    indices.dedup();
    indices
        .into_iter()
        .map(|d| {
            rows.iter()
                .filter(|r| r.joint == joint && r.depth_index == d)
                .copied()
                .collect()
        })
        .collect()
}

/// Fits one joint of a clamp data set: every depth, then the cubic and the mean backlash.
pub fn fit_joint(rows: &[DataRow], joint: u8, opts: &FitOptions) -> Result<JointFit, FitError> {
    check_joint(joint)?;
    let groups = group_by_depth(rows, joint);
    if groups.is_empty() {
        return Err(FitError::NoData { joint });
    }
    let cands = groups
        .iter()
        .map(|g| candidates(g, opts))
        .collect::<Result<Vec<_>, _>>()?;
    // The kind of hysteresis is a property of the mechanism, not of one depth: with
    // `BranchRule::Auto` the split is chosen once per joint, from the residual scores summed over
    // the depths where both splits fit.
    let (mut motion_score, mut load_score, mut friction_score) = (0.0, 0.0, Some(0.0));
    for c in &cands {
        if let (Ok((_, m)), Ok((_, l))) = (&c.motion, &c.load) {
            motion_score += m;
            load_score += l;
            // the friction split only where it fits at every depth the plain ones do
            friction_score = match (&c.load_friction, friction_score) {
                (Ok((_, f)), Some(sum)) => Some(sum + f),
                _ => None,
            };
        }
    }
    let mut want = preferred(opts, motion_score, load_score, friction_score);
    // A plain reading whose hysteresis moves with the depth gives way to the friction reading
    // whose hysteresis holds, if that one scores lower (see HYSTERESIS_SPREAD_LIMIT).
    let plain_score = match want {
        Branches::Motion => Some(motion_score),
        Branches::Load => Some(load_score),
        Branches::LoadFriction => None,
    };
    if opts.branches == BranchRule::Auto
        && let (Some(plain), Some(friction)) = (plain_score, friction_score)
        && friction < plain
    {
        let spread = |b: Branches| {
            let depths: Vec<(f64, f64)> = cands
                .iter()
                .filter_map(|c| {
                    let fit = match b {
                        Branches::Motion => c.motion.as_ref(),
                        Branches::Load => c.load.as_ref(),
                        Branches::LoadFriction => c.load_friction.as_ref(),
                    };
                    let [a, z] = fit.ok()?.0.lines;
                    Some((
                        z.zero_crossing_rad() - a.zero_crossing_rad(),
                        0.5 * (a.slope + z.slope),
                    ))
                })
                .collect();
            hysteresis_spread(&depths)
        };
        if spread(want).is_some_and(|s| s > HYSTERESIS_SPREAD_LIMIT)
            && spread(Branches::LoadFriction).is_some_and(|s| s <= HYSTERESIS_SPREAD_LIMIT)
        {
            want = Branches::LoadFriction;
        }
    }
    let depths = cands
        .into_iter()
        .map(|c| finish(c, want))
        .collect::<Result<Vec<_>, _>>()?;
    let l: Vec<f64> = depths.iter().map(|d| d.insertion_m).collect();
    let k: Vec<f64> = depths.iter().map(|d| d.stiffness_nm_per_rad).collect();
    let (c, r_squared) = fit_inverse_compliance(joint, &l, &k)?;
    // The range as the depths measured, to 0.1 mm (issue 10): an averaged encoder reading of
    // 0.09000026854724652 m is the depth 0.09 m, and written as such it does not flag the
    // nominal depth as clamped.
    let to_tenth_mm = |x: f64| (x * 1e4).round() / 1e4;
    let range = [
        to_tenth_mm(l.iter().copied().fold(f64::INFINITY, f64::min)),
        to_tenth_mm(l.iter().copied().fold(f64::NEG_INFINITY, f64::max)),
    ];
    let (at, value) = cubic_min_on(&c, range);
    if value.is_nan() || value <= 0.0 {
        return Err(FitError::CubicNotPositive {
            joint,
            insertion_m: at,
            value_nm_per_rad: value,
        });
    }
    let backlash_rad = depths.iter().map(|d| d.backlash_rad).sum::<f64>() / depths.len() as f64;
    let backlash_rel_sigma = relative_spread(depths.iter().map(|d| d.backlash_rad), backlash_rad);
    Ok(JointFit {
        joint,
        depths,
        inverse_compliance_nm_per_rad: c,
        backlash_rad,
        backlash_rel_sigma,
        r_squared,
        rel_sigma: relative_scatter(&c, &l, &k),
        insertion_range_m: range,
    })
}

/// Fits every joint present in `rows` (ascending joint number). All or nothing.
pub fn fit_clamp(rows: &[DataRow], opts: &FitOptions) -> Result<Vec<JointFit>, FitError> {
    let mut joints: Vec<u8> = rows.iter().map(|r| r.joint).collect();
    joints.sort_unstable();
    joints.dedup();
    if joints.is_empty() {
        return Err(FitError::NoData { joint: 0 });
    }
    joints
        .into_iter()
        .map(|j| fit_joint(rows, j, opts))
        .collect()
}

/// tau_0(q) table of one joint from an unloaded sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct TorqueOffsetFit {
    pub joint: u8,
    /// Strictly increasing angles (rad): the mean measured position of each angle group.
    pub position_rad: Vec<f64>,
    /// tau_0 per angle (N·m): mean over depths of the per-depth means, so both directions of the
    /// sweep count equally at each depth and their friction cancels.
    pub effort_nm: Vec<f64>,
    /// Depths that contributed.
    pub depths: usize,
    /// Per angle, max - min of the per-depth means (N·m); its largest value over angles.
    pub max_depth_spread_nm: f64,
    /// Mean over angles of that spread (N·m).
    pub mean_depth_spread_nm: f64,
    /// Per depth `(depth_index, insertion_m, mean deviation from the table over its angles)`:
    /// a systematic dependence on depth shows up here.
    pub depth_bias_nm: Vec<(u32, f64, f64)>,
    /// Rows dropped as settling samples.
    pub dropped_settling: usize,
}

/// Averages an unloaded sweep of `joint` into a tau_0 table. The sample of tau_0 is each row's
/// `effort_nm`. Rows are grouped into angles by sorting all positions and starting a new group
/// where the next position is more than `direction_step_fraction` of the median step beyond the
/// group's first one.
pub fn fit_torque_offset(
    rows: &[DataRow],
    joint: u8,
    opts: &FitOptions,
) -> Result<TorqueOffsetFit, FitError> {
    check_joint(joint)?;
    let groups = group_by_depth(rows, joint);
    if groups.is_empty() {
        return Err(FitError::NoData { joint });
    }
    // (position, effort, depth slot)
    let mut samples: Vec<(f64, f64, usize)> = Vec::new();
    let mut steps: Vec<f64> = Vec::new();
    let mut depth_info: Vec<(u32, f64)> = Vec::new();
    let mut dropped_settling = 0;
    for (slot, g) in groups.iter().enumerate() {
        check_finite(g)?;
        let kept = drop_settling(g, opts.insertion_tolerance_m);
        dropped_settling += g.len() - kept.len();
        steps.extend(
            kept.windows(2)
                .map(|w| (w[1].position_rad - w[0].position_rad).abs())
                .filter(|s| *s > 0.0),
        );
        let l = kept.iter().map(|r| r.insertion_m).sum::<f64>() / kept.len().max(1) as f64;
        depth_info.push((g[0].depth_index, l));
        samples.extend(kept.iter().map(|r| (r.position_rad, r.effort_nm, slot)));
    }
    let tolerance = opts.direction_step_fraction * median(&mut steps);
    samples.sort_by(|a, b| a.0.total_cmp(&b.0));

    let ndepth = groups.len();
    let mut position_rad = Vec::new();
    let mut effort_nm = Vec::new();
    let mut per_angle_depth_means: Vec<Vec<Option<f64>>> = Vec::new();
    let mut start = 0;
    while start < samples.len() {
        let q0 = samples[start].0;
        let mut end = start;
        while end < samples.len() && samples[end].0 - q0 <= tolerance {
            end += 1;
        }
        let group = &samples[start..end];
        let mut sum = vec![0.0; ndepth];
        let mut cnt = vec![0usize; ndepth];
        for &(_, e, s) in group {
            sum[s] += e;
            cnt[s] += 1;
        }
        let means: Vec<Option<f64>> = (0..ndepth)
            .map(|s| (cnt[s] > 0).then(|| sum[s] / cnt[s] as f64))
            .collect();
        let present: Vec<f64> = means.iter().flatten().copied().collect();
        position_rad.push(group.iter().map(|s| s.0).sum::<f64>() / group.len() as f64);
        effort_nm.push(present.iter().sum::<f64>() / present.len() as f64);
        per_angle_depth_means.push(means);
        start = end;
    }
    if position_rad.len() < 2 {
        return Err(FitError::TooFewAngles {
            joint,
            got: position_rad.len(),
        });
    }
    let spreads: Vec<f64> = per_angle_depth_means
        .iter()
        .map(|m| {
            let v: Vec<f64> = m.iter().flatten().copied().collect();
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            hi - lo
        })
        .collect();
    let depth_bias_nm = (0..ndepth)
        .map(|s| {
            let dev: Vec<f64> = per_angle_depth_means
                .iter()
                .zip(effort_nm.iter())
                .filter_map(|(m, t)| m[s].map(|v| v - t))
                .collect();
            let bias = dev.iter().sum::<f64>() / dev.len().max(1) as f64;
            (depth_info[s].0, depth_info[s].1, bias)
        })
        .collect();
    Ok(TorqueOffsetFit {
        joint,
        depths: ndepth,
        max_depth_spread_nm: spreads.iter().copied().fold(0.0, f64::max),
        mean_depth_spread_nm: spreads.iter().sum::<f64>() / spreads.len() as f64,
        position_rad,
        effort_nm,
        depth_bias_nm,
        dropped_settling,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic noise in [-1, 1).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        }
    }

    /// Clamp procedure on a shaft with a play of half-width `delta` (play operator) in series
    /// with stiffness `k`: out in `first_dir` until |tau| > 1, back until |tau| > 1, out again
    /// until past the start. Returns rows with direction 0 (as the 2017 files) and the indices of
    /// rows recorded while the shaft crossed the play after a reversal.
    struct Clamp {
        joint: u8,
        depth_index: u32,
        insertion_m: f64,
        k: f64,
        delta: f64,
        noise_nm: f64,
        first_dir: f64,
        /// Shaft held by the clamp with a dead zone (dvrk-sim's model) instead of a play
        /// operator: the torque depends on the twist alone.
        dead_zone: bool,
        /// A motor friction the effort carries in the direction of the step's motion (N·m).
        friction_nm: f64,
        /// How far the recorded torque offset is below the one the effort carries (N·m): the
        /// play's flat part then lies at this torque, not at zero.
        offset_error_nm: f64,
    }

    impl Clamp {
        fn rows(&self, seed: u64) -> (Vec<DataRow>, Vec<usize>) {
            let mut rng = Lcg(seed);
            let step = 0.25e-3 / self.insertion_m;
            let q_tip = 0.01;
            let mut q = q_tip;
            let mut root = q_tip; // shaft root, starts centred in the play
            let mut rows = Vec::new();
            let mut crossing = Vec::new();
            let mut dir = self.first_dir;
            let mut phase = 0;
            loop {
                q += dir * step;
                let before = root;
                if q - root > self.delta {
                    root = q - self.delta;
                } else if q - root < -self.delta {
                    root = q + self.delta;
                }
                let (engaged, tau) = if self.dead_zone {
                    let x = q - q_tip;
                    if x > self.delta {
                        (true, self.k * (x - self.delta))
                    } else if x < -self.delta {
                        (true, self.k * (x + self.delta))
                    } else {
                        (false, 0.0)
                    }
                } else {
                    (root != before, self.k * (root - q_tip))
                };
                let offset = 0.1 + 0.2 * q;
                if !engaged {
                    crossing.push(rows.len());
                }
                rows.push(DataRow {
                    joint: self.joint,
                    depth_index: self.depth_index,
                    insertion_m: self.insertion_m,
                    position_rad: q,
                    effort_nm: tau
                        + offset
                        + self.offset_error_nm
                        + self.friction_nm * dir
                        + self.noise_nm * rng.next(),
                    torque_offset_nm: offset,
                    direction: 0,
                });
                match phase {
                    0 | 1 if tau.abs() > 1.0 && tau.signum() == dir => {
                        dir = -dir;
                        phase += 1;
                    }
                    2 if (q - q_tip) * dir > 0.0 => break,
                    _ => {}
                }
            }
            (rows, crossing)
        }
    }

    fn clamp(k: f64, delta: f64) -> Clamp {
        Clamp {
            joint: 1,
            depth_index: 0,
            insertion_m: 0.12,
            k,
            delta,
            noise_nm: 0.0,
            first_dir: -1.0,
            dead_zone: false,
            friction_nm: 0.0,
            offset_error_nm: 0.0,
        }
    }

    /// A dead zone behind a motor with friction (a console stand-in's arm: 2.5 mrad of play,
    /// 20 mN·m of friction): each row measures the load plus the friction in the direction it
    /// moved. Neither plain split describes it (the motion lines bridge the play, the load lines
    /// straddle the friction); the load split with the friction taken out does, at every depth.
    #[test]
    fn a_dead_zone_behind_motor_friction_is_fitted_with_the_friction_taken_out() {
        let mut rows = Vec::new();
        for (i, l) in [0.10, 0.13, 0.16, 0.19].into_iter().enumerate() {
            let mut c = clamp(11.0 + 60.0 * l, 0.0025);
            c.dead_zone = true;
            c.friction_nm = 0.02;
            c.noise_nm = 0.002;
            c.depth_index = i as u32;
            c.insertion_m = l;
            rows.extend(c.rows(7 + i as u64).0);
        }
        let fit = fit_joint(&rows, 1, &FitOptions::default()).unwrap();
        for d in &fit.depths {
            let truth = 11.0 + 60.0 * d.insertion_m;
            assert_eq!(d.branches, Branches::LoadFriction, "{d:?}");
            assert!(
                (d.stiffness_nm_per_rad / truth - 1.0).abs() < 0.005,
                "{d:?}"
            );
            assert!((d.backlash_rad / 0.0025 - 1.0).abs() < 0.03, "{d:?}");
            assert!((d.friction_nm / 0.02 - 1.0).abs() < 0.1, "{d:?}");
            assert!(d.hysteresis_gap_rad < 0.0, "a play: {d:?}");
        }
        // the plain motion split, which the friction's hysteresis would otherwise win
        let motion = FitOptions {
            branches: BranchRule::Motion,
            ..FitOptions::default()
        };
        let plain = fit_joint(&rows, 1, &motion).unwrap();
        let d = &plain.depths[0];
        assert!(
            (d.stiffness_nm_per_rad / 17.0 - 1.0).abs() > 0.02
                || (d.backlash_rad / 0.0025 - 1.0).abs() > 0.2,
            "the motion split unexpectedly exact: {d:?}"
        );
        // without friction the plain load split is kept
        let mut c = clamp(17.0, 0.0025);
        c.dead_zone = true;
        c.noise_nm = 0.002;
        let d = fit_depth(&c.rows(3).0, &FitOptions::default()).unwrap();
        assert_eq!(d.branches, Branches::Load, "{d:?}");
        assert_eq!(d.friction_nm, 0.0);
        // ...unless the friction reading is asked for: it finds no friction there
        let forced = FitOptions {
            branches: BranchRule::LoadFriction,
            ..FitOptions::default()
        };
        let d = fit_depth(&c.rows(3).0, &forced).unwrap();
        assert_eq!(d.branches, Branches::LoadFriction, "{d:?}");
        assert!(d.friction_nm.abs() < 2e-3, "{d:?}");
        assert!((d.stiffness_nm_per_rad / 17.0 - 1.0).abs() < 0.005, "{d:?}");
        let j = fit_joint(&rows, 1, &forced).unwrap();
        assert!(
            j.depths
                .iter()
                .all(|d| d.branches == Branches::LoadFriction)
        );
    }

    /// A play is judged by its width, a friction hysteresis by its torque: a friction's gap that
    /// falls as the shaft stiffens holds; a play's width that falls so does not.
    #[test]
    fn hysteresis_spread_judges_a_play_by_width_and_a_friction_by_torque() {
        let k = [12.0, 16.0, 20.0, 24.0, 28.0];
        let play: Vec<(f64, f64)> = k.iter().map(|&k| (-0.004, k)).collect();
        assert!(hysteresis_spread(&play).unwrap() < 1e-12);
        let friction: Vec<(f64, f64)> = k.iter().map(|&k| (2.0 * 0.1 / k, k)).collect();
        assert!(hysteresis_spread(&friction).unwrap() < 1e-12);
        let drifting: Vec<(f64, f64)> = k.iter().map(|&k| (-2.0 * 0.1 / k, k)).collect();
        assert!(hysteresis_spread(&drifting).unwrap() > HYSTERESIS_SPREAD_LIMIT);
        assert_eq!(hysteresis_spread(&play[..1]), None);
    }

    #[test]
    fn exact_play_data_gives_exact_stiffness_and_backlash() {
        let (rows, crossing) = clamp(20.0, 0.003).rows(1);
        let fit = fit_depth(&rows, &FitOptions::default()).unwrap();
        assert!((fit.stiffness_nm_per_rad - 20.0).abs() < 1e-9, "{fit:?}");
        assert!((fit.backlash_rad - 0.003).abs() < 1e-9, "{fit:?}");
        // play operator: the moving-+ branch lies 2 delta to the right
        assert!((fit.hysteresis_gap_rad + 0.006).abs() < 1e-9);
        assert_eq!(fit.branches, Branches::Motion);
        assert!(fit.directions_derived);
        assert_eq!(fit.points + fit.excluded, rows.len());
        // every row that was crossing the play is left out...
        assert!(crossing.len() >= 4);
        assert!(fit.excluded >= crossing.len());
        // ...and no more than one extra per segment start (the row exactly 2 delta away)
        assert!(fit.excluded <= crossing.len() + 3, "{fit:?}");
    }

    #[test]
    fn leaving_the_turnarounds_in_biases_the_fit() {
        let (rows, _) = clamp(20.0, 0.003).rows(1);
        let plain = FitOptions {
            max_transition_iterations: 0,
            ..FitOptions::default()
        };
        let biased = fit_depth(&rows, &plain).unwrap();
        assert_eq!(biased.excluded, 0);
        assert!(
            (biased.backlash_rad - 0.003).abs() > 5e-5,
            "plain fit unexpectedly exact: {biased:?}"
        );
        let good = fit_depth(&rows, &FitOptions::default()).unwrap();
        assert!((good.backlash_rad - 0.003).abs() < (biased.backlash_rad - 0.003).abs());
    }

    #[test]
    fn dead_zone_data_is_split_by_load_sign() {
        let mut c = clamp(20.0, 0.003);
        c.dead_zone = true;
        let (rows, in_play) = c.rows(1);
        let fit = fit_depth(&rows, &FitOptions::default()).unwrap();
        assert_eq!(fit.branches, Branches::Load);
        assert!((fit.stiffness_nm_per_rad - 20.0).abs() < 1e-9, "{fit:?}");
        assert!((fit.backlash_rad - 0.003).abs() < 1e-9, "{fit:?}");
        // exactly the rows with no torque (inside the play) are left out
        assert_eq!(fit.excluded, in_play.len());
        // the direction-of-motion split cannot see a dead zone: both directions trace the same
        // curve, so the gap and the backlash vanish
        let motion = FitOptions {
            branches: BranchRule::Motion,
            ..FitOptions::default()
        };
        let wrong = fit_depth(&rows, &motion).unwrap();
        assert!(wrong.backlash_rad < 0.001, "{wrong:?}");
    }

    /// The torque offset of a depth is never exact (on the simulator's clamp data it is off by
    /// about 0.01 N·m near the play, where the internal torque is steepest), so the play's flat
    /// part lies at that error, and the zero crossings that bound the play are off by the error
    /// over the stiffness. The flat rows just inside the play's far edge then have the error's
    /// sign and would be fitted to that side's line. Off their line by far more than the noise,
    /// they are left out, and the play comes out whole.
    #[test]
    fn a_play_whose_flat_part_is_off_zero_is_fitted_whole() {
        let mut worst = 0.0_f64;
        for (i, err) in [0.012, -0.012, 0.02, -0.02].into_iter().enumerate() {
            let mut c = clamp(14.0, 0.003);
            c.dead_zone = true;
            c.noise_nm = 0.001;
            c.offset_error_nm = err;
            c.first_dir = if i % 2 == 0 { -1.0 } else { 1.0 };
            let (rows, _) = c.rows(40 + i as u64);
            let d = fit_depth(&rows, &FitOptions::default()).unwrap();
            assert_eq!(d.branches, Branches::Load, "{d:?}");
            worst = worst.max((d.backlash_rad / 0.003 - 1.0).abs());
            assert!((d.stiffness_nm_per_rad / 14.0 - 1.0).abs() < 0.01, "{d:?}");
        }
        assert!(worst < 0.01, "play off by {:.1}%", 100.0 * worst);
    }

    #[test]
    fn noisy_dead_zone_within_tolerance() {
        let mut c = clamp(15.0, 0.0017);
        c.dead_zone = true;
        c.noise_nm = 0.02;
        let (rows, _) = c.rows(11);
        let load = FitOptions {
            branches: BranchRule::Load,
            ..FitOptions::default()
        };
        let fit = fit_depth(&rows, &load).unwrap();
        assert!((fit.stiffness_nm_per_rad - 15.0).abs() < 0.3, "{fit:?}");
        assert!((fit.backlash_rad - 0.0017).abs() < 3e-4, "{fit:?}");
    }

    #[test]
    fn joint_level_choice_sees_a_noisy_dead_zone() {
        // 14 depths of noisy dead-zone data with the simulator's default joint-2 parameters:
        // one depth alone can be a near tie, the sum over depths is not.
        let rows: Vec<DataRow> = depths()
            .into_iter()
            .enumerate()
            .flat_map(|(i, l)| {
                Clamp {
                    joint: 2,
                    depth_index: i as u32,
                    insertion_m: l,
                    k: eval_cubic(&PAPER_J2, l),
                    delta: 0.0017,
                    noise_nm: 0.02,
                    first_dir: if i % 2 == 0 { -1.0 } else { 1.0 },
                    dead_zone: true,
                    friction_nm: 0.0,
                    offset_error_nm: 0.0,
                }
                .rows(100 + i as u64)
                .0
            })
            .collect();
        let fit = fit_joint(&rows, 2, &FitOptions::default()).unwrap();
        assert!(fit.depths.iter().all(|d| d.branches == Branches::Load));
        assert!(
            (fit.backlash_rad / 0.0017 - 1.0).abs() < 0.2,
            "{}",
            fit.backlash_rad
        );
        // The depths' backlashes scatter; the fit says by how much, and it is what they show.
        let b: Vec<f64> = fit.depths.iter().map(|d| d.backlash_rad).collect();
        let rel = fit.backlash_rel_sigma.unwrap();
        let (lo, hi) = b.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
        assert!(
            rel > 0.0 && rel * fit.backlash_rad <= hi - lo,
            "{rel} {b:?}"
        );
        for l in depths() {
            let rel = eval_cubic(&fit.inverse_compliance_nm_per_rad, l) / eval_cubic(&PAPER_J2, l);
            assert!((rel - 1.0).abs() < 0.05, "L {l}: {rel}");
        }
    }

    #[test]
    fn play_data_forced_to_load_split_fits_worse() {
        let (rows, _) = clamp(20.0, 0.003).rows(1);
        let load = FitOptions {
            branches: BranchRule::Load,
            ..FitOptions::default()
        };
        let forced = fit_depth(&rows, &load).unwrap();
        let auto = fit_depth(&rows, &FitOptions::default()).unwrap();
        let rms = |f: &DepthFit| f.lines[0].residual_rms_nm.max(f.lines[1].residual_rms_nm);
        assert!(rms(&forced) > 10.0 * rms(&auto).max(1e-6), "{forced:?}");
    }

    #[test]
    fn noisy_data_within_tolerance() {
        let mut c = clamp(25.0, 0.002);
        c.noise_nm = 0.02;
        c.first_dir = 1.0;
        let (rows, _) = c.rows(7);
        let fit = fit_depth(&rows, &FitOptions::default()).unwrap();
        assert!((fit.stiffness_nm_per_rad - 25.0).abs() < 0.5, "{fit:?}");
        assert!((fit.backlash_rad - 0.002).abs() < 3e-4, "{fit:?}");
    }

    #[test]
    fn explicit_direction_column_is_used() {
        let (mut rows, _) = clamp(20.0, 0.003).rows(1);
        // label every row by hand the way a recorder does
        let (dirs, derived) = label_directions(&rows, 0.25);
        assert!(derived);
        for (r, d) in rows.iter_mut().zip(dirs.iter()) {
            r.direction = *d;
        }
        // a stationary row at the start is kept out of the lines
        let mut start = rows[0];
        start.direction = 0;
        rows.insert(0, start);
        let fit = fit_depth(&rows, &FitOptions::default()).unwrap();
        assert!(!fit.directions_derived);
        assert_eq!(fit.stationary, 1);
        assert!((fit.stiffness_nm_per_rad - 20.0).abs() < 1e-9);
    }

    #[test]
    fn small_position_change_keeps_direction() {
        let mk = |q: f64| DataRow {
            joint: 1,
            depth_index: 0,
            insertion_m: 0.1,
            position_rad: q,
            effort_nm: 0.0,
            torque_offset_nm: 0.0,
            direction: 0,
        };
        // steps of 2.5 mrad, then the repeated turnaround sample moving 0.3 mrad further
        let q = [0.0, -0.0025, -0.005, -0.0075, -0.0078, -0.0053, -0.0028];
        let rows: Vec<DataRow> = q.iter().map(|&q| mk(q)).collect();
        let (dirs, _) = label_directions(&rows, 0.25);
        assert_eq!(dirs, vec![-1, -1, -1, -1, -1, 1, 1]);
    }

    #[test]
    fn settling_row_at_another_depth_is_dropped() {
        let (mut rows, _) = clamp(20.0, 0.003).rows(1);
        let mut settling = rows[0];
        settling.insertion_m = 0.16;
        settling.effort_nm = 5.0;
        rows.insert(0, settling);
        let fit = fit_depth(&rows, &FitOptions::default()).unwrap();
        assert_eq!(fit.dropped_settling, 1);
        assert!((fit.stiffness_nm_per_rad - 20.0).abs() < 1e-9);
        assert!((fit.insertion_m - 0.12).abs() < 1e-12);
    }

    #[test]
    fn single_direction_is_an_error() {
        let (rows, _) = clamp(20.0, 0.003).rows(1);
        let first_leg: Vec<DataRow> = rows
            .windows(2)
            .take_while(|w| w[1].position_rad < w[0].position_rad)
            .map(|w| w[0])
            .collect();
        assert!(first_leg.len() > 10);
        assert_eq!(
            fit_depth(&first_leg, &FitOptions::default()),
            Err(FitError::SingleDirection {
                joint: 1,
                depth_index: 0,
                direction: -1
            })
        );
    }

    #[test]
    fn too_few_points_is_an_error() {
        let (rows, _) = clamp(20.0, 0.003).rows(1);
        let opts = FitOptions {
            min_points_per_direction: 1000,
            ..FitOptions::default()
        };
        assert!(matches!(
            fit_depth(&rows, &opts),
            Err(FitError::TooFewPoints {
                joint: 1,
                depth_index: 0,
                need: 1000,
                ..
            })
        ));
    }

    #[test]
    fn negative_slope_is_an_error() {
        let (mut rows, _) = clamp(20.0, 0.003).rows(1);
        for r in rows.iter_mut() {
            r.effort_nm = -r.effort_nm;
            r.torque_offset_nm = -r.torque_offset_nm;
        }
        assert!(matches!(
            fit_depth(&rows, &FitOptions::default()),
            Err(FitError::NonPositiveStiffness { joint: 1, slope_nm_per_rad, .. }) if slope_nm_per_rad < 0.0
        ));
    }

    #[test]
    fn non_finite_is_an_error() {
        let (mut rows, _) = clamp(20.0, 0.003).rows(1);
        rows[3].effort_nm = f64::NAN;
        assert_eq!(
            fit_depth(&rows, &FitOptions::default()),
            Err(FitError::NonFinite {
                joint: 1,
                depth_index: 0,
                row: 3,
                field: "effort_nm"
            })
        );
    }

    const PAPER_J1: [f64; 4] = [639.16, -432.35, 136.32, 3.12];
    const PAPER_J2: [f64; 4] = [3163.17, -1969.15, 448.92, -6.00];

    fn depths() -> Vec<f64> {
        (0..14).map(|i| 0.09 + 0.01 * i as f64).collect()
    }

    #[test]
    fn cubic_recovers_paper_coefficients() {
        for c in [PAPER_J1, PAPER_J2] {
            let l = depths();
            let k: Vec<f64> = l.iter().map(|&l| eval_cubic(&c, l)).collect();
            let (got, r2) = fit_inverse_compliance(1, &l, &k).unwrap();
            for i in 0..4 {
                assert!(
                    (got[i] - c[i]).abs() < 1e-6 * c[i].abs().max(1.0),
                    "{got:?}"
                );
            }
            assert!((r2 - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn cubic_r_squared_drops_with_noise() {
        let l = depths();
        let mut rng = Lcg(3);
        let k: Vec<f64> = l
            .iter()
            .map(|&l| eval_cubic(&PAPER_J1, l) + 0.5 * rng.next())
            .collect();
        let (_, r2) = fit_inverse_compliance(1, &l, &k).unwrap();
        assert!(r2 < 1.0 && r2 > 0.9, "{r2}");
    }

    #[test]
    fn relative_spread_is_the_sample_deviation_over_the_mean() {
        // 1, 2, 3: sample deviation 1, mean 2.
        assert_eq!(relative_spread([1.0, 2.0, 3.0].into_iter(), 2.0), Some(0.5));
        assert_eq!(relative_spread([2.0].into_iter(), 2.0), None);
        assert_eq!(relative_spread([0.0, 0.0].into_iter(), 0.0), None);
        assert_eq!(relative_spread([1.0, f64::NAN].into_iter(), 1.0), None);
    }

    #[test]
    fn relative_scatter_measures_the_depths_around_the_cubic() {
        let l = depths();
        let exact: Vec<f64> = l.iter().map(|&l| eval_cubic(&PAPER_J1, l)).collect();
        let (c, _) = fit_inverse_compliance(1, &l, &exact).unwrap();
        assert!(relative_scatter(&c, &l, &exact).unwrap() < 1e-9);
        // 2% multiplicative scatter, alternating: measured near 2% (fewer dof than points).
        let noisy: Vec<f64> = exact
            .iter()
            .enumerate()
            .map(|(i, k)| k * if i % 2 == 0 { 1.02 } else { 0.98 })
            .collect();
        let (c, _) = fit_inverse_compliance(1, &l, &noisy).unwrap();
        let r = relative_scatter(&c, &l, &noisy).unwrap();
        assert!((0.015..0.03).contains(&r), "{r}");
        // Four depths leave no degree of freedom.
        assert_eq!(relative_scatter(&c, &l[..4], &noisy[..4]), None);
    }

    #[test]
    fn cubic_needs_four_depths() {
        assert_eq!(
            fit_inverse_compliance(2, &[0.1, 0.1, 0.2, 0.2, 0.15], &[1.0, 1.0, 2.0, 2.0, 1.5]),
            Err(FitError::TooFewDepths {
                joint: 2,
                got: 3,
                need: 4
            })
        );
    }

    #[test]
    fn cubic_minimum_is_exact() {
        // (L - 0.15)^2 (L + 1) + 1e-4 -> interior local minimum at L = 0.15, value 1e-4
        // expand: L^3 + 0.7 L^2 - 0.2775 L + 0.0225 + 1e-4
        let c = [1.0, 0.7, -0.2775, 0.0225 + 1e-4];
        let (at, v) = cubic_min_on(&c, [0.09, 0.22]);
        assert!((at - 0.15).abs() < 1e-9);
        assert!((v - 1e-4).abs() < 1e-12);
        // the paper's joint-2 cubic is positive on its range but not near its root 0.0142 m
        assert!(cubic_min_on(&PAPER_J2, [0.09, 0.22]).1 > 0.0);
        assert!(cubic_min_on(&PAPER_J2, [0.0, 0.22]).1 < 0.0);
    }

    fn clamp_set(joint: u8, c: &[f64; 4], delta: f64, dead_zone: bool) -> Vec<DataRow> {
        depths()
            .into_iter()
            .enumerate()
            .flat_map(|(i, l)| {
                Clamp {
                    joint,
                    depth_index: i as u32,
                    insertion_m: l,
                    k: eval_cubic(c, l),
                    delta,
                    noise_nm: 0.0,
                    first_dir: if i % 2 == 0 { -1.0 } else { 1.0 },
                    dead_zone,
                    friction_nm: 0.0,
                    offset_error_nm: 0.0,
                }
                .rows(i as u64)
                .0
            })
            .collect()
    }

    #[test]
    fn full_two_joint_fit_recovers_parameters() {
        // joint 1 with a play operator (hysteresis by direction), joint 2 with a dead zone
        let mut rows = clamp_set(1, &PAPER_J1, 0.003, false);
        rows.extend(clamp_set(2, &PAPER_J2, 0.0017, true));
        let fits = fit_clamp(&rows, &FitOptions::default()).unwrap();
        assert_eq!(fits.len(), 2);
        for (fit, c, d, split) in [
            (&fits[0], PAPER_J1, 0.003, Branches::Motion),
            (&fits[1], PAPER_J2, 0.0017, Branches::Load),
        ] {
            assert_eq!(fit.depths.len(), 14);
            assert!(fit.depths.iter().all(|d| d.branches == split));
            for l in depths() {
                let rel = eval_cubic(&fit.inverse_compliance_nm_per_rad, l) / eval_cubic(&c, l);
                assert!((rel - 1.0).abs() < 1e-6, "joint {} L {l}: {rel}", fit.joint);
            }
            assert!((fit.backlash_rad - d).abs() < 1e-9);
            assert!(fit.r_squared > 0.999_999);
            assert!((fit.insertion_range_m[0] - 0.09).abs() < 1e-12);
            assert!((fit.insertion_range_m[1] - 0.22).abs() < 1e-12);
        }
    }

    #[test]
    fn cubic_dipping_below_zero_is_an_error() {
        // stiff at both ends, soft in the middle: every depth is fine, the cubic is not
        let wobble = |l: f64| {
            if !(0.105..=0.205).contains(&l) {
                60.0
            } else {
                2.0
            }
        };
        let mut rows = Vec::new();
        for (i, l) in depths().into_iter().enumerate() {
            rows.extend(
                Clamp {
                    joint: 2,
                    depth_index: i as u32,
                    insertion_m: l,
                    k: wobble(l),
                    delta: 0.002,
                    noise_nm: 0.0,
                    first_dir: -1.0,
                    dead_zone: false,
                    friction_nm: 0.0,
                    offset_error_nm: 0.0,
                }
                .rows(1)
                .0,
            );
        }
        assert!(matches!(
            fit_joint(&rows, 2, &FitOptions::default()),
            Err(FitError::CubicNotPositive { joint: 2, value_nm_per_rad, insertion_m })
                if value_nm_per_rad <= 0.0 && (0.09..=0.22).contains(&insertion_m)
        ));
    }

    #[test]
    fn joint_must_be_one_or_two() {
        assert_eq!(
            fit_joint(&[], 3, &FitOptions::default()),
            Err(FitError::BadJoint { joint: 3 })
        );
        assert_eq!(
            fit_joint(&[], 1, &FitOptions::default()),
            Err(FitError::NoData { joint: 1 })
        );
    }

    /// Sweep out and back over `angles` with Coulomb friction `f` (effort = tau0 + f * dir).
    fn sweep(joint: u8, depth_index: u32, l: f64, f: f64, bias: f64) -> Vec<DataRow> {
        let tau0 = |q: f64| 0.1 + 0.05 * q + 0.02 * (5.0 * q).sin();
        let step = 5f64.to_radians();
        let mut rows = Vec::new();
        let mut push = |q: f64, dir: f64| {
            rows.push(DataRow {
                joint,
                depth_index,
                insertion_m: l,
                position_rad: q + 1e-5 * dir,
                effort_nm: tau0(q) + f * dir + bias,
                torque_offset_nm: 0.0,
                direction: dir as i8,
            })
        };
        for i in 0..=12 {
            push(-0.5 + step * i as f64, 1.0);
        }
        for i in (0..=12).rev() {
            push(-0.5 + step * i as f64, -1.0);
        }
        rows
    }

    #[test]
    fn torque_offset_averages_directions_and_reports_depth_spread() {
        let mut rows = sweep(2, 0, 0.09, 0.04, 0.0);
        rows.extend(sweep(2, 1, 0.15, 0.04, 0.01));
        rows.extend(sweep(2, 2, 0.22, 0.04, -0.01));
        let t = fit_torque_offset(&rows, 2, &FitOptions::default()).unwrap();
        assert_eq!(t.position_rad.len(), 13);
        assert_eq!(t.depths, 3);
        for (q, e) in t.position_rad.iter().zip(t.effort_nm.iter()) {
            let expect = 0.1 + 0.05 * q + 0.02 * (5.0 * q).sin();
            assert!((e - expect).abs() < 1e-6, "{q}: {e} vs {expect}");
        }
        assert!(t.position_rad.windows(2).all(|w| w[1] > w[0]));
        assert!((t.max_depth_spread_nm - 0.02).abs() < 1e-9);
        assert!((t.depth_bias_nm[1].2 - 0.01).abs() < 1e-9);
        assert!((t.depth_bias_nm[2].2 + 0.01).abs() < 1e-9);
    }

    #[test]
    fn torque_offset_needs_two_angles() {
        let rows: Vec<DataRow> = sweep(1, 0, 0.1, 0.0, 0.0).into_iter().take(1).collect();
        assert_eq!(
            fit_torque_offset(&rows, 1, &FitOptions::default()),
            Err(FitError::TooFewAngles { joint: 1, got: 1 })
        );
    }
}
