//! Runs every solution (UWB-only, INS-only, each filter) on one dataset and
//! evaluates them at the same epochs ([`Epochs`]): the UWB fix epochs, or the
//! ground-truth sample times with each solution interpolated there (how the
//! UTIL dataset's references are measured).

use insuwb_fusion::config::{build_estimator, ConfigError, FusionConfig};
use insuwb_fusion::runner::{self, RunOutput};
use insuwb_msg::{
    BodyVelocity, FilterDiag, FilterKind, FusedState, GroundTruth, Height, ImuSample, NavState,
    UwbFix, UwbRange, UwbTdoa,
};

use crate::metrics::{compute, Estimate, Metrics, MetricsError, TruthTrack};

/// A dataset to evaluate: sensor streams and ground truth, time-sorted.
#[derive(Debug, Clone, Default)]
pub struct Dataset {
    /// Name for reports.
    pub name: String,
    /// IMU samples.
    pub imu: Vec<ImuSample>,
    /// TDOA measurements.
    pub tdoa: Vec<UwbTdoa>,
    /// Two-way ranges (a ranging log); when present the fixes and the
    /// tight filter use them instead of `tdoa`.
    pub range: Vec<UwbRange>,
    /// Ground truth.
    pub truth: Vec<GroundTruth>,
    /// Body-frame velocities (odometry, flow) the filters are aided with;
    /// empty: no aiding.
    pub velocity: Vec<BodyVelocity>,
    /// Heights (a range finder's) the filters are aided with; empty: none.
    pub height: Vec<Height>,
    /// Evaluate only epochs inside this span (ns), e.g. the flight segment.
    pub segment: Option<(u64, u64)>,
}

/// One solution's results.
#[derive(Debug, Clone)]
pub struct Solution {
    /// JSON key (`uwb`, `ins`, `kf`, ...).
    pub key: String,
    /// Metrics at the common epochs.
    pub metrics: Metrics,
    /// Its estimates at the common epochs (for plots).
    pub track: Vec<Estimate>,
    /// Full output of a filter run (absent for `uwb` and `ins`).
    pub run: Option<RunOutput>,
}

/// Why an evaluation failed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A run could not start.
    #[error(transparent)]
    Run(#[from] ConfigError),
    /// Metrics could not be computed for a solution.
    #[error("{solution}: {error}")]
    Metrics {
        /// The solution.
        solution: String,
        /// Why.
        error: MetricsError,
    },
    /// The UWB system produced no fix at all.
    #[error("no UWB fix could be computed from {tdoa} TDOA measurements and {range} ranges")]
    NoFixes {
        /// TDOA measurements given.
        tdoa: usize,
        /// Two-way ranges given.
        range: usize,
    },
}

/// Everything an evaluation produced.
#[derive(Debug, Clone)]
pub struct EvalReport {
    /// Dataset name.
    pub dataset: String,
    /// Solutions, in order: uwb, ins, then the filters as asked.
    pub solutions: Vec<Solution>,
    /// The epochs (ns).
    pub epochs: Vec<u64>,
}

/// Maximum truth gap bridged by interpolation (ns).
const TRUTH_MAX_GAP_NS: u64 = 100_000_000;

/// Longest gap between two estimates of a solution that
/// [`Epochs::Truth`] interpolates across (ns): 1 s, ten fix periods.
pub const ESTIMATE_MAX_GAP_NS: u64 = 1_000_000_000;

/// Truth samples closer than this to the previous one are not evaluated
/// again (ns): motion-capture logs hold near-duplicate stamps 20 us apart.
const TRUTH_MIN_SPACING_NS: u64 = 1_000_000;

/// Which part of a log is evaluated (`[eval] segment`, a manifest's
/// `segment` column, `insuwb eval --segment`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Segment {
    /// The flight: from the first to the last instant the ground truth is
    /// above `[eval] min_height_m` (a log that never rises above it is an
    /// error, naming this setting).
    #[default]
    Flight,
    /// The whole log (a vehicle that stays on the floor).
    All,
}

