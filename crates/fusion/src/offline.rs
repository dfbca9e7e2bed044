//! In-process, lockstep runs of the whole chain on recorded samples: the
//! fix builder of the UWB driver, the INS engine of the INS stage and the
//! fusion engine of the fusion stage, wired exactly as the processes are, so
//! `insuwb eval` and a replay through the pipeline give the same result.

use insuwb_msg::{
    FilterDiag, FilterKind, FusedState, ImuSample, InsCorrection, NavState, UwbFix, UwbTdoa,
};
use serde::{Deserialize, Serialize};

use crate::engine::{FusionCounters, FusionEngine, FusionEngineConfig, Measurement, Outputs};
use crate::estimator::{Estimator, LooseConfig, LooseConfigError, PaperEstimator};
use crate::ins_engine::{InsCounters, InsEngine, InsEngineConfig, InsEngineError};
use crate::tight::{TightBuildError, TightConfig, TightEstimator};
use crate::vibration::{VibrationConfig, VibrationConfigError};

/// Everything a run needs: the INS, the fix builder, the engine and every filter's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct FusionConfig {
    /// INS engine (mechanisation, initial state, alignment).
    pub ins: InsEngineConfig,
    /// UWB fix builder (the UWB driver's multilateration).
    pub fix: insuwb_uwb::fix::FixConfig,
    /// Fusion engine, with the divergence monitor of every filter (`monitor`).
    pub engine: FusionEngineConfig,
    /// The paper's error model (shared by KF, SHAF, STF, IAKF).
    pub model: insuwb_filter::ModelConfig,
    /// Adaptive parameters (b, kappa, gamma, fading cap, R clamps, rho, beta).
    pub filter: insuwb_filter::FilterParams,
    /// `P_0` and `R_0` shared by the paper's filters.
    pub setup: insuwb_filter::FilterSetup,
    /// Loose-coupling options.
    pub loose: LooseConfig,
    /// The tightly coupled error-state filter (`iakf_tdoa`): noise, initial
    /// uncertainty, TDOA noise and robust weighting.
    pub eskf: insuwb_eskf::EskfConfig,
    /// Tight-coupling settings outside the ESKF (antenna lever arm, specific-force smoothing).
    pub tight: TightConfig,
    /// Velocity noise from the vibration the IMU measures, for every filter.
    pub vibration: VibrationConfig,
}

