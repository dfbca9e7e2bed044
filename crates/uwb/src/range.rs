//! Position from UWB two-way ranges: robust Gauss-Newton multilateration,
//! geometry checks and the DOP covariance of the result.
//!
//! Each observation is a [`RangeObs`] with `range_m = |p - anchor|`, the
//! convention of [`insuwb_msg::UwbRange`]. [`solve_ranges`] estimates `p`
//! in 3D (`height_m` `None`) or east/north with the tag height held.
//!
//! ```
//! use insuwb_uwb::range::{solve_ranges, RangeObs};
//! use insuwb_uwb::solve::SolverConfig;
//! let anchors = [[-4.0, -4.0, 0.2], [4.0, -4.0, 3.0], [-4.0, 4.0, 3.0], [4.0, 4.0, 0.2]];
//! let truth = [1.0, 2.0, 1.0];
//! let obs: Vec<RangeObs> = anchors
//!     .iter()
//!     .map(|&a| RangeObs { anchor_m: a, range_m: RangeObs::distance(truth, a) })
//!     .collect();
//! let fix = solve_ranges(&obs, None, None, &SolverConfig::default()).unwrap();
//! assert!((0..3).all(|i| (fix.pos_m[i] - truth[i]).abs() < 1e-6));
//! ```
//!
//! # Method
//!
//! 1. Checks: finite input, positive range sigma, at most
//!    [`crate::solve::MAX_ANCHORS`] distinct anchors (an anchor may be
//!    ranged more than once; the number of observations is not limited),
//!    at least 3 distinct anchors in 2D and 4 in 3D (one more than the
//!    unknowns: with one range per unknown a fix has no redundancy and its
//!    mirror solution fits as well), and an anchor spread that is not collinear (2D) or
//!    coplanar (3D), as for TDOA ([`SolverConfig::max_anchor_spread_condition`]).
//! 2. Seed: the caller's `init` first; then the linear least-squares
//!    solution of the differences of the squared ranges against their
//!    mean, `2 (a_i - a_mean) . p = |a_i|^2 - mean|a|^2 - (r_i^2 -
//!    mean r^2)` (exact for exact ranges, a few centimetres off with noise);
//!    then the anchor centroid.
//! 3. Gauss-Newton with iteratively re-weighted residuals: each range's
//!    weight is Huber's, 1 within `range_huber_k` sigma of the current fit,
//!    `k sigma / |residual|` beyond, so that a non-line-of-sight range
//!    (always too long) pulls the fix far less than in plain least squares.
//!    Steps are limited to [`SolverConfig::max_step_m`] with a backtracking
//!    line search on the robust cost, at most
//!    [`SolverConfig::max_iterations`] iterations per attempt, and an
//!    iterate farther than [`SolverConfig::max_distance_from_anchors_m`]
//!    from the anchors' bounding box aborts the attempt.
//!
//! A solve allocates nothing on the heap: its scratch space (the distinct
//! anchors, at most [`crate::solve::MAX_ANCHORS`], and the seeds) is on the
//! stack, and nothing is kept per observation (the sigmas are borrowed, the
//! Huber weights recomputed where used), so a device or replay loop can
//! solve every epoch without allocating.
//!
//! # A common range offset
//!
//! Two-way ranges carry the tag's antenna delay: every range of one tag is
//! off by about the same length (on the UTIL two-way-ranging log about
//! 0.28 m short). With one anchor more than the position needs (5 in 3D,
//! 4 in 2D), [`solve_ranges_with_offset`] estimates that offset `b` with
//! the position (`range = |p - a| + b`, the same robust Gauss-Newton); the
//! fix builder averages it over time ([`crate::fix`]).
//!
//! # Covariance and DOP
//!
//! With `J` the unit vectors from the anchors to the solution (rows
//! `(p - a)/|p - a|`) and `W` the final Huber weights over `sigma^2`, the
//! covariance is `(J^T W J)^-1`; `gdop = sqrt(trace((J^T J)^-1))` with unit
//! weights (horizontal in 2D, where the height row and column are zero but
//! `cov[2][2] = fixed_height_sigma_m^2`). A `J^T J` whose condition number
//! exceeds [`SolverConfig::max_condition_number`] is refused as degenerate.

