//! Position from TDOA range differences: seeded Gauss-Newton least squares,
//! geometry checks and the DOP covariance of the result.
//!
//! Each observation is a [`TdoaObs`] with `diff_m = |p - b| - |p - a|`, the
//! convention of [`insuwb_msg::UwbTdoa`] (note the sign: distance to B minus
//! distance to A). [`solve_3d`] estimates `p` in 3D; [`solve_2d`] holds the
//! tag height fixed and estimates east/north.
//!
//! ```
//! use insuwb_uwb::solve::{solve_2d, SolverConfig, TdoaObs};
//! let anchors = [[-5.0, -5.0, 0.0], [5.0, -5.0, 0.0], [-5.0, 5.0, 0.0], [5.0, 5.0, 0.0]];
//! let truth = [1.0, 2.0, 0.0];
//! let dist = |a: [f64; 3]| ((truth[0] - a[0]).powi(2) + (truth[1] - a[1]).powi(2)).sqrt();
//! let obs: Vec<TdoaObs> = anchors[1..]
//!     .iter()
//!     .map(|&b| TdoaObs { a_m: anchors[0], b_m: b, diff_m: dist(b) - dist(anchors[0]) })
//!     .collect();
//! let fix = solve_2d(&obs, 0.0, None, &SolverConfig::default()).unwrap();
//! assert!((fix.pos_m[0] - 1.0).abs() < 1e-9 && (fix.pos_m[1] - 2.0).abs() < 1e-9);
//! ```
//!
//! # Method
//!
//! 1. Checks: finite input, A and B distinct, at least 4 distinct anchors and
//!    3 independent differences in 3D (3 and 2 in 2D), at most
//!    [`MAX_ANCHORS`] anchors, and an anchor spread that is not collinear
//!    (2D, in east/north) or coplanar (3D): the condition number of the
//!    anchors' scatter matrix must not exceed
//!    [`SolverConfig::max_anchor_spread_condition`]. Coplanar anchors leave a
//!    mirror ambiguity about their plane in 3D; use 2D mode for them.
//!    Anchors are told apart by their surveyed position (bitwise equal
//!    positions are one anchor). "Independent differences" counts the
//!    distinct anchors minus the connected components of the pair graph.
//! 2. Closed-form seed (Chan/Fang-style linearisation about a reference
//!    anchor `r`, the anchor in the most pairs): the differences are chained
//!    along the pair graph into `d_k = |p - a_k| - |p - a_r|` for every anchor
//!    connected to `r` (so consecutive pairs (0,1), (1,2), ... work as well as
//!    a common reference), then `2 (a_k - a_r) . p + 2 d_k R = |a_k|^2 -
//!    |a_r|^2 - d_k^2` with `R = |p - a_r|` is solved in least squares for
//!    `p = u + v R` and `R` from the quadratic `|u + v R - a_r|^2 = R^2`. Of
//!    the (up to two) roots, the one with the lower TDOA cost is tried first;
//!    an exact tie (four anchors in 3D, noise free: both roots fit exactly)
//!    prefers a root inside the anchors' bounding box, then the one nearer the
//!    anchor centroid. When fewer anchors than unknowns are connected to `r`
//!    there is no closed form and the anchor centroid is the seed.
//! 3. Gauss-Newton on the weighted residuals `(diff - h(p)) / sigma` with the
//!    step limited to [`SolverConfig::max_step_m`], a backtracking line search
//!    (the cost never increases), at most [`SolverConfig::max_iterations`]
//!    iterations, and runaway detection: an iterate farther than
//!    [`SolverConfig::max_distance_from_anchors_m`] from the anchors'
//!    bounding box (east/north only in 2D) aborts the attempt.
//! 4. Attempts, in order, until one converges with acceptable geometry: the
//!    caller's `init`, the closed-form roots, the anchor centroid. The last
//!    attempt's error is returned when all fail.
//!
//! # Covariance and DOP
//!
//! With `J` the Jacobian of `h(p) = |p - b| - |p - a|` (rows
//! `(p - b)/|p - b| - (p - a)/|p - a|`) at the solution, the covariance is
//! `(J^T W J)^-1` with `W = diag(1/sigma_i^2)`; with unit weights that is
//! `sigma^2 (J^T J)^-1`, `sigma` = [`SolverConfig::tdoa_sigma_m`]: the DOP
//! matrix scaled by the TDOA variance. `gdop = sqrt(trace((J^T J)^-1))`
//! (unit weights, dimensionless). The differences are treated as independent
//! (per-pair noise, as the simulator and the UTIL logs have it); differences
//! that share a reference anchor's timing noise are correlated and would need
//! a full `W`. In 2D the height row and column of the covariance are zero
//! except `cov[2][2] = fixed_height_sigma_m^2`, and GDOP is horizontal.
//! The geometry is refused as degenerate when the condition number of the
//! unit-weight `J^T J` exceeds [`SolverConfig::max_condition_number`].

use nalgebra::{Matrix2, Matrix3, SymmetricEigen, Vector3};
use serde::{Deserialize, Serialize};

/// Most distinct anchors one solve accepts (bounds the stack scratch space).
pub const MAX_ANCHORS: usize = 64;

/// Halvings of the line search before a step is declared unproductive.
const MAX_HALVINGS: u32 = 40;

/// One TDOA observation: `diff_m = |p - b_m| - |p - a_m|`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TdoaObs {
    /// Position of anchor A (ENU, m).
    pub a_m: [f64; 3],
    /// Position of anchor B (ENU, m).
    pub b_m: [f64; 3],
    /// Range difference `|p - b| - |p - a|`, m.
    pub diff_m: f64,
}