impl std::str::FromStr for Segment {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "flight" => Ok(Self::Flight),
            "all" => Ok(Self::All),
            other => Err(format!("unknown segment `{other}` (flight, all)")),
        }
    }
}

/// Where every solution is evaluated (`[eval] epochs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Epochs {
    /// At the UWB fix epochs, each filter's state published for that epoch
    /// (the paper's Table 1).
    #[default]
    Fixes,
    /// At the ground-truth sample times, each solution linearly
    /// interpolated between its estimates around that time (fixes, INS
    /// states, published fused states; no extrapolation, no bridge over
    /// [`ESTIMATE_MAX_GAP_NS`]): the UTIL dataset's references are measured
    /// this way, so a ratio to them compares like with like.
    Truth,
}

/// Runs UWB-only, INS-only and each of `filters` on `data`, evaluated at the
/// UWB fix epochs ([`Epochs::Fixes`]).
///
/// # Errors
/// A configuration that does not validate, no UWB fix, or non-finite output.
pub fn evaluate(
    data: &Dataset,
    cfg: &FusionConfig,
    filters: &[FilterKind],
) -> Result<EvalReport, EvalError> {
    evaluate_at(data, cfg, filters, Epochs::Fixes)
}

/// [`evaluate`] at the epochs `at` says.
///
/// # Errors
/// As [`evaluate`].
pub fn evaluate_at(
    data: &Dataset,
    cfg: &FusionConfig,
    filters: &[FilterKind],
    at: Epochs,
) -> Result<EvalReport, EvalError> {
    let truth = TruthTrack::new(&data.truth, TRUTH_MAX_GAP_NS);
    let ranging = data.is_ranging();
    let fixes = if ranging {
        runner::run_fixes(&data.range, cfg)?
    } else {
        runner::run_fixes(&data.tdoa, cfg)?
    };
    if fixes.is_empty() {
        return Err(EvalError::NoFixes {
            tdoa: data.tdoa.len(),
            range: data.range.len(),
        });
    }
    let fix_epochs: Vec<u64> = fixes.iter().map(|f| f.header.meas_time_ns).collect();
    let epochs = match at {
        Epochs::Fixes => fix_epochs.clone(),
        Epochs::Truth => truth_epochs(&data.truth),
    };
    let resample = |track: Vec<Estimate>| match at {
        Epochs::Fixes => track,
        Epochs::Truth => interpolate(&track, &epochs, ESTIMATE_MAX_GAP_NS),
    };
    let mut solutions = Vec::new();
    let uwb_track: Vec<Estimate> = fixes.iter().map(fix_estimate).collect();
    solutions.push(solution(
        "uwb",
        resample(uwb_track),
        &truth,
        data.segment,
        &[],
        None,
    )?);

    let nav = runner::run_ins_only(&data.imu, cfg)?;
    let ins_track = sample_nav(&nav, &epochs);
    solutions.push(solution("ins", ins_track, &truth, data.segment, &[], None)?);

    for &kind in filters {
        let est = build_estimator(kind, cfg)?;
        let out = if ranging {
            runner::run_aided(
                &data.imu,
                &data.range,
                &data.velocity,
                &data.height,
                cfg,
                est,
            )?
        } else {
            runner::run_aided(
                &data.imu,
                &data.tdoa,
                &data.velocity,
                &data.height,
                cfg,
                est,
            )?
        };
        let track = match at {
            Epochs::Fixes => sample_fused(&out.fused, &fix_epochs),
            Epochs::Truth => interpolate(&published(&out.fused), &epochs, ESTIMATE_MAX_GAP_NS),
        };
        let nis: Vec<f64> = out.diag.iter().map(|d| d.nis).collect();
        solutions.push(solution(
            solution_key(kind, ranging),
            track,
            &truth,
            data.segment,
            &nis,
            Some(out),
        )?);
    }
    Ok(EvalReport {
        dataset: data.name.clone(),
        solutions,
        epochs,
    })
}