use nalgebra::{Matrix2, Matrix3, SymmetricEigen, Vector3};
use serde::{Deserialize, Serialize};

use crate::solve::{AnchorSet, Fix, GeometryCheck, Seed, Sigmas, SolveError, SolverConfig};

/// Halvings of the line search before a step is declared unproductive.
const MAX_HALVINGS: u32 = 40;
/// Re-weighting rounds after Gauss-Newton converged with the first weights.
const MAX_REWEIGHTS: u32 = 10;
/// Shortest distance from the tag to an anchor the Jacobian uses, m.
const MIN_ANCHOR_DIST_M: f64 = 1e-6;

/// One range observation: `range_m = |p - anchor_m|`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct RangeObs {
    /// Position of the anchor (ENU, m).
    pub anchor_m: [f64; 3],
    /// Measured range, m.
    pub range_m: f64,
}

impl RangeObs {
    /// The observation carried by a UWB range sample.
    #[must_use]
    pub fn from_msg(m: &insuwb_msg::UwbRange) -> Self {
        Self {
            anchor_m: m.anchor_pos_m,
            range_m: m.range_m,
        }
    }

    /// The distance between two points, m.
    #[must_use]
    pub fn distance(p_m: [f64; 3], q_m: [f64; 3]) -> f64 {
        (Vector3::from(p_m) - Vector3::from(q_m)).norm()
    }

    /// The range a tag at `p_m` would measure, m.
    #[must_use]
    pub fn predicted_m(&self, p_m: [f64; 3]) -> f64 {
        Self::distance(p_m, self.anchor_m)
    }

    /// Gradient of [`RangeObs::predicted_m`] with respect to `p`: the unit
    /// vector from the anchor to `p` (zero where `p` sits on the anchor).
    #[must_use]
    pub fn gradient(&self, p_m: [f64; 3]) -> [f64; 3] {
        let d = Vector3::from(p_m) - Vector3::from(self.anchor_m);
        let n = d.norm();
        if n < MIN_ANCHOR_DIST_M {
            [0.0; 3]
        } else {
            (d / n).into()
        }
    }
}

