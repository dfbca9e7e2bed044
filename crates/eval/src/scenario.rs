//! Simulated datasets from a scenario file and Monte-Carlo evaluation over
//! seeds.

use insuwb_fusion::scenario::{ScenarioError, ScenarioFile};
use insuwb_msg::FilterKind;

use crate::metrics::{mean_of, Metrics};
use crate::run::{evaluate_at, Dataset, Epochs, EvalError};

/// Why a scenario could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioRunError {
    /// The scenario could not be loaded or simulated.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The evaluation failed.
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// The options do not fit the scenario.
    #[error("{0}")]
    Options(String),
}

/// What the filters of a scenario's evaluation are aided with, and where
/// they are evaluated. The default is the paper's evaluation: IMU and UWB
/// alone, at the UWB fix epochs, over the whole run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ScenarioOptions {
    /// The sources (`BodyVelocity::SOURCE_ODOMETRY`, `SOURCE_FLOW`) whose
    /// simulated body velocities aid the filters; empty (default): none.
    pub velocity_sources: Vec<u32>,
    /// Evaluate at the ground truth's sample times inside `[start, end]`
    /// (s from the start of the run), each solution interpolated there
    /// ([`Epochs::Truth`]: the filters' coasting states count where the
    /// scenario's `[fusion.output]` makes them), instead of at the fix
    /// epochs of the whole run (None, default). A UWB outage has no fix
    /// epoch: this is how a solution is measured through one.
    pub window_s: Option<[f64; 2]>,
}

impl ScenarioOptions {
    /// Checks the window: finite, `0 <= start < end`.
    ///
    /// # Errors
    /// [`ScenarioRunError::Options`] naming the window.
    pub fn validate(&self) -> Result<(), ScenarioRunError> {
        if let Some([a, b]) = self.window_s {
            if !(a.is_finite() && b.is_finite() && a >= 0.0 && a < b) {
                return Err(ScenarioRunError::Options(format!(
                    "the evaluation window must be 0 <= start < end (s), got {a}..{b}"
                )));
            }
        }
        Ok(())
    }
}

/// The scenario of `file` simulated with `seed`, as a dataset to evaluate,
/// with every body velocity the scenario simulates (`[sim.odometry]`,
/// `[sim.flow]`; none without them).
///
/// # Errors
/// A simulation failure.
pub fn dataset(file: &ScenarioFile, seed: u64) -> Result<Dataset, ScenarioError> {
    let out = file.simulate(seed)?;
    Ok(Dataset {
        name: format!("{} (seed {seed})", file.sim.name),
        imu: out.imu,
        tdoa: out.tdoa,
        range: out.range,
        truth: out.truth,
        velocity: out.velocity,
        height: out.height,
        segment: None,
    })
}

/// [`dataset`] with the body velocities of `opts.velocity_sources` alone (and
/// the range finder's heights with the flow's) and
/// the evaluation window of `opts` as its segment.
///
/// # Errors
/// A simulation failure; a source asked for that the scenario does not
/// simulate.
pub fn dataset_with(
    file: &ScenarioFile,
    seed: u64,
    opts: &ScenarioOptions,
) -> Result<Dataset, ScenarioRunError> {
    opts.validate()?;
    let mut data = dataset(file, seed)?;
    for &source in &opts.velocity_sources {
        if !data.velocity.iter().any(|v| v.source == source) {
            let table = match source {
                insuwb_msg::BodyVelocity::SOURCE_ODOMETRY => "[sim.odometry]",
                insuwb_msg::BodyVelocity::SOURCE_FLOW => "[sim.flow]",
                _ => "a table for it",
            };
            return Err(ScenarioRunError::Options(format!(
                "scenario {}: no body velocity of source {source} to aid with (it needs {table})",
                file.sim.name
            )));
        }
    }
    data.velocity
        .retain(|v| opts.velocity_sources.contains(&v.source));
    // The range finder's heights come with the flow deck's velocities.
    if !opts
        .velocity_sources
        .contains(&insuwb_msg::BodyVelocity::SOURCE_FLOW)
    {
        data.height.clear();
    }
    data.segment = opts
        .window_s
        .map(|[a, b]| (seconds_to_ns(a), seconds_to_ns(b)));
    Ok(data)
}

/// Seconds (finite, >= 0: [`ScenarioOptions::validate`]) to nanoseconds.
fn seconds_to_ns(t_s: f64) -> u64 {
    (t_s * 1e9).round().clamp(0.0, u64::MAX as f64) as u64
}

/// Mean metrics per solution over `runs` seeds starting at `seed`, the
/// paper's evaluation ([`ScenarioOptions::default`]).
///
/// # Errors
/// The first run that fails.
pub fn monte_carlo(
    file: &ScenarioFile,
    filters: &[FilterKind],
    runs: u32,
    seed: u64,
) -> Result<Vec<(String, Metrics)>, ScenarioRunError> {
    monte_carlo_with(file, filters, runs, seed, &ScenarioOptions::default())
}

/// Mean metrics per solution over `runs` seeds starting at `seed`, aided
/// and evaluated as `opts` says.
///
/// # Errors
/// The first run that fails, or options that do not fit the scenario.
pub fn monte_carlo_with(
    file: &ScenarioFile,
    filters: &[FilterKind],
    runs: u32,
    seed: u64,
    opts: &ScenarioOptions,
) -> Result<Vec<(String, Metrics)>, ScenarioRunError> {
    let epochs = if opts.window_s.is_some() {
        Epochs::Truth
    } else {
        Epochs::Fixes
    };
    let mut per: Vec<(String, Vec<Metrics>)> = Vec::new();
    for r in 0..u64::from(runs.max(1)) {
        let s = seed.wrapping_add(r);
        let data = dataset_with(file, s, opts)?;
        let cfg = file.fusion_for_seed(s)?;
        let rep = evaluate_at(&data, &cfg, filters, epochs)?;
        for sol in rep.solutions {
            match per.iter_mut().find(|(k, _)| *k == sol.key) {
                Some((_, v)) => v.push(sol.metrics),
                None => per.push((sol.key, vec![sol.metrics])),
            }
        }
    }
    Ok(per
        .into_iter()
        .filter_map(|(k, v)| mean_of(&v).map(|m| (k, m)))
        .collect())
}