/// The name of the tight filter when it fuses two-way ranges.
pub const TIGHT_TWR_KEY: &str = "iakf_twr";

/// A filter's solution key: its name, but [`TIGHT_TWR_KEY`] for the tight
/// filter on a ranging log (`iakf_tdoa` stays the TDOA one).
#[must_use]
pub fn solution_key(kind: FilterKind, ranging: bool) -> &'static str {
    if ranging && kind == FilterKind::IakfTdoa {
        TIGHT_TWR_KEY
    } else {
        kind.name()
    }
}

impl Dataset {
    /// Whether the UWB measurements are two-way ranges (the dataset holds
    /// ranges and no TDOA difference).
    #[must_use]
    pub fn is_ranging(&self) -> bool {
        !self.range.is_empty() && self.tdoa.is_empty()
    }
}

fn solution(
    key: &str,
    track: Vec<Estimate>,
    truth: &TruthTrack<'_>,
    segment: Option<(u64, u64)>,
    nis: &[f64],
    run: Option<RunOutput>,
) -> Result<Solution, EvalError> {
    let mut metrics =
        compute(&track, truth, segment, nis).map_err(|source| EvalError::Metrics {
            solution: key.to_owned(),
            error: source,
        })?;
    if let Some(r) = &run {
        let inside = |t: u64| segment.is_none_or(|(a, b)| (a..=b).contains(&t));
        let n = r
            .diag
            .iter()
            .filter(|d| d.header.flags & FilterDiag::FLAG_DIVERGENCE != 0)
            .filter(|d| inside(d.header.meas_time_ns))
            .count();
        // Counts stay far below 2^53: exact in f64.
        #[allow(clippy::cast_precision_loss)]
        let n = n as f64;
        metrics.divergences = Some(n);
    }
    Ok(Solution {
        key: key.to_owned(),
        metrics,
        track,
        run,
    })
}

fn fix_estimate(f: &UwbFix) -> Estimate {
    Estimate {
        t_ns: f.header.meas_time_ns,
        pos_en_m: [f.pos_m[0], f.pos_m[1]],
        up_m: f.pos_m[2],
        vel_en_mps: None,
        cov4: None,
        yaw_rad: None,
    }
}

/// INS states interpolated at the epochs.
fn sample_nav(nav: &[NavState], epochs: &[u64]) -> Vec<Estimate> {
    epochs
        .iter()
        .filter_map(|&t| {
            let i = nav.partition_point(|n| n.header.meas_time_ns < t);
            let b = nav.get(i)?;
            let a = if b.header.meas_time_ns == t {
                b
            } else {
                nav.get(i.checked_sub(1)?)?
            };
            let (ta, tb) = (a.header.meas_time_ns, b.header.meas_time_ns);
            let w = if tb > ta {
                (t - ta) as f64 / (tb - ta) as f64
            } else {
                0.0
            };
            let p = |k: usize| a.pos_m[k] + w * (b.pos_m[k] - a.pos_m[k]);
            Some(Estimate {
                t_ns: t,
                pos_en_m: [p(0), p(1)],
                up_m: p(2),
                vel_en_mps: None,
                cov4: None,
                yaw_rad: None,
            })
        })
        .collect()
}

/// The ground-truth sample times, near-duplicates dropped.
fn truth_epochs(truth: &[GroundTruth]) -> Vec<u64> {
    let mut out: Vec<u64> = Vec::with_capacity(truth.len());
    for g in truth {
        let t = g.header.meas_time_ns;
        if out
            .last()
            .is_none_or(|&p| t >= p.saturating_add(TRUTH_MIN_SPACING_NS))
        {
            out.push(t);
        }
    }
    out
}

/// Every published fused state as an estimate, the last one of each
/// measurement time (an update may follow a reset at the same epoch).
fn published(fused: &[FusedState]) -> Vec<Estimate> {
    let mut out: Vec<Estimate> = Vec::with_capacity(fused.len());
    for f in fused {
        let e = fused_estimate(f);
        match out.last_mut() {
            Some(last) if last.t_ns == e.t_ns => *last = e,
            Some(last) if last.t_ns > e.t_ns => {}
            _ => out.push(e),
        }
    }
    out
}