/// Solves for the tag position from ranges (see the module doc): 3D with
/// `height_m` `None`, else east/north at that height. `sigma_m` is one
/// range's standard deviation (`None`: [`SolverConfig::range_sigma_m`]).
///
/// # Errors
/// See [`SolveError`]; every variant but `Config` is a property of the input.
pub fn solve_ranges(
    obs: &[RangeObs],
    height_m: Option<f64>,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Fix, SolveError> {
    solve_ranges_weighted(obs, None, height_m, init, cfg)
}

/// [`solve_ranges`] with one standard deviation per observation
/// (`sigma_m[i]` for `obs[i]`, m), e.g. a mean of several ranges.
///
/// # Errors
/// See [`SolveError`]; also [`SolveError::SigmaCount`] and [`SolveError::InvalidSigma`].
pub fn solve_ranges_weighted(
    obs: &[RangeObs],
    sigma_m: Option<&[f64]>,
    height_m: Option<f64>,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Fix, SolveError> {
    let Prepared {
        sigmas,
        dims,
        bbox,
        seeds,
    } = prepare(obs, sigma_m, height_m, init, cfg, 1)?;
    let mut iterations = 0;
    let mut last_err = SolveError::NoConvergence {
        iterations: 0,
        last_step_m: f64::INFINITY,
    };
    for (seed_pos, seed) in seeds.into_iter().flatten() {
        match gauss_newton(obs, sigmas, dims, seed_pos, bbox, cfg, false) {
            Ok((pos, _, _, it)) => {
                iterations += it;
                match covariance(obs, sigmas, pos, dims, cfg) {
                    Ok((cov_m2, gdop)) => {
                        let residual_rms_m = (obs
                            .iter()
                            .map(|o| (o.range_m - o.predicted_m(pos)).powi(2))
                            .sum::<f64>()
                            / obs.len().max(1) as f64)
                            .sqrt();
                        return Ok(Fix {
                            pos_m: pos,
                            cov_m2,
                            gdop,
                            iterations,
                            residual_rms_m,
                            n_obs: obs.len(),
                            seed,
                        });
                    }
                    Err(e) => last_err = e,
                }
            }
            Err((e, it)) => {
                iterations += it;
                last_err = e;
            }
        }
    }
    Err(last_err)
}

/// A fix with the common range offset estimated too.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetFix {
    /// Position, ENU, m (in 2D, `pos_m[2]` is the given height).
    pub pos_m: [f64; 3],
    /// The common offset `b` of every range (`range = |p - a| + b`), m.
    pub offset_m: f64,
    /// Its variance from `(J^T W J)^-1`, m^2.
    pub offset_var_m2: f64,
    /// Gauss-Newton iterations.
    pub iterations: u32,
}

/// Solves for the position and the common range offset `b` (`range = |p -
/// a| + b`): 3D with `height_m` `None`, else east/north at that height.
/// Needs two distinct anchors more than the position's unknowns. `init`
/// seeds the position (then the linear seed, then the centroid), the
/// offset starts at 0.
///
/// # Errors
/// As [`solve_ranges`]; [`SolveError::TooFewAnchors`] below 5 anchors in
/// 3D or 4 in 2D.
pub fn solve_ranges_with_offset(
    obs: &[RangeObs],
    sigma_m: Option<&[f64]>,
    height_m: Option<f64>,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<OffsetFix, SolveError> {
    let Prepared {
        sigmas,
        dims,
        bbox,
        seeds,
    } = prepare(obs, sigma_m, height_m, init, cfg, 2)?;
    let mut last_err = SolveError::NoConvergence {
        iterations: 0,
        last_step_m: f64::INFINITY,
    };
    let mut iterations = 0;
    for (seed, _) in seeds.into_iter().flatten() {
        match gauss_newton(obs, sigmas, dims, seed, bbox, cfg, true) {
            Ok((pos_m, offset_m, offset_var_m2, it)) => {
                return Ok(OffsetFix {
                    pos_m,
                    offset_m,
                    offset_var_m2,
                    iterations: iterations + it,
                });
            }
            Err((e, it)) => {
                iterations += it;
                last_err = e;
            }
        }
    }
    Err(last_err)
}

/// A solution `(p, b, var(b), iterations)`; `b` is 0 without the offset.
type Solved = ([f64; 3], f64, f64, u32);

/// Robust cost of the ranges less the offset `b`.
fn cost_offset(obs: &[RangeObs], sigmas: Sigmas<'_>, p: [f64; 3], b: f64, k: f64) -> f64 {
    obs.iter()
        .enumerate()
        .map(|(i, o)| {
            let r = ((o.range_m - b - o.predicted_m(p)) / sigmas.get(i)).abs();
            if r <= k {
                0.5 * r * r
            } else {
                k * r - 0.5 * k * k
            }
        })
        .sum()
}

/// One robust Gauss-Newton attempt (module doc) over `p`, and the common
/// offset `b` when `with_offset` (else `b` stays 0 and its variance is 0).
fn gauss_newton(
    obs: &[RangeObs],
    sigmas: Sigmas<'_>,
    dims: usize,
    seed: [f64; 3],
    bbox: ([f64; 3], [f64; 3]),
    cfg: &SolverConfig,
    with_offset: bool,
) -> Result<Solved, (SolveError, u32)> {
    use nalgebra::{Matrix4, Vector4};
    let k = cfg.range_huber_k;
    let (mut p, mut b) = (seed, 0.0_f64);
    let mut it = 0_u32;
    let mut last_step = f64::INFINITY;
    let normal = |p: [f64; 3], b: f64| {
        let mut jtj = Matrix4::<f64>::zeros();
        let mut jtr = Vector4::<f64>::zeros();
        for (i, o) in obs.iter().enumerate() {
            let s = sigmas.get(i);
            let res = o.range_m - b - o.predicted_m(p);
            let w = huber(res, s, k) / (s * s);
            let g = o.gradient(p);
            let row = Vector4::new(
                g[0],
                g[1],
                if dims == 2 { 0.0 } else { g[2] },
                if with_offset { 1.0 } else { 0.0 },
            );
            jtj += w * row * row.transpose();
            jtr += w * res * row;
        }
        // Unknowns held (the height in 2D, the offset without it) get a
        // unit diagonal and a zero step.
        if dims == 2 {
            jtj[(2, 2)] = 1.0;
        }
        if !with_offset {
            jtj[(3, 3)] = 1.0;
        }
        (jtj, jtr)
    };
    let singular = |it| {
        (
            SolveError::DegenerateGeometry {
                check: GeometryCheck::Jacobian,
                condition: f64::INFINITY,
                max: cfg.max_condition_number,
            },
            it,
        )
    };
    let mut converged = false;
    while it < cfg.max_iterations.saturating_mul(MAX_REWEIGHTS + 1) {
        it += 1;
        let (jtj, jtr) = normal(p, b);
        let Some(mut step) = jtj.cholesky().map(|c| c.solve(&jtr)) else {
            return Err(singular(it));
        };
        let len = step.norm();
        if len > cfg.max_step_m {
            step *= cfg.max_step_m / len;
        }
        let c0 = cost_offset(obs, sigmas, p, b, k);
        let mut alpha = 1.0;
        let mut accepted = None;
        for _ in 0..MAX_HALVINGS {
            let q = [
                p[0] + alpha * step[0],
                p[1] + alpha * step[1],
                p[2] + alpha * step[2],
            ];
            let qb = b + alpha * step[3];
            if cost_offset(obs, sigmas, q, qb, k) <= c0 {
                accepted = Some((q, qb));
                break;
            }
            alpha *= 0.5;
        }
        let Some((q, qb)) = accepted else {
            converged = true;
            break;
        };
        last_step = alpha * step.norm();
        (p, b) = (q, qb);
        let distance_m = box_distance(&p, bbox, dims);
        if distance_m > cfg.max_distance_from_anchors_m {
            return Err((
                SolveError::Runaway {
                    distance_m,
                    max_m: cfg.max_distance_from_anchors_m,
                },
                it,
            ));
        }
        if last_step < cfg.tolerance_m {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err((
            SolveError::NoConvergence {
                iterations: it,
                last_step_m: last_step,
            },
            it,
        ));
    }
    if !with_offset {
        return Ok((p, 0.0, 0.0, it));
    }
    let (jtj, _) = normal(p, b);
    let Some(inv) = jtj.try_inverse() else {
        return Err(singular(it));
    };
    let var = inv[(3, 3)];
    if !(var.is_finite() && var > 0.0) {
        return Err(singular(it));
    }
    Ok((p, b, var, it))
}

/// What both solves check and start from (on the stack).
struct Prepared<'a> {
    sigmas: Sigmas<'a>,
    dims: usize,
    bbox: ([f64; 3], [f64; 3]),
    /// In order: `init`, the linear seed, the anchor centroid (the last
    /// always present).
    seeds: [Option<([f64; 3], Seed)>; 3],
}

/// The checks of a solve (settings, input, at least `extra` distinct
/// anchors more than the position's unknowns, their spread) and its seeds
/// in order: `init`, the linear seed, the anchor centroid.
fn prepare<'a>(
    obs: &[RangeObs],
    sigma_m: Option<&'a [f64]>,
    height_m: Option<f64>,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
    extra: usize,
) -> Result<Prepared<'a>, SolveError> {
    cfg.validate()?;
    let sigmas = check_input(obs, sigma_m, height_m, init, cfg)?;
    let dims = if height_m.is_some() { 2 } else { 3 };
    let set = distinct_anchors(obs)?;
    let anchors = set.as_slice();
    let required = dims + extra;
    if anchors.len() < required {
        return Err(SolveError::TooFewAnchors {
            count: anchors.len(),
            required,
        });
    }
    spread_check(anchors, dims, cfg)?;
    let n = anchors.len() as f64;
    let centroid = anchors.iter().fold([0.0; 3], |c, a| {
        [c[0] + a[0] / n, c[1] + a[1] / n, c[2] + a[2] / n]
    });
    let seeds = [
        init.map(|p| (with_height(p, height_m), Seed::Init)),
        linear_seed(obs, height_m).map(|p| (p, Seed::ClosedForm)),
        Some((with_height(centroid, height_m), Seed::Centroid)),
    ];
    Ok(Prepared {
        sigmas,
        dims,
        bbox: bounding_box(anchors),
        seeds,
    })
}