impl TdoaObs {
    /// The observation carried by a UWB TDOA sample (same convention).
    #[must_use]
    pub fn from_msg(m: &insuwb_msg::UwbTdoa) -> Self {
        Self {
            a_m: m.anchor_a_pos_m,
            b_m: m.anchor_b_pos_m,
            diff_m: m.diff_m,
        }
    }

    /// The range difference `|p - b| - |p - a|` a tag at `p_m` would measure, m.
    #[must_use]
    pub fn predicted_diff_m(&self, p_m: [f64; 3]) -> f64 {
        let p = Vector3::from(p_m);
        (p - Vector3::from(self.b_m)).norm() - (p - Vector3::from(self.a_m)).norm()
    }

    /// Gradient of [`TdoaObs::predicted_diff_m`] with respect to `p`:
    /// `(p - b)/|p - b| - (p - a)/|p - a|` (a term is zero where `p` sits on
    /// its anchor). This is the measurement row of a tightly coupled filter.
    #[must_use]
    pub fn gradient(&self, p_m: [f64; 3]) -> [f64; 3] {
        gradient(self, &Vector3::from(p_m)).into()
    }

    /// The same pair seen from the other side: A and B swapped, sign flipped.
    #[must_use]
    pub fn flipped(&self) -> Self {
        Self {
            a_m: self.b_m,
            b_m: self.a_m,
            diff_m: -self.diff_m,
        }
    }
}

/// Settings of the multilateration solver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolverConfig {
    /// Standard deviation of one TDOA difference, m; scales the covariance.
    /// Default 0.1: the UTIL README's robust spread of the const3 logs
    /// (0.10-0.13 m); the paper's simulation needs a value giving a UWB-only
    /// RMSE of about 0.07 m per axis (READING.md, section 3.4).
    pub tdoa_sigma_m: f64,
    /// Gauss-Newton iterations per attempt (cap). Default 20 (engineering
    /// choice: noise-free solves converge in under 10).
    pub max_iterations: u32,
    /// Convergence: stop when the accepted step is shorter than this, m.
    /// Default 1e-6 (far below any UWB noise).
    pub tolerance_m: f64,
    /// Longest step one iteration may take, m. Default 1.0 (engineering
    /// choice: keeps an ill-conditioned first step from throwing the iterate
    /// out of the room).
    pub max_step_m: f64,
    /// An iterate or solution farther than this from the anchors' bounding
    /// box (Euclidean distance to the box; east/north only in 2D) is a
    /// runaway, m. Default 2.0 (the tag moves inside the anchored area;
    /// UTIL README: a least-squares TDOA solver can run away).
    pub max_distance_from_anchors_m: f64,
    /// Largest acceptable condition number of the unit-weight `J^T J` at the
    /// solution. Default 1e6 (engineering choice: a singular-value ratio of
    /// 1000 between the best and worst determined direction).
    pub max_condition_number: f64,
    /// Largest acceptable condition number of the anchors' scatter matrix
    /// (3 x 3 in 3D, east/north 2 x 2 in 2D): refuses collinear (and in 3D
    /// coplanar) anchors. Default 1e4 (a spread of 7 m against 7 cm).
    pub max_anchor_spread_condition: f64,
    /// Standard deviation reported for the fixed tag height of a 2D fix
    /// (`cov[2][2]` is its square), m. Default 0.0: the height is taken as
    /// known (the paper's filter uses east/north only, READING.md erratum 17).
    pub fixed_height_sigma_m: f64,
    /// Standard deviation of one two-way range, m ([`crate::range`]).
    /// Default 0.1: the robust spread of the UTIL two-way-ranging log's
    /// ranges against motion capture is 0.05-0.15 m per anchor.
    pub range_sigma_m: f64,
    /// Huber threshold of the range fix's re-weighting, in sigmas
    /// ([`crate::range`]). Default 2.0 (engineering choice: ranges within
    /// two sigmas count fully, a non-line-of-sight range far less).
    pub range_huber_k: f64,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            tdoa_sigma_m: 0.1,
            max_iterations: 20,
            tolerance_m: 1e-6,
            max_step_m: 1.0,
            max_distance_from_anchors_m: 2.0,
            max_condition_number: 1e6,
            max_anchor_spread_condition: 1e4,
            fixed_height_sigma_m: 0.0,
            range_sigma_m: 0.1,
            range_huber_k: 2.0,
        }
    }
}

/// A [`SolverConfig`] value out of range (keys are relative to the UWB fix table).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SolverConfigError {
    /// A setting is outside its valid range.
    #[error("{key} must be {requirement}, got {value}")]
    OutOfRange {
        /// Configuration key, e.g. `solver.tdoa_sigma_m`.
        key: &'static str,
        /// What the value must satisfy.
        requirement: &'static str,
        /// The offending value.
        value: f64,
    },
}

fn check(
    ok: bool,
    key: &'static str,
    requirement: &'static str,
    value: f64,
) -> Result<(), SolverConfigError> {
    if ok {
        Ok(())
    } else {
        Err(SolverConfigError::OutOfRange {
            key,
            requirement,
            value,
        })
    }
}

