//! Runs every solution (UWB-only, INS-only, each filter) on one dataset and
//! evaluates them at the same epochs: the UWB fix epochs.

use insuwb_fusion::offline::{self, FusionConfig, RunError, RunOutput};
use insuwb_msg::{FilterKind, FusedState, GroundTruth, ImuSample, NavState, UwbFix, UwbTdoa};

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
    /// Ground truth.
    pub truth: Vec<GroundTruth>,
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
    Run(#[from] RunError),
    /// Metrics could not be computed for a solution.
    #[error("{solution}: {error}")]
    Metrics {
        /// The solution.
        solution: String,
        /// Why.
        error: MetricsError,
    },
    /// The UWB system produced no fix at all.
    #[error("no UWB fix could be computed from {tdoa} TDOA measurements")]
    NoFixes {
        /// Measurements given.
        tdoa: usize,
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

/// Runs UWB-only, INS-only and each of `filters` on `data`.
///
/// # Errors
/// A configuration that does not validate, no UWB fix, or non-finite output.
pub fn evaluate(
    data: &Dataset,
    cfg: &FusionConfig,
    filters: &[FilterKind],
) -> Result<EvalReport, EvalError> {
    let truth = TruthTrack::new(&data.truth, TRUTH_MAX_GAP_NS);
    let fixes = offline::run_fixes(&data.tdoa, cfg)?;
    if fixes.is_empty() {
        return Err(EvalError::NoFixes {
            tdoa: data.tdoa.len(),
        });
    }
    let epochs: Vec<u64> = fixes.iter().map(|f| f.header.meas_time_ns).collect();
    let mut solutions = Vec::new();
    let uwb_track: Vec<Estimate> = fixes.iter().map(fix_estimate).collect();
    solutions.push(solution("uwb", uwb_track, &truth, data.segment, &[], None)?);

    let nav = offline::run_ins_only(&data.imu, cfg)?;
    let ins_track = sample_nav(&nav, &epochs);
    solutions.push(solution("ins", ins_track, &truth, data.segment, &[], None)?);

    for &kind in filters {
        let est = offline::build_estimator(kind, cfg)?;
        let out = offline::run_with(&data.imu, &data.tdoa, cfg, est)?;
        let track = sample_fused(&out.fused, &epochs);
        let nis: Vec<f64> = out.diag.iter().map(|d| d.nis).collect();
        solutions.push(solution(
            kind.name(),
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

fn solution(
    key: &str,
    track: Vec<Estimate>,
    truth: &TruthTrack<'_>,
    segment: Option<(u64, u64)>,
    nis: &[f64],
    run: Option<RunOutput>,
) -> Result<Solution, EvalError> {
    let metrics = compute(&track, truth, segment, nis).map_err(|source| EvalError::Metrics {
        solution: key.to_owned(),
        error: source,
    })?;
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
        vel_en_mps: None,
        cov4: None,
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
                vel_en_mps: None,
                cov4: None,
            })
        })
        .collect()
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
        vel_en_mps: Some([f.vel_mps[0], f.vel_mps[1]]),
        cov4: Some(cov4),
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