fn with_height(p: [f64; 3], height_m: Option<f64>) -> [f64; 3] {
    match height_m {
        Some(h) => [p[0], p[1], h],
        None => p,
    }
}

fn check_input<'a>(
    obs: &[RangeObs],
    sigma_m: Option<&'a [f64]>,
    height_m: Option<f64>,
    init: Option<[f64; 3]>,
    cfg: &SolverConfig,
) -> Result<Sigmas<'a>, SolveError> {
    for (index, o) in obs.iter().enumerate() {
        if !o.range_m.is_finite() {
            return Err(SolveError::NonFiniteObs {
                index,
                field: "range_m",
                value: o.range_m,
            });
        }
        if let Some(&value) = o.anchor_m.iter().find(|v| !v.is_finite()) {
            return Err(SolveError::NonFiniteObs {
                index,
                field: "anchor_m",
                value,
            });
        }
    }
    if let Some(h) = height_m.filter(|h| !h.is_finite()) {
        return Err(SolveError::NonFiniteArg {
            name: "height_m",
            value: h,
        });
    }
    if let Some(&value) = init.iter().flatten().find(|v| !v.is_finite()) {
        return Err(SolveError::NonFiniteArg {
            name: "init",
            value,
        });
    }
    match sigma_m {
        None => Ok(Sigmas::Uniform(cfg.range_sigma_m)),
        Some(s) if s.len() != obs.len() => Err(SolveError::SigmaCount {
            got: s.len(),
            expected: obs.len(),
        }),
        Some(s) => {
            if let Some((index, &value)) = s
                .iter()
                .enumerate()
                .find(|(_, v)| !(v.is_finite() && **v > 0.0))
            {
                return Err(SolveError::InvalidSigma { index, value });
            }
            Ok(Sigmas::PerObs(s))
        }
    }
}