/// `track` (time-sorted) linearly interpolated at each of `epochs` between
/// the two estimates around it: position, and velocity and covariance where
/// both have them (a convex combination of two covariances is one). Epochs
/// before the first or after the last estimate, or inside a gap longer than
/// `max_gap_ns`, are skipped.
#[must_use]
pub fn interpolate(track: &[Estimate], epochs: &[u64], max_gap_ns: u64) -> Vec<Estimate> {
    let mut out = Vec::with_capacity(epochs.len());
    for &t in epochs {
        let i = track.partition_point(|e| e.t_ns < t);
        let Some(b) = track.get(i) else {
            continue;
        };
        if b.t_ns == t {
            out.push(*b);
            continue;
        }
        let Some(a) = i.checked_sub(1).and_then(|j| track.get(j)) else {
            continue;
        };
        if b.t_ns - a.t_ns > max_gap_ns {
            continue;
        }
        let w = (t - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
        let lerp = |x: f64, y: f64| x + w * (y - x);
        let vel_en_mps = match (a.vel_en_mps, b.vel_en_mps) {
            (Some(va), Some(vb)) => Some([lerp(va[0], vb[0]), lerp(va[1], vb[1])]),
            _ => None,
        };
        let cov4 = match (a.cov4, b.cov4) {
            (Some(ca), Some(cb)) => Some(std::array::from_fn(|r| {
                std::array::from_fn(|c| lerp(ca[r][c], cb[r][c]))
            })),
            _ => None,
        };
        // Along the shorter way round.
        let yaw_rad = match (a.yaw_rad, b.yaw_rad) {
            (Some(ya), Some(yb)) => {
                let d = (yb - ya + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                Some(wrap_pi(ya + w * d))
            }
            _ => None,
        };
        out.push(Estimate {
            t_ns: t,
            pos_en_m: [
                lerp(a.pos_en_m[0], b.pos_en_m[0]),
                lerp(a.pos_en_m[1], b.pos_en_m[1]),
            ],
            up_m: lerp(a.up_m, b.up_m),
            vel_en_mps,
            cov4,
            yaw_rad,
        });
    }
    out
}

/// The fused state at each epoch (the state published for the update at
/// that epoch; epochs with no update are skipped).
fn sample_fused(fused: &[FusedState], epochs: &[u64]) -> Vec<Estimate> {
    let mut out = Vec::with_capacity(epochs.len());
    let mut j = 0usize;
    for &t in epochs {
        while j < fused.len() && fused[j].header.meas_time_ns < t {
            j += 1;
        }
        // The last state published for this epoch (an update may follow a reset).
        let mut k = j;
        while k + 1 < fused.len() && fused[k + 1].header.meas_time_ns == t {
            k += 1;
        }
        if let Some(f) = fused.get(k).filter(|f| f.header.meas_time_ns == t) {
            out.push(fused_estimate(f));
        }
    }
    out
}

/// `a` in [-pi, pi).
fn wrap_pi(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// A fused state as an [`Estimate`] with its covariance.
#[must_use]
pub fn fused_estimate(f: &FusedState) -> Estimate {
    let idx = [0usize, 1, 3, 4];
    let mut cov4 = [[0.0; 4]; 4];
    for (i, a) in idx.iter().enumerate() {
        for (j, b) in idx.iter().enumerate() {
            cov4[i][j] = f.cov[*a][*b];
        }
    }
    Estimate {
        t_ns: f.header.meas_time_ns,
        pos_en_m: [f.pos_m[0], f.pos_m[1]],
        up_m: f.pos_m[2],
        vel_en_mps: Some([f.vel_mps[0], f.vel_mps[1]]),
        cov4: Some(cov4),
        yaw_rad: Some(f.yaw_rad),
    }
}

/// Per-solution metrics as one JSON object keyed by solution; refuses non-finite numbers.
///
/// # Errors
/// The name of the first solution holding a non-finite number.
pub fn to_json(solutions: &[(String, Metrics)]) -> Result<serde_json::Value, String> {
    let mut map = serde_json::Map::new();
    for (key, m) in solutions {
        let v = serde_json::to_value(m).map_err(|e| format!("{key}: {e}"))?;
        if !all_finite(&v) {
            return Err(format!("{key}: a metric is not finite"));
        }
        map.insert(key.clone(), v);
    }
    Ok(serde_json::Value::Object(map))
}

fn all_finite(v: &serde_json::Value) -> bool {
    match v {
        serde_json::Value::Null => false,
        serde_json::Value::Number(n) => n.as_f64().is_some_and(f64::is_finite),
        serde_json::Value::Array(a) => a.iter().all(all_finite),
        serde_json::Value::Object(o) => o.values().all(all_finite),
        _ => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn est(t_ns: u64, e: f64, cov: f64) -> Estimate {
        Estimate {
            t_ns,
            pos_en_m: [e, -e],
            up_m: 0.0,
            vel_en_mps: Some([2.0 * e, 0.0]),
            cov4: Some([[cov; 4]; 4]),
            yaw_rad: None,
        }
    }

    #[test]
    fn interpolation_is_linear_inside_and_skips_outside_and_gaps() {
        let track = [est(100, 1.0, 1.0), est(200, 2.0, 3.0), est(5_000, 4.0, 1.0)];
        let out = interpolate(&track, &[50, 100, 125, 200, 1_000, 6_000], 1_000);
        let times: Vec<u64> = out.iter().map(|e| e.t_ns).collect();
        // 50: before the first; 1000: inside the 4.8 us gap; 6000: after the last.
        assert_eq!(times, vec![100, 125, 200]);
        assert_eq!(out[0], track[0]);
        assert!((out[1].pos_en_m[0] - 1.25).abs() < 1e-12);
        assert!((out[1].pos_en_m[1] + 1.25).abs() < 1e-12);
        assert_eq!(out[1].vel_en_mps.map(|v| v[0]), Some(2.5));
        assert_eq!(out[1].cov4.map(|c| c[2][3]), Some(1.5));
        assert_eq!(out[2], track[1]);
    }

    #[test]
    fn interpolation_keeps_missing_velocity_and_covariance_missing() {
        let a = Estimate {
            t_ns: 0,
            pos_en_m: [0.0, 0.0],
            up_m: 0.0,
            vel_en_mps: None,
            cov4: None,
            yaw_rad: None,
        };
        let b = est(10, 1.0, 1.0);
        let out = interpolate(&[a, b], &[5], 100);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].pos_en_m, [0.5, -0.5]);
        assert_eq!(out[0].vel_en_mps, None);
        assert_eq!(out[0].cov4, None);
    }

    #[test]
    fn truth_epochs_drop_near_duplicate_stamps() {
        let g = |t: u64| {
            let mut g = GroundTruth::default();
            g.header.meas_time_ns = t;
            g
        };
        let truth = [g(0), g(20_000), g(4_000_000), g(4_500_000), g(5_000_000)];
        assert_eq!(truth_epochs(&truth), vec![0, 4_000_000, 5_000_000]);
    }

    #[test]
    fn the_last_state_of_an_epoch_is_the_published_one() {
        let f = |t: u64, x: f64| {
            let mut f = FusedState::default();
            f.header.meas_time_ns = t;
            f.pos_m = [x, 0.0, 0.0];
            f
        };
        let out = published(&[f(10, 1.0), f(10, 2.0), f(20, 3.0), f(15, 9.0)]);
        let got: Vec<(u64, f64)> = out.iter().map(|e| (e.t_ns, e.pos_en_m[0])).collect();
        assert_eq!(got, vec![(10, 2.0), (20, 3.0)]);
    }
}
