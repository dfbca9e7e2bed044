//! The tightly coupled estimator: the 15-state error-state filter of
//! `insuwb-eskf` behind the engine's [`Estimator`] interface.
//!
//! [`TightEstimator`] propagates the ESKF covariance on every INS interval
//! (3D attitude, specific force from the INS's kinematic acceleration plus
//! gravity), fuses each TDOA difference at the antenna (lever arm from
//! [`TightConfig`]), and hands the full correction (position, velocity,
//! attitude, both biases) back to the engine, which feeds it to the INS at the
//! end of each TDOA epoch. UWB fixes are not fused: the engine uses them only
//! to initialise the INS and to re-initialise it after a divergence
//! ([`Estimator::needs_reset`]).

use insuwb_eskf::{Eskf, EskfConfig, EskfConfigError, TdoaOutcome, TdoaUpdateReport};
use insuwb_msg::{FilterKind, NavState, UwbFix, UwbTdoa};
use serde::{Deserialize, Serialize};

use crate::estimator::{Delta, Estimator, InsAt, UpdateInfo};

/// Most sub-steps one INS interval is split into when it is longer than the
/// ESKF's `max_dt_s`; a longer interval is refused (counted).
const MAX_PREDICT_SPLIT: u32 = 100;

/// Settings of the tight coupling that are not the ESKF's own.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TightConfig {
    /// Position of the UWB antenna in the body frame (FLU), m. Default
    /// `[0, 0, 0]` (antenna at the IMU); the UTIL Crazyflie's is
    /// `[-0.01245, 0.00127, 0.0908]` (dataset README).
    pub lever_arm_m: [f64; 3],
    /// Time constant of the first-order low-pass applied to the specific
    /// force used in the covariance propagation, s. Default 0 (off). The
    /// ESKF's `F` couples the attitude error to the velocity error through
    /// the specific force; on a vibrating airframe the raw 1 kHz specific
    /// force (0.4-0.8 m/s^2 RMS of vibration on the UTIL Crazyflie, dataset
    /// README) lends the yaw a spurious observability, which a smoothed one
    /// avoids. The INS itself always integrates the raw samples.
    pub specific_force_tau_s: f64,
}

impl Default for TightConfig {
    fn default() -> Self {
        Self {
            lever_arm_m: [0.0; 3],
            specific_force_tau_s: 0.0,
        }
    }
}

/// A [`TightConfig`] value out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TightConfigError {
    /// A lever-arm component is not finite or longer than 10 m.
    #[error("tight.lever_arm_m[{index}] must be finite and within [-10, 10] m, got {value}")]
    LeverArm {
        /// The component.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// The smoothing time constant is negative, not finite or above 10 s.
    #[error("tight.specific_force_tau_s must be in [0, 10] s, got {0}")]
    SmoothingTau(f64),
    /// The gravity handed over from the INS configuration is not usable.
    #[error("ins.ins.gravity_mps2 must be finite and in [9, 10.6] m/s^2, got {0}")]
    Gravity(f64),
}

impl TightConfig {
    /// Checks every value, naming the first offending key.
    ///
    /// # Errors
    /// [`TightConfigError`] naming the key and its value.
    pub fn validate(&self) -> Result<(), TightConfigError> {
        for (index, &value) in self.lever_arm_m.iter().enumerate() {
            if !(value.is_finite() && value.abs() <= 10.0) {
                return Err(TightConfigError::LeverArm { index, value });
            }
        }
        let tau = self.specific_force_tau_s;
        if !(tau.is_finite() && (0.0..=10.0).contains(&tau)) {
            return Err(TightConfigError::SmoothingTau(tau));
        }
        Ok(())
    }
}