/// The distinct anchors of `obs` in order of first appearance.
fn distinct_anchors(obs: &[RangeObs]) -> Result<AnchorSet, SolveError> {
    let mut out = AnchorSet::new();
    for o in obs {
        out.insert(o.anchor_m)?;
    }
    Ok(out)
}

fn spread_check(anchors: &[[f64; 3]], dims: usize, cfg: &SolverConfig) -> Result<(), SolveError> {
    let n = anchors.len() as f64;
    let mean = anchors
        .iter()
        .fold(Vector3::zeros(), |m, a| m + Vector3::from(*a) / n);
    let mut s = Matrix3::zeros();
    for a in anchors {
        let d = Vector3::from(*a) - mean;
        s += d * d.transpose();
    }
    let condition = if dims == 2 {
        condition2(&s.fixed_view::<2, 2>(0, 0).into_owned())
    } else {
        condition3(&s)
    };
    if condition > cfg.max_anchor_spread_condition {
        return Err(SolveError::DegenerateGeometry {
            check: GeometryCheck::AnchorSpread,
            condition,
            max: cfg.max_anchor_spread_condition,
        });
    }
    Ok(())
}

fn condition_from(eigenvalues: impl Iterator<Item = f64>) -> f64 {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0_f64);
    for v in eigenvalues {
        lo = lo.min(v.abs());
        hi = hi.max(v.abs());
    }
    if lo <= 0.0 || !lo.is_finite() {
        f64::INFINITY
    } else {
        hi / lo
    }
}