/// Why a run could not start.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The INS engine config was refused.
    #[error(transparent)]
    Ins(#[from] InsEngineError),
    /// The fix builder config was refused.
    #[error("fix: {0}")]
    Fix(insuwb_uwb::fix::FixConfigError),
    /// The error model config was refused.
    #[error("model: {0}")]
    Model(insuwb_filter::ModelConfigError),
    /// A filter could not be built.
    #[error("filter: {0}")]
    Filter(insuwb_filter::BuildError),
    /// The loose-coupling settings were refused.
    #[error(transparent)]
    Loose(#[from] LooseConfigError),
    /// The tightly coupled filter could not be built.
    #[error(transparent)]
    Tight(#[from] TightBuildError),
    /// The vibration settings were refused.
    #[error(transparent)]
    Vibration(#[from] VibrationConfigError),
    /// The engine's divergence monitor config was refused (the message
    /// names the key, `engine.monitor.*`).
    #[error("engine.{0}")]
    Engine(insuwb_filter::MonitorConfigError),
}

impl From<insuwb_uwb::fix::FixConfigError> for RunError {
    fn from(e: insuwb_uwb::fix::FixConfigError) -> Self {
        Self::Fix(e)
    }
}

impl From<insuwb_filter::ModelConfigError> for RunError {
    fn from(e: insuwb_filter::ModelConfigError) -> Self {
        Self::Model(e)
    }
}

impl From<insuwb_filter::BuildError> for RunError {
    fn from(e: insuwb_filter::BuildError) -> Self {
        Self::Filter(e)
    }
}

impl From<insuwb_filter::MonitorConfigError> for RunError {
    fn from(e: insuwb_filter::MonitorConfigError) -> Self {
        Self::Engine(e)
    }
}

/// Builds the estimator for `kind` from `cfg`: the paper's filters from
/// `model`, `filter`, `setup` and `loose`; [`FilterKind::IakfTdoa`] the
/// tightly coupled ESKF from `eskf` and `tight`. Checks the engine's
/// settings too (the divergence monitor every filter gets).
///
/// # Errors
/// A model, filter or engine config that does not validate.
pub fn build_estimator(
    kind: FilterKind,
    cfg: &FusionConfig,
) -> Result<Box<dyn Estimator>, RunError> {
    cfg.engine.validate()?;
    cfg.vibration.validate()?;
    if kind == FilterKind::IakfTdoa {
        return Ok(Box::new(
            TightEstimator::new(
                cfg.eskf.clone(),
                cfg.tight.clone(),
                cfg.ins.ins.gravity_mps2,
            )?
            .with_vibration(cfg.vibration.clone()),
        ));
    }
    cfg.loose.validate()?;
    let model = insuwb_filter::PaperModel::new(cfg.model.clone())?;
    let f = insuwb_filter::build(kind, model, &cfg.filter, &cfg.setup)?;
    Ok(Box::new(
        PaperEstimator::new(f, cfg.loose.clone(), cfg.setup.p0())
            .with_gravity(cfg.ins.ins.gravity_mps2)
            .with_vibration(cfg.vibration.clone()),
    ))
}

/// What a run produced.
#[derive(Debug, Clone, Default)]
pub struct RunOutput {
    /// Fused states, one per update (and per reset).
    pub fused: Vec<FusedState>,
    /// Diagnostics, one per update.
    pub diag: Vec<FilterDiag>,
    /// Corrections sent to the INS.
    pub corrections: Vec<InsCorrection>,
    /// UWB fixes built.
    pub fixes: Vec<UwbFix>,
    /// INS counters.
    pub ins: InsCounters,
    /// Fusion counters.
    pub fusion: FusionCounters,
}

/// One input sample, in time order.
#[derive(Debug, Clone, Copy)]
enum Input<'a> {
    Imu(&'a ImuSample),
    Tdoa(&'a UwbTdoa),
}

/// Merges two time-sorted streams; at equal times the IMU sample comes first.
fn merged<'a>(imu: &'a [ImuSample], tdoa: &'a [UwbTdoa]) -> impl Iterator<Item = Input<'a>> {
    let (mut i, mut j) = (0usize, 0usize);
    std::iter::from_fn(move || match (imu.get(i), tdoa.get(j)) {
        (Some(a), Some(b)) if a.header.meas_time_ns <= b.header.meas_time_ns => {
            i += 1;
            Some(Input::Imu(a))
        }
        (_, Some(b)) => {
            j += 1;
            Some(Input::Tdoa(b))
        }
        (Some(a), None) => {
            i += 1;
            Some(Input::Imu(a))
        }
        (None, None) => None,
    })
}

/// Runs the closed loop with the filter `kind` over time-sorted IMU and TDOA samples.
///
/// # Errors
/// A configuration that does not validate.
pub fn run(
    imu: &[ImuSample],
    tdoa: &[UwbTdoa],
    cfg: &FusionConfig,
    kind: FilterKind,
) -> Result<RunOutput, RunError> {
    let est = build_estimator(kind, cfg)?;
    run_with(imu, tdoa, cfg, est)
}

/// Runs the closed loop with a given estimator.
///
/// # Errors
/// A configuration that does not validate.
pub fn run_with(
    imu: &[ImuSample],
    tdoa: &[UwbTdoa],
    cfg: &FusionConfig,
    est: Box<dyn Estimator>,
) -> Result<RunOutput, RunError> {
    cfg.engine.validate()?;
    let tight = est.is_tight();
    let mut ins = InsEngine::new(cfg.ins.clone())?;
    let mut fixb = insuwb_uwb::fix::FixBuilder::new(cfg.fix.clone())?;
    let mut fusion = FusionEngine::new(cfg.engine.clone(), est);
    let mut out = RunOutput::default();
    let mut o = Outputs::default();
    let mut renav: Vec<NavState> = Vec::new();
    for input in merged(imu, tdoa) {
        match input {
            Input::Imu(s) => {
                if let Some(n) = ins.on_imu(s) {
                    fusion.on_nav(&n, &mut o);
                }
            }
            Input::Tdoa(m) => {
                // The UWB driver publishes the fixes an incoming measurement
                // completes before the measurement itself.
                if let Ok(fixes) = fixb.push(m) {
                    for f in fixes.iter() {
                        out.fixes.push(*f);
                        fusion.on_measurement(Measurement::Fix(*f), &mut o);
                        settle(&mut ins, &mut fusion, &mut o, &mut renav, &mut out);
                    }
                }
                if tight {
                    fusion.on_measurement(Measurement::Tdoa(*m), &mut o);
                }
            }
        }
        settle(&mut ins, &mut fusion, &mut o, &mut renav, &mut out);
    }
    if let Some(f) = fixb.flush() {
        out.fixes.push(f);
        fusion.on_measurement(Measurement::Fix(f), &mut o);
        settle(&mut ins, &mut fusion, &mut o, &mut renav, &mut out);
    }
    out.ins = ins.counters();
    out.fusion = fusion.counters();
    Ok(out)
}

/// Delivers corrections to the INS and the re-propagated states back to
/// fusion until nothing is left in flight.
fn settle(
    ins: &mut InsEngine,
    fusion: &mut FusionEngine,
    o: &mut Outputs,
    renav: &mut Vec<NavState>,
    out: &mut RunOutput,
) {
    loop {
        out.fused.extend_from_slice(&o.fused);
        out.diag.extend_from_slice(&o.diag);
        let corrections: Vec<InsCorrection> = std::mem::take(&mut o.corrections);
        o.clear();
        if corrections.is_empty() {
            return;
        }
        for c in &corrections {
            out.corrections.push(*c);
            ins.on_correction(c, renav);
            for n in renav.iter() {
                fusion.on_nav(n, o);
            }
        }
    }
}

/// INS-only: integrates the IMU from the configured initial state with no correction.
///
/// # Errors
/// An INS configuration that does not validate.
pub fn run_ins_only(imu: &[ImuSample], cfg: &FusionConfig) -> Result<Vec<NavState>, RunError> {
    let mut ins = InsEngine::new(cfg.ins.clone())?;
    Ok(imu.iter().filter_map(|s| ins.on_imu(s)).collect())
}

/// The UWB fixes alone (UWB-only solution).
///
/// # Errors
/// A fix-builder configuration that does not validate.
pub fn run_fixes(tdoa: &[UwbTdoa], cfg: &FusionConfig) -> Result<Vec<UwbFix>, RunError> {
    let mut fixb = insuwb_uwb::fix::FixBuilder::new(cfg.fix.clone())?;
    let mut out = Vec::new();
    for m in tdoa {
        if let Ok(f) = fixb.push(m) {
            out.extend(f.iter().copied());
        }
    }
    out.extend(fixb.flush());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chain printed with `{:#}` (anyhow, the binaries) names each cause
    /// once: a variant that shows its inner error does not also expose it
    /// as its source.
    #[test]
    fn an_error_shows_its_cause_once() {
        let mut cfg = FusionConfig::default();
        cfg.fix.period_s = -1.0;
        let e = run(&[], &[], &cfg, FilterKind::Kf).unwrap_err();
        let text = e.to_string();
        assert!(text.starts_with("fix: period_s"), "{text}");
        assert!(std::error::Error::source(&e).is_none(), "{text}");
    }
}