/// Why a [`TightEstimator`] could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TightBuildError {
    /// The tight-coupling settings were refused.
    #[error(transparent)]
    Tight(#[from] TightConfigError),
    /// The ESKF settings were refused.
    #[error(transparent)]
    Eskf(#[from] EskfConfigError),
}

/// The tightly coupled ESKF as an [`Estimator`] ([`FilterKind::IakfTdoa`]).
///
/// Prediction runs on every INS interval with the interval's attitude and
/// specific force (`accel_nav + [0, 0, g]`, optionally low-passed); intervals
/// longer than the ESKF's `max_dt_s` are split into equal sub-steps.
/// Each TDOA difference is one robust scalar update; [`Estimator::update_fix`]
/// returns `None` (fixes serve the engine's initialisation and resets only).
#[derive(Debug, Clone)]
pub struct TightEstimator {
    eskf: Eskf,
    cfg: TightConfig,
    gravity_mps2: f64,
    /// Low-passed specific force (ENU, m/s^2); `None` before the first interval.
    f_smooth: Option<[f64; 3]>,
    predict_errors: u64,
    update_errors: u64,
}

impl TightEstimator {
    /// A filter with the ESKF settings `eskf`, the coupling settings `cfg` and
    /// the INS's gravity magnitude (m/s^2, `ins.ins.gravity_mps2`: the INS
    /// removes it from the specific force, the filter adds it back).
    ///
    /// # Errors
    /// [`TightBuildError`] naming the first invalid key.
    pub fn new(
        eskf: EskfConfig,
        cfg: TightConfig,
        gravity_mps2: f64,
    ) -> Result<Self, TightBuildError> {
        cfg.validate()?;
        if !(gravity_mps2.is_finite() && (9.0..=10.6).contains(&gravity_mps2)) {
            return Err(TightConfigError::Gravity(gravity_mps2).into());
        }
        Ok(Self {
            eskf: Eskf::new(eskf)?,
            cfg,
            gravity_mps2,
            f_smooth: None,
            predict_errors: 0,
            update_errors: 0,
        })
    }

    /// The wrapped ESKF (statistics, covariance, monitors).
    #[must_use]
    pub fn eskf(&self) -> &Eskf {
        &self.eskf
    }

    /// The coupling settings.
    #[must_use]
    pub fn config(&self) -> &TightConfig {
        &self.cfg
    }

    /// INS intervals the ESKF refused (non-finite input, or longer than
    /// `MAX_PREDICT_SPLIT` times `max_dt_s`).
    #[must_use]
    pub fn predict_errors(&self) -> u64 {
        self.predict_errors
    }

    /// TDOA measurements the ESKF refused (non-finite input, antenna on an anchor).
    #[must_use]
    pub fn update_errors(&self) -> u64 {
        self.update_errors
    }

    /// The specific force for the interval ending at `nav`, low-passed when configured.
    fn specific_force(&mut self, dt_s: f64, nav: &NavState) -> [f64; 3] {
        let a = nav.accel_nav_mps2;
        let f = [a[0], a[1], a[2] + self.gravity_mps2];
        let tau = self.cfg.specific_force_tau_s;
        if tau <= 0.0 {
            return f;
        }
        let s = match self.f_smooth {
            None => f,
            Some(prev) => {
                let w = dt_s / (tau + dt_s);
                [
                    prev[0] + w * (f[0] - prev[0]),
                    prev[1] + w * (f[1] - prev[1]),
                    prev[2] + w * (f[2] - prev[2]),
                ]
            }
        };
        self.f_smooth = Some(s);
        s
    }
}

/// The engine's record of one scalar TDOA update.
fn report_to_info(r: &TdoaUpdateReport) -> UpdateInfo {
    let mut info = UpdateInfo {
        dim: 1,
        nis: r.nis,
        fading: 1.0,
        divergence: r.needs_reset,
        ..UpdateInfo::default()
    };
    info.innovation[0] = r.innovation_m;
    info.innovation_var[0] = r.innovation_var_m2;
    info.lambda[0] = r.lambda;
    info.r_diag[0] = r.r_gain_m2;
    match r.outcome {
        TdoaOutcome::Accepted => {}
        TdoaOutcome::Downweighted => info.outlier = true,
        TdoaOutcome::Rejected => {
            info.outlier = true;
            info.rejected = true;
        }
        // Skipped by the per-pair decimation: not a measurement of this epoch.
        TdoaOutcome::Decimated => info.dim = 0,
    }
    info
}

impl Estimator for TightEstimator {
    fn kind(&self) -> FilterKind {
        FilterKind::IakfTdoa
    }

    fn predict(&mut self, dt_s: f64, nav: &NavState) {
        if !(dt_s > 0.0 && dt_s.is_finite()) {
            return;
        }
        let f = self.specific_force(dt_s, nav);
        let max_dt = self.eskf.config().max_dt_s;
        // Split a long interval (an IMU gap) into equal steps the ESKF accepts.
        let n = (dt_s / max_dt).ceil().max(1.0);
        if n > f64::from(MAX_PREDICT_SPLIT) {
            self.predict_errors += 1;
            return;
        }
        let step = dt_s / n;
        // n is an integer in [1, MAX_PREDICT_SPLIT].
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        for _ in 0..(n as u32) {
            if self.eskf.predict(step, nav.quat, f).is_err() {
                self.predict_errors += 1;
                return;
            }
        }
    }

    fn update_fix(&mut self, _ins: &InsAt, _fix: &UwbFix) -> Option<UpdateInfo> {
        None
    }

    fn update_tdoa(&mut self, ins: &InsAt, m: &UwbTdoa) -> Option<UpdateInfo> {
        let res = self.eskf.update_tdoa(
            ins.pos_m,
            ins.quat,
            self.cfg.lever_arm_m,
            m.anchor_a_pos_m,
            m.anchor_b_pos_m,
            m.diff_m,
        );
        Some(match res {
            Ok(r) => report_to_info(&r),
            Err(_) => {
                self.update_errors += 1;
                UpdateInfo {
                    rejected: true,
                    divergence: self.eskf.needs_reset(),
                    ..UpdateInfo::default()
                }
            }
        })
    }

    fn take_correction(&mut self) -> Delta {
        let c = self.eskf.take_correction();
        Delta {
            d_pos_m: c.d_pos_m,
            d_vel_mps: c.d_vel_mps,
            d_att_rad: c.d_att_rad,
            d_accel_bias_mps2: c.d_accel_bias_mps2,
            d_gyro_bias_rps: c.d_gyro_bias_rps,
        }
    }

    fn pos_vel_cov(&self) -> [[f64; 6]; 6] {
        self.eskf.position_velocity_cov()
    }

    fn needs_reset(&self) -> bool {
        self.eskf.needs_reset()
    }

    fn reset(&mut self) {
        self.eskf.reset();
    }

    fn is_tight(&self) -> bool {
        true
    }
}