fn condition3(m: &Matrix3<f64>) -> f64 {
    condition_from(SymmetricEigen::new(*m).eigenvalues.iter().copied())
}

fn condition2(m: &Matrix2<f64>) -> f64 {
    condition_from(SymmetricEigen::new(*m).eigenvalues.iter().copied())
}

fn bounding_box(anchors: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for a in anchors {
        for i in 0..3 {
            lo[i] = lo[i].min(a[i]);
            hi[i] = hi[i].max(a[i]);
        }
    }
    (lo, hi)
}

/// Distance from `p` to the box (east/north only in 2D), m.
fn box_distance(p: &[f64; 3], (lo, hi): ([f64; 3], [f64; 3]), dims: usize) -> f64 {
    (0..dims)
        .map(|i| {
            let d = (lo[i] - p[i]).max(p[i] - hi[i]).max(0.0);
            d * d
        })
        .sum::<f64>()
        .sqrt()
}

/// The linear least-squares seed (module doc, step 2); `None` when singular.
fn linear_seed(obs: &[RangeObs], height_m: Option<f64>) -> Option<[f64; 3]> {
    if obs.len() < 3 {
        return None;
    }
    let nf = obs.len() as f64;
    let mean_a = obs
        .iter()
        .fold(Vector3::zeros(), |m, o| m + Vector3::from(o.anchor_m) / nf);
    let mean_a2 = obs
        .iter()
        .map(|o| Vector3::from(o.anchor_m).norm_squared())
        .sum::<f64>()
        / nf;
    let mean_r2 = obs.iter().map(|o| o.range_m * o.range_m).sum::<f64>() / nf;
    // Normal equations of the linear system, accumulated on the stack (no
    // allocation per fix); in 2D the height is held.
    let mut ata = Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for o in obs {
        let ai = Vector3::from(o.anchor_m);
        let mut row = 2.0 * (ai - mean_a);
        let mut rhs = ai.norm_squared() - mean_a2 - (o.range_m * o.range_m - mean_r2);
        if let Some(h) = height_m {
            rhs -= row[2] * h;
            row[2] = 0.0;
        }
        ata += row * row.transpose();
        atb += rhs * row;
    }
    if height_m.is_some() {
        ata[(2, 2)] = 1.0;
    }
    let sol = ata.cholesky()?.solve(&atb);
    let p = match height_m {
        Some(h) => [sol[0], sol[1], h],
        None => [sol[0], sol[1], sol[2]],
    };
    p.iter().all(|v| v.is_finite()).then_some(p)
}

fn huber(res: f64, sigma: f64, k: f64) -> f64 {
    let r = res.abs() / sigma;
    if r <= k {
        1.0
    } else {
        k / r
    }
}

