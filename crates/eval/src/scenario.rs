//! Simulated datasets from a scenario file and Monte-Carlo evaluation over
//! seeds.

use insuwb_fusion::scenario::{ScenarioError, ScenarioFile};
use insuwb_msg::FilterKind;

use crate::metrics::{mean_of, Metrics};
use crate::run::{evaluate, Dataset, EvalError};

/// Why a scenario could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioRunError {
    /// The scenario could not be loaded or simulated.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The evaluation failed.
    #[error(transparent)]
    Eval(#[from] EvalError),
}

/// The scenario of `file` simulated with `seed`, as a dataset to evaluate.
///
/// # Errors
/// A simulation failure.
pub fn dataset(file: &ScenarioFile, seed: u64) -> Result<Dataset, ScenarioError> {
    let out = file.simulate(seed)?;
    Ok(Dataset {
        name: format!("{} (seed {seed})", file.sim.name),
        imu: out.imu,
        tdoa: out.tdoa,
        truth: out.truth,
        velocity: Vec::new(),
        segment: None,
    })
}

/// Mean metrics per solution over `runs` seeds starting at `seed`.
///
/// # Errors
/// The first run that fails.
pub fn monte_carlo(
    file: &ScenarioFile,
    filters: &[FilterKind],
    runs: u32,
    seed: u64,
) -> Result<Vec<(String, Metrics)>, ScenarioRunError> {
    let mut per: Vec<(String, Vec<Metrics>)> = Vec::new();
    for r in 0..u64::from(runs.max(1)) {
        let s = seed.wrapping_add(r);
        let data = dataset(file, s)?;
        let cfg = file.fusion_for_seed(s)?;
        let rep = evaluate(&data, &cfg, filters)?;
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