impl SolverConfig {
    /// Checks every setting, naming the first offending key.
    ///
    /// # Errors
    /// [`SolverConfigError::OutOfRange`] for a value outside its range.
    pub fn validate(&self) -> Result<(), SolverConfigError> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        check(
            pos(self.tdoa_sigma_m),
            "solver.tdoa_sigma_m",
            "finite and > 0",
            self.tdoa_sigma_m,
        )?;
        check(
            (1..=1000).contains(&self.max_iterations),
            "solver.max_iterations",
            "in 1..=1000",
            f64::from(self.max_iterations),
        )?;
        check(
            pos(self.tolerance_m),
            "solver.tolerance_m",
            "finite and > 0",
            self.tolerance_m,
        )?;
        check(
            pos(self.max_step_m),
            "solver.max_step_m",
            "finite and > 0",
            self.max_step_m,
        )?;
        check(
            self.max_distance_from_anchors_m.is_finite() && self.max_distance_from_anchors_m >= 0.0,
            "solver.max_distance_from_anchors_m",
            "finite and >= 0",
            self.max_distance_from_anchors_m,
        )?;
        check(
            self.max_condition_number.is_finite() && self.max_condition_number >= 1.0,
            "solver.max_condition_number",
            "finite and >= 1",
            self.max_condition_number,
        )?;
        check(
            self.max_anchor_spread_condition.is_finite() && self.max_anchor_spread_condition >= 1.0,
            "solver.max_anchor_spread_condition",
            "finite and >= 1",
            self.max_anchor_spread_condition,
        )?;
        check(
            self.fixed_height_sigma_m.is_finite() && self.fixed_height_sigma_m >= 0.0,
            "solver.fixed_height_sigma_m",
            "finite and >= 0",
            self.fixed_height_sigma_m,
        )?;
        check(
            pos(self.range_sigma_m),
            "solver.range_sigma_m",
            "finite and > 0",
            self.range_sigma_m,
        )?;
        check(
            pos(self.range_huber_k),
            "solver.range_huber_k",
            "finite and > 0",
            self.range_huber_k,
        )
    }
}

/// Where the successful attempt started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Seed {
    /// The caller's `init` (e.g. the previous fix).
    Init,
    /// A root of the closed-form (Chan/Fang-style) solution.
    ClosedForm,
    /// The anchor centroid.
    Centroid,
}

/// A multilateration result.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Fix {
    /// Position, ENU, m (in 2D, `pos_m[2]` is the given height).
    pub pos_m: [f64; 3],
    /// Position covariance `(J^T W J)^-1`, m^2 (row-major; 2D: see module doc).
    pub cov_m2: [[f64; 3]; 3],
    /// Geometric dilution of precision `sqrt(trace((J^T J)^-1))` (horizontal in 2D).
    pub gdop: f64,
    /// Gauss-Newton iterations, summed over all attempts.
    pub iterations: u32,
    /// RMS of the unweighted residuals `diff - h(p)` at the solution, m.
    pub residual_rms_m: f64,
    /// Number of observations used.
    pub n_obs: usize,
    /// Where the successful attempt started.
    pub seed: Seed,
}

/// Which geometry check refused a solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum GeometryCheck {
    /// The anchors' scatter matrix (collinear, or coplanar in 3D).
    AnchorSpread,
    /// The unit-weight normal matrix `J^T J` at the solution.
    Jacobian,
}

impl core::fmt::Display for GeometryCheck {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::AnchorSpread => "anchor spread",
            Self::Jacobian => "J^T J",
        })
    }
}