/// `(J^T W J)^-1` and the GDOP at `p` (module doc), with the Huber
/// weights of the residuals at `p`.
fn covariance(
    obs: &[RangeObs],
    sigmas: Sigmas<'_>,
    p: [f64; 3],
    dims: usize,
    cfg: &SolverConfig,
) -> Result<([[f64; 3]; 3], f64), SolveError> {
    let k = cfg.range_huber_k;
    let mut jtj = Matrix3::<f64>::zeros();
    let mut jwj = Matrix3::<f64>::zeros();
    for (i, o) in obs.iter().enumerate() {
        let s = sigmas.get(i);
        let w = huber(o.range_m - o.predicted_m(p), s, k);
        let mut g = Vector3::from(o.gradient(p));
        if dims == 2 {
            g[2] = 0.0;
        }
        let gg = g * g.transpose();
        jtj += gg;
        jwj += (w / (s * s)) * gg;
    }
    let (unit, weighted) = if dims == 2 {
        (
            jtj.fixed_view::<2, 2>(0, 0).into_owned(),
            jwj.fixed_view::<2, 2>(0, 0).into_owned(),
        )
    } else {
        let condition = condition3(&jtj);
        if condition > cfg.max_condition_number {
            return Err(SolveError::DegenerateGeometry {
                check: GeometryCheck::Jacobian,
                condition,
                max: cfg.max_condition_number,
            });
        }
        let (Some(inv_u), Some(inv_w)) = (jtj.try_inverse(), jwj.try_inverse()) else {
            return Err(singular(cfg));
        };
        return Ok((inv_w.into(), inv_u.trace().max(0.0).sqrt()));
    };
    let condition = condition2(&unit);
    if condition > cfg.max_condition_number {
        return Err(SolveError::DegenerateGeometry {
            check: GeometryCheck::Jacobian,
            condition,
            max: cfg.max_condition_number,
        });
    }
    let (Some(inv_u), Some(inv_w)) = (unit.try_inverse(), weighted.try_inverse()) else {
        return Err(singular(cfg));
    };
    let mut cov = [[0.0; 3]; 3];
    for (i, row) in cov.iter_mut().enumerate().take(2) {
        for (j, c) in row.iter_mut().enumerate().take(2) {
            *c = inv_w[(i, j)];
        }
    }
    cov[2][2] = cfg.fixed_height_sigma_m * cfg.fixed_height_sigma_m;
    Ok((cov, inv_u.trace().max(0.0).sqrt()))
}

