//! The fusion configuration ([`FusionConfig`], the `[fusion]` table of a
//! scenario, preset or fusion settings file, and of a log's metadata) and
//! the construction of the estimator it describes ([`build_estimator`]),
//! shared by the stages, the lockstep runner ([`crate::runner`]) and
//! `insuwb eval`.

use insuwb_msg::FilterKind;
use serde::{Deserialize, Serialize};

use crate::engine::FusionEngineConfig;
use crate::estimator::{Estimator, LooseConfig, LooseConfigError, PaperEstimator};
use crate::ins_engine::{InsEngineConfig, InsEngineError};
use crate::output::{OutputPolicyConfig, OutputPolicyConfigError};
use crate::tight::{TightBuildError, TightConfig, TightEstimator};
use crate::vehicle::{GroundConfig, MultirotorConfig, VehicleConfigError, VehicleSettings};
use crate::vibration::{VibrationConfig, VibrationConfigError};
use insuwb_nav::vehicle::VehicleKind;

/// Everything a run needs: the INS, the fix builder, the engine, every
/// filter's settings and the runner's output policy.
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
    /// The vehicle model of the INS and every filter: `free` (default, the
    /// paper's), `multirotor` (thrust along body z, rotor drag) or `ground`
    /// (no lateral or vertical body velocity); see [`crate::vehicle`].
    pub vehicle: VehicleKind,
    /// The multirotor model's settings (`vehicle = "multirotor"`).
    pub multirotor: MultirotorConfig,
    /// The ground model's settings (`vehicle = "ground"`).
    pub ground: GroundConfig,
    /// The velocity updates' settings (odometry, flow): each source's
    /// online scale factor ([`crate::aiding`]).
    pub aiding: crate::aiding::AidingConfig,
    /// The coasting and stale-input policy (`[fusion.output]`), its one
    /// home: the fusion stage applies it on the monotonic clock (its
    /// defaults where absent), the lockstep runner on the recording's clock
    /// (absent: the runner publishes the updates' fused states only).
    pub output: Option<OutputPolicyConfig>,
    /// The site calibration of the TDOA differences, applied by the fix
    /// builder before the fixes and the tight filter use them
    /// (`insuwb_uwb::calibration`). Never read from or written to a
    /// `[fusion]` table: it comes from a file named on the command line
    /// (`--calibration`) or in the robot config (`[uwb] calibration`).
    #[serde(skip)]
    pub calibration: Option<std::sync::Arc<insuwb_uwb::calibration::SiteCalibration>>,
}

/// Why a fusion configuration was refused (by [`build_estimator`], or by
/// the lockstep runner building its INS, fix builder and output policy).
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
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
    /// The vehicle model's settings were refused.
    #[error(transparent)]
    Vehicle(#[from] VehicleConfigError),
    /// The velocity aiding's settings were refused.
    #[error(transparent)]
    Aiding(#[from] crate::aiding::AidingConfigError),
    /// The engine's divergence monitor config was refused (the message
    /// names the key, `engine.monitor.*`).
    #[error("engine.{0}")]
    Engine(insuwb_filter::MonitorConfigError),
    /// The runner's output policy was refused (the message names the key,
    /// `output.*`).
    #[error("output.{0}")]
    Output(OutputPolicyConfigError),
}

impl From<insuwb_uwb::fix::FixConfigError> for ConfigError {
    fn from(e: insuwb_uwb::fix::FixConfigError) -> Self {
        Self::Fix(e)
    }
}

impl From<insuwb_filter::ModelConfigError> for ConfigError {
    fn from(e: insuwb_filter::ModelConfigError) -> Self {
        Self::Model(e)
    }
}

impl From<insuwb_filter::BuildError> for ConfigError {
    fn from(e: insuwb_filter::BuildError) -> Self {
        Self::Filter(e)
    }
}

impl From<insuwb_filter::MonitorConfigError> for ConfigError {
    fn from(e: insuwb_filter::MonitorConfigError) -> Self {
        Self::Engine(e)
    }
}

impl From<OutputPolicyConfigError> for ConfigError {
    fn from(e: OutputPolicyConfigError) -> Self {
        Self::Output(e)
    }
}

impl FusionConfig {
    /// The vehicle model's settings.
    #[must_use]
    pub fn vehicle_settings(&self) -> VehicleSettings<'_> {
        VehicleSettings {
            kind: self.vehicle,
            multirotor: &self.multirotor,
            ground: &self.ground,
        }
    }

    /// The INS engine's settings with the vehicle's mechanisation: what
    /// every INS of a run (the INS stage, the lockstep runner) is built from.
    #[must_use]
    pub fn ins_engine_config(&self) -> InsEngineConfig {
        let mut ins = self.ins.clone();
        ins.ins.mechanisation = self.vehicle_settings().mechanisation();
        ins.free_handover = (self.vehicle == insuwb_nav::vehicle::VehicleKind::Multirotor
            && self.multirotor.free_above_signal_ratio > 0.0)
            .then_some(crate::ins_engine::FreeHandover {
                ratio: self.multirotor.free_above_signal_ratio,
                window_s: self.multirotor.signal_window_s,
            });
        ins
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
) -> Result<Box<dyn Estimator>, ConfigError> {
    cfg.engine.validate()?;
    cfg.vibration.validate()?;
    let vehicle = cfg.vehicle_settings();
    vehicle.validate()?;
    cfg.aiding.validate()?;
    cfg.loose.validate()?;
    if kind == FilterKind::IakfTdoa {
        return Ok(Box::new(
            TightEstimator::new(
                cfg.eskf.clone(),
                cfg.tight.clone(),
                cfg.ins.ins.gravity_mps2,
            )?
            .with_vibration(cfg.vibration.clone())
            .with_vehicle(&vehicle)
            .with_aiding(&cfg.aiding, cfg.loose.scale_baseline_m)
            .with_calibration(cfg.calibration.as_deref()),
        ));
    }
    let model = insuwb_filter::PaperModel::new(cfg.model.clone())?;
    let f = insuwb_filter::build(kind, model, &cfg.filter, &cfg.setup)?;
    Ok(Box::new(
        PaperEstimator::new(f, cfg.loose.clone(), cfg.setup.p0())
            .with_gravity(cfg.ins.ins.gravity_mps2)
            .with_vibration(cfg.vibration.clone())
            .with_vehicle(&vehicle)
            .with_aiding(&cfg.aiding),
    ))
}