/// Why a solve failed.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SolveError {
    /// The solver settings are invalid.
    #[error("invalid solver configuration: {0}")]
    Config(SolverConfigError),
    /// An observation holds a NaN or infinity.
    #[error("observation {index}: {field} is not finite ({value})")]
    NonFiniteObs {
        /// Index of the observation.
        index: usize,
        /// Field name (`diff_m`, `a_m`, `b_m`).
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// An argument (`init`, `height_m`) holds a NaN or infinity.
    #[error("argument {name} is not finite ({value})")]
    NonFiniteArg {
        /// Argument name.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A per-observation sigma is not finite and positive.
    #[error("observation {index}: sigma must be finite and > 0, got {value}")]
    InvalidSigma {
        /// Index of the observation.
        index: usize,
        /// The offending value.
        value: f64,
    },
    /// The sigma slice does not match the observations.
    #[error("{got} sigmas given for {expected} observations")]
    SigmaCount {
        /// Sigmas given.
        got: usize,
        /// Observations given.
        expected: usize,
    },
    /// An observation's anchors A and B are the same point.
    #[error("observation {index}: anchors A and B are the same point {pos_m:?}")]
    SameAnchor {
        /// Index of the observation.
        index: usize,
        /// The shared position, m.
        pos_m: [f64; 3],
    },
    /// Fewer distinct anchors than the mode needs.
    #[error("too few anchors: {count} distinct, need {required}")]
    TooFewAnchors {
        /// Distinct anchors seen.
        count: usize,
        /// Anchors needed.
        required: usize,
    },
    /// Fewer independent differences than unknowns.
    #[error("too few independent pairs: {count}, need {required}")]
    TooFewPairs {
        /// Independent differences (anchors minus connected components).
        count: usize,
        /// Differences needed.
        required: usize,
    },
    /// More distinct anchors than [`MAX_ANCHORS`].
    #[error("too many anchors: {count} distinct, at most {max}")]
    TooManyAnchors {
        /// Distinct anchors seen (counting stops at `max + 1`).
        count: usize,
        /// The limit.
        max: usize,
    },
    /// Collinear/coplanar anchors or an ill-conditioned `J^T J`.
    #[error("degenerate geometry: condition number of the {check} {condition:e} exceeds {max:e}")]
    DegenerateGeometry {
        /// Which check failed.
        check: GeometryCheck,
        /// Condition number found (infinite when singular).
        condition: f64,
        /// Configured limit.
        max: f64,
    },
    /// The iteration cap was reached before the step became small.
    #[error("no convergence after {iterations} iterations (last step {last_step_m} m)")]
    NoConvergence {
        /// Iterations run.
        iterations: u32,
        /// Length of the last accepted step, m.
        last_step_m: f64,
    },
    /// An iterate or the solution left the box around the anchors.
    #[error("runaway: {distance_m} m from the anchors' bounding box, limit {max_m} m")]
    Runaway {
        /// Distance from the anchors' bounding box, m.
        distance_m: f64,
        /// Configured limit, m.
        max_m: f64,
    },
}

impl From<SolverConfigError> for SolveError {
    fn from(e: SolverConfigError) -> Self {
        Self::Config(e)
    }
}

/// Solves for a 3D position (needs 4+ distinct anchors, 3+ independent
/// differences), unit weights with `cfg.tdoa_sigma_m`.
///
/// `init` is tried first when given (e.g. the previous fix), then the closed
/// form, then the anchor centroid.
///
/// # Errors
/// See [`SolveError`]; every variant but `Config` is a property of the input.
pub fn solve_3d(
    obs: &[TdoaObs],
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Fix, SolveError> {
    solve(obs, Sigmas::Uniform(cfg.tdoa_sigma_m), None, init, cfg)
}

/// Solves for east/north with the tag height fixed at `height_m` (needs 3+
/// distinct anchors, 2+ independent differences); `init[2]` is ignored.
///
/// # Errors
/// See [`SolveError`].
pub fn solve_2d(
    obs: &[TdoaObs],
    height_m: f64,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Fix, SolveError> {
    solve(
        obs,
        Sigmas::Uniform(cfg.tdoa_sigma_m),
        Some(height_m),
        init,
        cfg,
    )
}

/// [`solve_3d`] with one standard deviation per observation (`sigma_m[i]`
/// for `obs[i]`, m) instead of `cfg.tdoa_sigma_m`.
///
/// # Errors
/// See [`SolveError`]; also [`SolveError::SigmaCount`] and [`SolveError::InvalidSigma`].
pub fn solve_3d_weighted(
    obs: &[TdoaObs],
    sigma_m: &[f64],
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Fix, SolveError> {
    solve(obs, Sigmas::PerObs(sigma_m), None, init, cfg)
}

/// [`solve_2d`] with one standard deviation per observation, m.
///
/// # Errors
/// See [`SolveError`]; also [`SolveError::SigmaCount`] and [`SolveError::InvalidSigma`].
pub fn solve_2d_weighted(
    obs: &[TdoaObs],
    sigma_m: &[f64],
    height_m: f64,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Fix, SolveError> {
    solve(obs, Sigmas::PerObs(sigma_m), Some(height_m), init, cfg)
}

/// The measurement standard deviations of one solve (TDOA here, ranges in
/// [`crate::range`]), m: one for all, or one per observation, its length
/// checked against the observations before any use. Borrowed, not copied:
/// a solve keeps nothing per observation.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Sigmas<'a> {
    /// Every observation's.
    Uniform(f64),
    /// `obs[i]`'s is `[i]`.
    PerObs(&'a [f64]),
}

impl Sigmas<'_> {
    /// Observation `i`'s sigma, m.
    pub(crate) fn get(self, i: usize) -> f64 {
        match self {
            Self::Uniform(s) => s,
            // Length checked before any use.
            Self::PerObs(s) => s.get(i).copied().unwrap_or(f64::NAN),
        }
    }
}

/// Distinct anchors of one solve, on the stack.
pub(crate) struct AnchorSet {
    pos: [[f64; 3]; MAX_ANCHORS],
    len: usize,
}

impl AnchorSet {
    /// None yet.
    pub(crate) const fn new() -> Self {
        Self {
            pos: [[0.0; 3]; MAX_ANCHORS],
            len: 0,
        }
    }

    /// The anchors, in order of insertion.
    pub(crate) fn as_slice(&self) -> &[[f64; 3]] {
        self.pos.get(..self.len).unwrap_or(&[])
    }

    fn index_of(&self, p: &[f64; 3]) -> Option<usize> {
        self.as_slice().iter().position(|q| q == p)
    }

    /// Adds `p` unless it is there; its index.
    ///
    /// # Errors
    /// [`SolveError::TooManyAnchors`] beyond [`MAX_ANCHORS`].
    pub(crate) fn insert(&mut self, p: [f64; 3]) -> Result<usize, SolveError> {
        if let Some(i) = self.index_of(&p) {
            return Ok(i);
        }
        let slot = self
            .pos
            .get_mut(self.len)
            .ok_or(SolveError::TooManyAnchors {
                count: MAX_ANCHORS + 1,
                max: MAX_ANCHORS,
            })?;
        *slot = p;
        self.len += 1;
        Ok(self.len - 1)
    }
}

/// The fixed data of one solve.
struct Problem<'a> {
    obs: &'a [TdoaObs],
    sigmas: Sigmas<'a>,
    /// `Some(h)` in 2D: the tag height.
    height: Option<f64>,
    box_min: Vector3<f64>,
    box_max: Vector3<f64>,
}

fn gradient(o: &TdoaObs, p: &Vector3<f64>) -> Vector3<f64> {
    let unit = |a: [f64; 3]| {
        let d = p - Vector3::from(a);
        let n = d.norm();
        if n > 0.0 {
            d / n
        } else {
            Vector3::zeros()
        }
    };
    unit(o.b_m) - unit(o.a_m)
}

impl Problem<'_> {
    fn dims(&self) -> usize {
        if self.height.is_some() {
            2
        } else {
            3
        }
    }

    /// Puts a candidate on the solution manifold (fixed height in 2D).
    fn embed(&self, mut p: Vector3<f64>) -> Vector3<f64> {
        if let Some(h) = self.height {
            p.z = h;
        }
        p
    }

    fn residual(&self, o: &TdoaObs, p: &Vector3<f64>) -> f64 {
        o.diff_m - ((p - Vector3::from(o.b_m)).norm() - (p - Vector3::from(o.a_m)).norm())
    }

    /// Weighted cost `sum ((diff - h(p)) / sigma)^2`.
    fn cost(&self, p: &Vector3<f64>) -> f64 {
        self.obs
            .iter()
            .enumerate()
            .map(|(i, o)| (self.residual(o, p) / self.sigmas.get(i)).powi(2))
            .sum()
    }

    /// Weighted normal matrix, weighted gradient `J^T W r` and unit-weight
    /// normal matrix; in 2D the height entries are zero.
    fn normal(&self, p: &Vector3<f64>) -> (Matrix3<f64>, Vector3<f64>, Matrix3<f64>) {
        let mut nw = Matrix3::zeros();
        let mut g = Vector3::zeros();
        let mut nu = Matrix3::zeros();
        for (i, o) in self.obs.iter().enumerate() {
            let mut j = gradient(o, p);
            if self.height.is_some() {
                j.z = 0.0;
            }
            let w = self.sigmas.get(i).powi(-2);
            let jj = j * j.transpose();
            nu += jj;
            nw += jj * w;
            g += j * (w * self.residual(o, p));
        }
        (nw, g, nu)
    }

    /// Distance from the anchors' bounding box (east/north only in 2D), m.
    fn box_distance(&self, p: &Vector3<f64>) -> f64 {
        let mut d2 = 0.0;
        for k in 0..self.dims() {
            let excess = (self.box_min[k] - p[k])
                .max(p[k] - self.box_max[k])
                .max(0.0);
            d2 += excess * excess;
        }
        d2.sqrt()
    }

    /// Solves `n x = g` in the unknowns (height pinned in 2D), with a tiny
    /// ridge so that a singular intermediate point does not stop the descent.
    fn newton_step(&self, n: &Matrix3<f64>, g: &Vector3<f64>) -> Option<Vector3<f64>> {
        let mut n = *n;
        let mut g = *g;
        if self.height.is_some() {
            n[(2, 2)] = 1.0;
            g.z = 0.0;
        }
        let ridge = 1e-12 * n.trace().max(f64::MIN_POSITIVE);
        n += Matrix3::identity() * ridge;
        let step = n.cholesky()?.solve(&g);
        step.iter().all(|v| v.is_finite()).then_some(step)
    }

    /// One Gauss-Newton attempt from `seed`. Returns the solution and the
    /// iterations used; `iters` accumulates iterations even on failure.
    fn refine(
        &self,
        seed: Vector3<f64>,
        cfg: &SolverConfig,
        iters: &mut u32,
    ) -> Result<Vector3<f64>, SolveError> {
        let mut x = self.embed(seed);
        let max_m = cfg.max_distance_from_anchors_m;
        let dist = self.box_distance(&x);
        if dist > max_m {
            return Err(SolveError::Runaway {
                distance_m: dist,
                max_m,
            });
        }
        let mut cost = self.cost(&x);
        let mut last_step_m = f64::INFINITY;
        for _ in 0..cfg.max_iterations {
            *iters += 1;
            let (nw, g, _) = self.normal(&x);
            let Some(mut delta) = self.newton_step(&nw, &g) else {
                return Err(SolveError::DegenerateGeometry {
                    check: GeometryCheck::Jacobian,
                    condition: f64::INFINITY,
                    max: cfg.max_condition_number,
                });
            };
            let len = delta.norm();
            if len > cfg.max_step_m {
                delta *= cfg.max_step_m / len;
            }
            // Backtracking: the Gauss-Newton direction is a descent direction,
            // so some fraction of it lowers the cost unless x is a minimum.
            let mut t = 1.0;
            let mut accepted = None;
            for _ in 0..MAX_HALVINGS {
                let cand = self.embed(x + delta * t);
                let c = self.cost(&cand);
                if c <= cost {
                    accepted = Some((cand, c));
                    break;
                }
                t *= 0.5;
            }
            let Some((cand, c)) = accepted else {
                // No fraction of the step lowers the cost: x is a minimum to
                // working precision.
                return Ok(x);
            };
            last_step_m = (cand - x).norm();
            x = cand;
            cost = c;
            let dist = self.box_distance(&x);
            if dist > max_m {
                return Err(SolveError::Runaway {
                    distance_m: dist,
                    max_m,
                });
            }
            if last_step_m < cfg.tolerance_m {
                return Ok(x);
            }
        }
        Err(SolveError::NoConvergence {
            iterations: cfg.max_iterations,
            last_step_m,
        })
    }

    /// Geometry check, covariance, GDOP and residuals at a solution.
    fn finish(
        &self,
        x: Vector3<f64>,
        cfg: &SolverConfig,
        iterations: u32,
        seed: Seed,
    ) -> Result<Fix, SolveError> {
        let (nw, _, nu) = self.normal(&x);
        let singular = SolveError::DegenerateGeometry {
            check: GeometryCheck::Jacobian,
            condition: f64::INFINITY,
            max: cfg.max_condition_number,
        };
        let (cov, gdop, condition) = if self.height.is_some() {
            let nu2 = nu.fixed_view::<2, 2>(0, 0).into_owned();
            let nw2 = nw.fixed_view::<2, 2>(0, 0).into_owned();
            let condition = condition_2x2(&nu2);
            let inv_u = nu2.try_inverse().ok_or(singular)?;
            let inv_w = nw2.try_inverse().ok_or(singular)?;
            let mut cov = Matrix3::zeros();
            cov.fixed_view_mut::<2, 2>(0, 0).copy_from(&inv_w);
            cov[(2, 2)] = cfg.fixed_height_sigma_m.powi(2);
            (cov, inv_u.trace().sqrt(), condition)
        } else {
            let condition = condition_3x3(&nu);
            let inv_u = nu.try_inverse().ok_or(singular)?;
            let inv_w = nw.try_inverse().ok_or(singular)?;
            (inv_w, inv_u.trace().sqrt(), condition)
        };
        if condition.is_nan() || condition > cfg.max_condition_number {
            return Err(SolveError::DegenerateGeometry {
                check: GeometryCheck::Jacobian,
                condition,
                max: cfg.max_condition_number,
            });
        }
        let sum_sq: f64 = self.obs.iter().map(|o| self.residual(o, &x).powi(2)).sum();
        let n = self.obs.len().max(1);
        Ok(Fix {
            pos_m: x.into(),
            cov_m2: cov.transpose().into(),
            gdop,
            iterations,
            residual_rms_m: (sum_sq / n as f64).sqrt(),
            n_obs: self.obs.len(),
            seed,
        })
    }

    /// Closed-form seeds (best first), see the module doc.
    fn closed_form(&self, anchors: &AnchorSet) -> [Option<Vector3<f64>>; 2] {
        let none = [None, None];
        let list = anchors.as_slice();
        // Reference: the anchor in the most pairs (first on a tie).
        let mut best = (0usize, 0usize);
        for (k, p) in list.iter().enumerate() {
            let degree = self
                .obs
                .iter()
                .filter(|o| o.a_m == *p || o.b_m == *p)
                .count();
            if degree > best.1 {
                best = (k, degree);
            }
        }
        let r = best.0;
        let Some(a_r) = list.get(r).map(|p| Vector3::from(*p)) else {
            return none;
        };
        // Chain the differences along the pair graph: phi_k = |p-a_k| - |p-a_r|.
        let mut phi = [None::<f64>; MAX_ANCHORS];
        if let Some(slot) = phi.get_mut(r) {
            *slot = Some(0.0);
        }
        for _ in 0..list.len() {
            let mut changed = false;
            for o in self.obs {
                let (Some(ia), Some(ib)) = (anchors.index_of(&o.a_m), anchors.index_of(&o.b_m))
                else {
                    continue;
                };
                let (pa, pb) = (
                    phi.get(ia).copied().flatten(),
                    phi.get(ib).copied().flatten(),
                );
                match (pa, pb) {
                    (Some(va), None) => {
                        if let Some(s) = phi.get_mut(ib) {
                            *s = Some(va + o.diff_m);
                            changed = true;
                        }
                    }
                    (None, Some(vb)) => {
                        if let Some(s) = phi.get_mut(ia) {
                            *s = Some(vb - o.diff_m);
                            changed = true;
                        }
                    }
                    _ => {}
                }
            }
            if !changed {
                break;
            }
        }
        // Normal equations of A p + 2 d R = c (A rows 2 (a_k - a_r)).
        let mut ata = Matrix3::zeros();
        let mut atc = Vector3::zeros();
        let mut atd = Vector3::zeros();
        let mut rows = 0usize;
        for (k, p) in list.iter().enumerate() {
            let Some(Some(d)) = phi.get(k).copied() else {
                continue;
            };
            if k == r {
                continue;
            }
            let a_k = Vector3::from(*p);
            let mut row = (a_k - a_r) * 2.0;
            let mut c = a_k.norm_squared() - a_r.norm_squared() - d * d;
            if let Some(h) = self.height {
                c -= row.z * h;
                row.z = 0.0;
            }
            ata += row * row.transpose();
            atc += row * c;
            atd += row * d;
            rows += 1;
        }
        if rows < self.dims() {
            return none;
        }
        let Some(u) = self.newton_step(&ata, &atc) else {
            return none;
        };
        let Some(v2) = self.newton_step(&ata, &atd) else {
            return none;
        };
        let v = -v2 * 2.0;
        let mut w = u - a_r;
        if let Some(h) = self.height {
            w.z = h - a_r.z;
        }
        let qa = v.norm_squared() - 1.0;
        let qb = 2.0 * w.dot(&v);
        let qc = w.norm_squared();
        let mut roots = [None::<f64>; 2];
        if qa.abs() < 1e-12 {
            if qb != 0.0 {
                roots[0] = Some(-qc / qb);
            }
        } else {
            let disc = qb * qb - 4.0 * qa * qc;
            if disc >= 0.0 {
                let s = disc.sqrt();
                roots = [Some((-qb + s) / (2.0 * qa)), Some((-qb - s) / (2.0 * qa))];
            } else {
                // Noise made the quadratic miss zero: take its closest point.
                roots[0] = Some(-qb / (2.0 * qa));
            }
        }
        let centroid = centroid(list, self.height);
        let mut cands = [None::<(Vector3<f64>, f64, f64, f64)>; 2];
        for (slot, root) in cands.iter_mut().zip(roots) {
            let Some(rr) = root.filter(|rr| rr.is_finite() && *rr >= 0.0) else {
                continue;
            };
            let p = self.embed(u + v * rr);
            if p.iter().all(|c| c.is_finite()) {
                *slot = Some((
                    p,
                    self.cost(&p),
                    self.box_distance(&p),
                    (p - centroid).norm(),
                ));
            }
        }
        match cands {
            [Some(a), Some(b)] => {
                let tie = (a.1 - b.1).abs() <= 1e-9 * (1.0 + a.1.max(b.1));
                let b_first = if tie {
                    (b.2, b.3) < (a.2, a.3)
                } else {
                    b.1 < a.1
                };
                if b_first {
                    [Some(b.0), Some(a.0)]
                } else {
                    [Some(a.0), Some(b.0)]
                }
            }
            [Some(a), None] | [None, Some(a)] => [Some(a.0), None],
            [None, None] => none,
        }
    }
}

fn centroid(list: &[[f64; 3]], height: Option<f64>) -> Vector3<f64> {
    let mut c = Vector3::zeros();
    for p in list {
        c += Vector3::from(*p);
    }
    c /= list.len().max(1) as f64;
    if let Some(h) = height {
        c.z = h;
    }
    c
}

/// Condition number of a symmetric positive semi-definite 2 x 2 matrix.
fn condition_2x2(m: &Matrix2<f64>) -> f64 {
    let (a, b, c) = (m[(0, 0)], m[(0, 1)], m[(1, 1)]);
    let mean = 0.5 * (a + c);
    let rad = (0.25 * (a - c).powi(2) + b * b).sqrt();
    ratio(mean + rad, mean - rad)
}

/// Condition number of a symmetric positive semi-definite 3 x 3 matrix.
fn condition_3x3(m: &Matrix3<f64>) -> f64 {
    match SymmetricEigen::try_new(*m, 1e-15, 200) {
        Some(e) => ratio(e.eigenvalues.max(), e.eigenvalues.min()),
        None => f64::INFINITY,
    }
}

fn ratio(max: f64, min: f64) -> f64 {
    if min > 0.0 && max.is_finite() {
        max / min
    } else {
        f64::INFINITY
    }
}

fn solve(
    obs: &[TdoaObs],
    sigmas: Sigmas<'_>,
    height: Option<f64>,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Fix, SolveError> {
    cfg.validate()?;
    if let Sigmas::PerObs(s) = sigmas {
        if s.len() != obs.len() {
            return Err(SolveError::SigmaCount {
                got: s.len(),
                expected: obs.len(),
            });
        }
        if let Some((index, &value)) = s
            .iter()
            .enumerate()
            .find(|(_, v)| !(v.is_finite() && **v > 0.0))
        {
            return Err(SolveError::InvalidSigma { index, value });
        }
    }
    if let Some(h) = height.filter(|h| !h.is_finite()) {
        return Err(SolveError::NonFiniteArg {
            name: "height_m",
            value: h,
        });
    }
    if let Some(v) = init.and_then(|p| {
        let dims = if height.is_some() { 2 } else { 3 };
        p.into_iter().take(dims).find(|v| !v.is_finite())
    }) {
        return Err(SolveError::NonFiniteArg {
            name: "init",
            value: v,
        });
    }
    let mut anchors = AnchorSet::new();
    // comp[k]: connected component label of anchor k in the pair graph.
    let mut comp = [0usize; MAX_ANCHORS];
    for (index, o) in obs.iter().enumerate() {
        if !o.diff_m.is_finite() {
            return Err(SolveError::NonFiniteObs {
                index,
                field: "diff_m",
                value: o.diff_m,
            });
        }
        for (field, p) in [("a_m", &o.a_m), ("b_m", &o.b_m)] {
            if let Some(&value) = p.iter().find(|v| !v.is_finite()) {
                return Err(SolveError::NonFiniteObs {
                    index,
                    field,
                    value,
                });
            }
        }
        if o.a_m == o.b_m {
            return Err(SolveError::SameAnchor {
                index,
                pos_m: o.a_m,
            });
        }
        let before = anchors.len;
        let ia = anchors.insert(o.a_m)?;
        if anchors.len > before {
            if let Some(c) = comp.get_mut(ia) {
                *c = ia;
            }
        }
        let before = anchors.len;
        let ib = anchors.insert(o.b_m)?;
        if anchors.len > before {
            if let Some(c) = comp.get_mut(ib) {
                *c = ib;
            }
        }
        let (ca, cb) = (comp.get(ia).copied(), comp.get(ib).copied());
        if let (Some(ca), Some(cb)) = (ca, cb) {
            if ca != cb {
                for c in comp.iter_mut().take(anchors.len) {
                    if *c == ca {
                        *c = cb;
                    }
                }
            }
        }
    }
    let (need_anchors, need_pairs) = if height.is_some() { (3, 2) } else { (4, 3) };
    if anchors.len < need_anchors {
        return Err(SolveError::TooFewAnchors {
            count: anchors.len,
            required: need_anchors,
        });
    }
    let labels = comp.get(..anchors.len).unwrap_or(&[]);
    let components = labels.iter().enumerate().filter(|(k, c)| *k == **c).count();
    let independent = anchors.len - components;
    if independent < need_pairs {
        return Err(SolveError::TooFewPairs {
            count: independent,
            required: need_pairs,
        });
    }
    let list = anchors.as_slice();
    let c = centroid(list, None);
    let mut scatter = Matrix3::zeros();
    let mut box_min = Vector3::repeat(f64::INFINITY);
    let mut box_max = Vector3::repeat(f64::NEG_INFINITY);
    for p in list {
        let v = Vector3::from(*p);
        let d = v - c;
        scatter += d * d.transpose();
        box_min = box_min.inf(&v);
        box_max = box_max.sup(&v);
    }
    let spread = if height.is_some() {
        condition_2x2(&scatter.fixed_view::<2, 2>(0, 0).into_owned())
    } else {
        condition_3x3(&scatter)
    };
    if spread.is_nan() || spread > cfg.max_anchor_spread_condition {
        return Err(SolveError::DegenerateGeometry {
            check: GeometryCheck::AnchorSpread,
            condition: spread,
            max: cfg.max_anchor_spread_condition,
        });
    }
    let problem = Problem {
        obs,
        sigmas,
        height,
        box_min,
        box_max,
    };
    let [cf1, cf2] = problem.closed_form(&anchors);
    let attempts: [(Option<Vector3<f64>>, Seed); 4] = [
        (init.map(Vector3::from), Seed::Init),
        (cf1, Seed::ClosedForm),
        (cf2, Seed::ClosedForm),
        (Some(centroid(list, height)), Seed::Centroid),
    ];
    let mut iterations = 0u32;
    let mut last_err = SolveError::NoConvergence {
        iterations: 0,
        last_step_m: f64::INFINITY,
    };
    for (start, seed) in attempts {
        let Some(start) = start else { continue };
        match problem
            .refine(start, cfg, &mut iterations)
            .and_then(|x| problem.finish(x, cfg, iterations, seed))
        {
            Ok(fix) => return Ok(fix),
            Err(e) => last_err = e,
        }
    }
    Err(last_err)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TETRA: [[f64; 3]; 4] = [
        [-3.04, -4.03, 0.21],
        [-3.23, 3.76, 2.95],
        [3.68, 3.72, 0.17],
        [4.10, -4.27, 3.20],
    ];

    fn exact(p: [f64; 3]) -> Vec<TdoaObs> {
        let d = |a: [f64; 3]| Vector3::from(p).metric_distance(&Vector3::from(a));
        TETRA[1..]
            .iter()
            .map(|&b| TdoaObs {
                a_m: TETRA[0],
                b_m: b,
                diff_m: d(b) - d(TETRA[0]),
            })
            .collect()
    }

    fn problem(obs: &[TdoaObs]) -> (Problem<'_>, AnchorSet) {
        let mut anchors = AnchorSet::new();
        let mut box_min = Vector3::repeat(f64::INFINITY);
        let mut box_max = Vector3::repeat(f64::NEG_INFINITY);
        for a in TETRA {
            anchors.insert(a).unwrap();
            box_min = box_min.inf(&Vector3::from(a));
            box_max = box_max.sup(&Vector3::from(a));
        }
        let p = Problem {
            obs,
            sigmas: Sigmas::Uniform(0.1),
            height: None,
            box_min,
            box_max,
        };
        (p, anchors)
    }

    #[test]
    fn both_closed_form_roots_are_exact_and_the_inside_one_comes_first() {
        // Four anchors in 3D: three differences, three unknowns; the quadratic
        // can have two non-negative roots, both exact solutions.
        let mut two_roots = 0;
        for i in -8..=8 {
            for j in -8..=8 {
                for k in [-2.0, 0.5, 1.5, 3.0, 5.0] {
                    let p = [i as f64, j as f64, k];
                    let obs = exact(p);
                    let (prob, anchors) = problem(&obs);
                    let [first, second] = prob.closed_form(&anchors);
                    let first = first.unwrap();
                    assert!(
                        prob.cost(&first) < 1e-12,
                        "{p:?}: first root cost {}",
                        prob.cost(&first)
                    );
                    if let Some(second) = second {
                        two_roots += 1;
                        assert!(prob.cost(&second) < 1e-12, "{p:?}: second root cost");
                        let truth = Vector3::from(p);
                        assert!(
                            (first - truth).norm() < 1e-6 || (second - truth).norm() < 1e-6,
                            "{p:?}: neither root is the tag"
                        );
                        assert!(
                            prob.box_distance(&first) <= prob.box_distance(&second),
                            "{p:?}"
                        );
                    } else {
                        assert!((first - Vector3::from(p)).norm() < 1e-6, "{p:?}: {first:?}");
                    }
                }
            }
        }
        assert!(
            two_roots > 10,
            "only {two_roots} two-root cases: the test does not exercise the tie-break"
        );
    }

    #[test]
    fn condition_numbers_match_hand_values() {
        assert!((condition_2x2(&Matrix2::new(4.0, 2.0, 2.0, 4.0)) - 3.0).abs() < 1e-12);
        assert!(
            (condition_3x3(&Matrix3::from_diagonal(&Vector3::new(2.0, 8.0, 0.5))) - 16.0).abs()
                < 1e-9
        );
        assert_eq!(
            condition_2x2(&Matrix2::new(1.0, 1.0, 1.0, 1.0)),
            f64::INFINITY
        );
    }
}