fn singular(cfg: &SolverConfig) -> SolveError {
    SolveError::DegenerateGeometry {
        check: GeometryCheck::Jacobian,
        condition: f64::INFINITY,
        max: cfg.max_condition_number,
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;

    const ANCHORS: [[f64; 3]; 8] = [
        [-3.04, -4.03, 0.21],
        [-3.23, 3.76, 2.95],
        [3.68, 3.72, 0.17],
        [4.10, -4.27, 3.20],
        [-3.04, -4.41, 3.04],
        [3.92, -3.79, 0.20],
        [4.06, 3.85, 3.15],
        [-3.17, 3.35, 0.18],
    ];

    fn obs_at(p: [f64; 3]) -> Vec<RangeObs> {
        ANCHORS
            .iter()
            .map(|&a| RangeObs {
                anchor_m: a,
                range_m: RangeObs::distance(p, a),
            })
            .collect()
    }

    #[test]
    fn exact_ranges_give_the_point_in_3d_and_2d() {
        let cfg = SolverConfig::default();
        for p in [[0.0, 0.0, 1.0], [2.5, -3.0, 0.1], [-2.0, 3.0, 2.5]] {
            let f = solve_ranges(&obs_at(p), None, None, &cfg).unwrap();
            assert!((0..3).all(|i| (f.pos_m[i] - p[i]).abs() < 1e-6), "{f:?}");
            assert!(f.gdop > 0.5 && f.gdop < 5.0);
            let f2 = solve_ranges(&obs_at(p), Some(p[2]), None, &cfg).unwrap();
            assert!((0..2).all(|i| (f2.pos_m[i] - p[i]).abs() < 1e-6));
            assert_eq!(f2.pos_m[2], p[2]);
            assert_eq!(f2.cov_m2[0][2], 0.0);
        }
    }

    #[test]
    fn the_linear_seed_is_exact_for_exact_ranges() {
        let p = [1.0, -2.0, 1.5];
        let s = linear_seed(&obs_at(p), None).unwrap();
        assert!((0..3).all(|i| (s[i] - p[i]).abs() < 1e-9), "{s:?}");
    }

    #[test]
    fn a_long_nlos_range_moves_the_robust_fix_less_than_least_squares() {
        let p = [0.5, 0.5, 1.0];
        let mut obs = obs_at(p);
        obs[2].range_m += 1.5;
        let robust = solve_ranges(&obs, None, None, &SolverConfig::default()).unwrap();
        let plain = solve_ranges(
            &obs,
            None,
            None,
            &SolverConfig {
                range_huber_k: 1e6,
                ..SolverConfig::default()
            },
        )
        .unwrap();
        let err = |f: &Fix| RangeObs::distance(f.pos_m, p);
        assert!(
            err(&robust) < 0.5 * err(&plain),
            "{} {}",
            err(&robust),
            err(&plain)
        );
    }

    #[test]
    fn a_common_offset_is_found_with_the_position() {
        let p = [0.5, -1.0, 1.2];
        let mut obs = obs_at(p);
        for o in &mut obs {
            o.range_m -= 0.28;
        }
        let cfg = SolverConfig::default();
        let f = solve_ranges_with_offset(&obs, None, None, None, &cfg).unwrap();
        assert!((f.offset_m + 0.28).abs() < 1e-6, "{f:?}");
        assert!((0..3).all(|i| (f.pos_m[i] - p[i]).abs() < 1e-6));
        assert!(f.offset_var_m2 > 0.0 && f.offset_var_m2 < 0.1);
        let f2 = solve_ranges_with_offset(&obs, None, Some(1.2), None, &cfg).unwrap();
        assert!((f2.offset_m + 0.28).abs() < 1e-6);
        assert!(matches!(
            solve_ranges_with_offset(&obs[..4], None, None, None, &cfg),
            Err(SolveError::TooFewAnchors {
                count: 4,
                required: 5
            })
        ));
    }

    #[test]
    fn covariance_scales_with_sigma_and_geometry_is_checked() {
        let p = [0.0, 0.0, 1.0];
        let a = solve_ranges(&obs_at(p), None, None, &SolverConfig::default()).unwrap();
        let cfg = SolverConfig {
            range_sigma_m: 0.2,
            ..SolverConfig::default()
        };
        let b = solve_ranges(&obs_at(p), None, None, &cfg).unwrap();
        assert!((b.cov_m2[0][0] / a.cov_m2[0][0] - 4.0).abs() < 1e-6);
        // Three anchors do not fix 3D; four on a line do not fix 2D.
        let few = obs_at(p)[..3].to_vec();
        assert!(matches!(
            solve_ranges(&few, None, None, &cfg),
            Err(SolveError::TooFewAnchors {
                count: 3,
                required: 4
            })
        ));
        let line: Vec<RangeObs> = (0..4)
            .map(|i| RangeObs {
                anchor_m: [f64::from(i), 0.0, 0.0],
                range_m: 3.0,
            })
            .collect();
        assert!(matches!(
            solve_ranges(&line, Some(0.0), None, &cfg),
            Err(SolveError::DegenerateGeometry { .. })
        ));
        let mut bad = obs_at(p);
        bad[1].range_m = f64::NAN;
        assert!(matches!(
            solve_ranges(&bad, None, None, &cfg),
            Err(SolveError::NonFiniteObs { index: 1, .. })
        ));
        assert!(matches!(
            solve_ranges_weighted(&obs_at(p), Some(&[0.1]), None, None, &cfg),
            Err(SolveError::SigmaCount {
                got: 1,
                expected: 8
            })
        ));
    }
}
