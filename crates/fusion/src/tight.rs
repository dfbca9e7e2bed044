//! The tightly coupled estimator: the 15-state error-state filter of
//! `insuwb-eskf` behind the engine's [`Estimator`] interface.
//!
//! [`TightEstimator`] propagates the ESKF covariance on every INS interval
//! (3D attitude, specific force from the INS's kinematic acceleration plus
//! gravity), fuses each TDOA difference at the antenna (lever arm from
//! [`TightConfig`]), and hands the full correction (position, velocity,
//! attitude, both biases) back to the engine, which feeds it to the INS at the
//! end of each TDOA epoch. UWB fixes are not fused: the engine uses them only
//! to initialise the INS and to re-initialise it after a divergence, which
//! the engine's monitor finds from each update's NIS as for every filter
//! (and [`Estimator::needs_reset`] when the covariance stops being finite).

use std::collections::BTreeMap;

use crate::aiding::{scale_corrected, AidingConfig, HeightConfig, VelocityScales};
use crate::vehicle::{DragMeasurement, DragMeter, GroundConfig, VehicleSettings};
use crate::vibration::{VibrationConfig, VibrationMeter};
use insuwb_eskf::{
    Covariance, Eskf, EskfConfig, EskfConfigError, MultirotorDynamics, StateVector, TdoaOutcome,
    TdoaUpdateReport, IDX_ATT, IDX_POS, IDX_VEL, N_STATES,
};
use insuwb_msg::{BodyVelocity, FilterKind, Height, NavState, UwbFix, UwbRange, UwbTdoa};
use insuwb_nav::vehicle::{model_accel_nav, Mechanisation};
use insuwb_uwb::calibration::SiteCalibration;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::estimator::{gap_velocity_noise, split_interval, Delta, Estimator, InsAt, UpdateInfo};

/// How long an applied velocity measurement counts as aiding the filter, s
/// (the flow deck reads at 100 Hz, odometry at 10-50 Hz).
const AIDED_HOLD_S: f64 = 1.0;

/// Settings of the tight coupling that are not the ESKF's own.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TightConfig {
    /// Position of the UWB antenna in the body frame (FLU), m. Default
    /// `[0, 0, 0]` (antenna at the IMU); the UTIL Crazyflie's is
    /// `[-0.01245, 0.00127, 0.0908]` (dataset README).
    pub lever_arm_m: [f64; 3],
    /// Time constant of the low-pass on the specific force the ESKF's `F`
    /// is built from, s; 0 (default) passes each INS interval's own. `F`
    /// couples the attitude error to the velocity through the horizontal
    /// specific force, so motor vibration (0.4-3 m/s^2 RMS on UTIL's
    /// quadrotors) passed through unfiltered reads as manoeuvres and lends
    /// the yaw a spurious observability; the nominal INS integrates the raw
    /// samples either way.
    pub specific_force_tau_s: f64,
    /// Interval of the covariance propagation, s: INS intervals are
    /// accumulated (the mean specific force, the newest attitude and
    /// velocity) until this much time has passed, and always before an
    /// update; 0 (default) propagates on every INS interval. A 1 kHz IMU
    /// need not propagate a 15-state covariance 1000 times a second.
    pub predict_period_s: f64,
    /// With a site calibration (`[uwb] calibration`, `--calibration`):
    /// weight each anchor pair by the noise the calibration measured on it
    /// after its bias, its TDOA sigma scaled by its noise over the median
    /// pair's (bounded to [0.7, 1.5]), so that a pair the site's multipath
    /// makes noisy counts less. Default true; without a calibration every
    /// pair has the configured sigma.
    pub calibrated_noise: bool,
    /// Add the velocity noise of the vibration the IMU measures
    /// (`[fusion.vibration]`) to this filter's, as every loose filter does.
    /// Default true. Off, the tight filter's velocity noise is its model's
    /// alone (the multirotor's `model_noise_mps2_per_rthz`).
    pub vibration_noise: bool,
}

impl Default for TightConfig {
    fn default() -> Self {
        Self {
            lever_arm_m: [0.0; 3],
            specific_force_tau_s: 0.0,
            predict_period_s: 0.0,
            calibrated_noise: true,
            vibration_noise: true,
        }
    }
}

/// A multirotor's velocity damping in the tight filter's model
/// ([`crate::vehicle::MultirotorConfig::damping_per_s`]).
#[derive(Debug, Clone, Copy)]
struct Damping {
    /// The drag the INS integrates, 1/s.
    drag_per_s: f64,
    /// The model's damping while no velocity measurement aids, 1/s.
    damping_per_s: f64,
    /// The unmodelled body x/y force, m/s^2/sqrt(Hz).
    model_noise_mps2_per_rthz: f64,
}

/// Bounds of a pair's TDOA sigma scale from a calibration's noise
/// ([`TightConfig::calibrated_noise`]).
const PAIR_SCALE_BOUNDS: (f64, f64) = (0.7, 1.5);

/// Each calibrated pair's sigma scale (its noise over the median pair's,
/// bounded), keyed by its anchor ids in increasing order; empty when the
/// calibration measured no noise.
fn pair_scales(cal: &SiteCalibration) -> BTreeMap<(u32, u32), f64> {
    let mut noise: Vec<f64> = cal
        .pairs()
        .values()
        .map(|m| m.noise_m)
        .filter(|n| n.is_finite() && *n > 0.0)
        .collect();
    if noise.is_empty() {
        return BTreeMap::new();
    }
    noise.sort_by(f64::total_cmp);
    let mid = noise.len() / 2;
    let median = if noise.len().is_multiple_of(2) {
        0.5 * (noise[mid - 1] + noise[mid])
    } else {
        noise[mid]
    };
    cal.pairs()
        .iter()
        .filter(|(_, m)| m.noise_m.is_finite() && m.noise_m > 0.0)
        .map(|(&key, m)| {
            let (lo, hi) = PAIR_SCALE_BOUNDS;
            (key, (m.noise_m / median).clamp(lo, hi))
        })
        .collect()
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
    /// The specific-force time constant is negative, not finite or above 10 s.
    #[error("tight.specific_force_tau_s must be finite and within [0, 10] s, got {0}")]
    SpecificForceTau(f64),
    /// The propagation interval is negative, not finite or above 0.1 s.
    #[error("tight.predict_period_s must be finite and within [0, 0.1] s, got {0}")]
    PredictPeriod(f64),
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
            return Err(TightConfigError::SpecificForceTau(tau));
        }
        let pp = self.predict_period_s;
        if !(pp.is_finite() && (0.0..=0.1).contains(&pp)) {
            return Err(TightConfigError::PredictPeriod(pp));
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
/// Prediction runs on every INS interval with the attitude and specific
/// force (`accel_nav + [0, 0, g]`) of the INS state ending it; intervals
/// longer than the ESKF's `max_dt_s` are split into equal sub-steps.
/// Each TDOA difference is one robust scalar update; [`Estimator::update_fix`]
/// returns `None` (fixes serve the engine's initialisation and resets only).
#[derive(Debug, Clone)]
pub struct TightEstimator {
    eskf: Eskf,
    cfg: TightConfig,
    gravity_mps2: f64,
    /// Low-passed specific force (ENU, m/s^2), `None` before the first interval.
    f_smooth: Option<[f64; 3]>,
    vib_cfg: VibrationConfig,
    vib: VibrationMeter,
    /// What the INS integrates ([`TightEstimator::with_vehicle`]).
    mech: Mechanisation,
    /// The multirotor's drag measurements.
    drag: Option<DragMeter>,
    /// The ground robot's constraint and the time since its last update, s.
    ground: Option<(GroundConfig, f64)>,
    /// INS intervals not yet propagated ([`TightConfig::predict_period_s`]):
    /// their total length (s), the specific force integrated over them
    /// (m/s), and the newest attitude and velocity.
    acc_dt_s: f64,
    acc_f: [f64; 3],
    /// How many intervals are accumulated, and the last one's specific
    /// force (used as it is when it is the only one).
    acc_n: u32,
    acc_last_f: [f64; 3],
    acc_quat: [f64; 4],
    acc_vel: [f64; 3],
    /// Pseudo-measurements (drag, velocity constraints) applied and gated out.
    pseudo_applied: u64,
    pseudo_rejected: u64,
    /// The scale factors of flow and odometry, the baselines they are
    /// observed on and the length a baseline needs, m.
    scales: VelocityScales,
    scale_baseline_m: f64,
    /// Velocity components (odometry, flow) applied and gated out.
    velocity_applied: u64,
    velocity_rejected: u64,
    /// The range finder's height ([`HeightConfig`]) and its updates
    /// applied and gated out.
    height: HeightConfig,
    height_applied: u64,
    height_rejected: u64,
    predict_errors: u64,
    update_errors: u64,
    /// The multirotor's velocity damping (`None`: a free vehicle).
    damping: Option<Damping>,
    /// Filter time until which a velocity measurement aids the filter, s:
    /// until then the model's damping is the drag alone.
    aided_until_s: f64,
    /// Each calibrated pair's TDOA sigma scale ([`TightConfig::calibrated_noise`]).
    pair_scale: BTreeMap<(u32, u32), f64>,
    /// The multirotor's model while the INS has handed over to the free
    /// one ([`NavState::FLAG_FREE`]), to return to if a restarted INS
    /// integrates the multirotor's again.
    handed_over: Option<(Mechanisation, Option<Damping>, Option<DragMeter>)>,
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
            vib_cfg: VibrationConfig::default(),
            vib: VibrationMeter::default(),
            mech: Mechanisation::Free,
            drag: None,
            ground: None,
            damping: None,
            aided_until_s: f64::NEG_INFINITY,
            pair_scale: BTreeMap::new(),
            handed_over: None,
            acc_dt_s: 0.0,
            acc_f: [0.0; 3],
            acc_n: 0,
            acc_last_f: [0.0; 3],
            acc_quat: [1.0, 0.0, 0.0, 0.0],
            acc_vel: [0.0; 3],
            pseudo_applied: 0,
            pseudo_rejected: 0,
            scales: VelocityScales::default(),
            scale_baseline_m: 2.0,
            velocity_applied: 0,
            velocity_rejected: 0,
            height: HeightConfig::default(),
            height_applied: 0,
            height_rejected: 0,
            predict_errors: 0,
            update_errors: 0,
        })
    }

    /// Uses the vehicle model of `vehicle` ([`crate::vehicle`]): the error
    /// dynamics of the mechanisation the INS integrates, and the
    /// multirotor's drag measurements or the ground robot's velocity
    /// constraints (zero lateral and vertical body velocity) as
    /// pseudo-measurements.
    #[must_use]
    pub fn with_vehicle(mut self, vehicle: &VehicleSettings<'_>) -> Self {
        self.mech = vehicle.mechanisation();
        self.drag = None;
        self.ground = None;
        if vehicle.kind == insuwb_nav::vehicle::VehicleKind::Ground {
            self.ground = Some((vehicle.ground.clone(), 0.0));
        }
        match self.mech {
            Mechanisation::Free => {
                let _ = self.eskf.set_multirotor(None);
                self.damping = None;
            }
            Mechanisation::ThrustDrag { drag_per_s } => {
                let m = vehicle.multirotor;
                let damping = m.damping_per_s.max(drag_per_s);
                self.damping = Some(Damping {
                    drag_per_s,
                    damping_per_s: damping,
                    model_noise_mps2_per_rthz: m.model_noise_mps2_per_rthz,
                });
                self.set_damping(damping);
                self.drag = Some(DragMeter::new(m));
            }
        }
        self
    }

    /// Follows the INS's hand-over ([`NavState::FLAG_FREE`]): what is
    /// accumulated is propagated with the model it was accumulated under;
    /// handed over, the error dynamics are the free vehicle's and the drag
    /// measurements stop; back (a restarted INS integrating the
    /// multirotor's model again), the multirotor's return.
    fn follow_handover(&mut self, free: bool) {
        self.propagate();
        if free {
            self.handed_over = Some((self.mech, self.damping.take(), self.drag.take()));
            self.mech = Mechanisation::Free;
            let _ = self.eskf.set_multirotor(None);
        } else if let Some((mech, damping, drag)) = self.handed_over.take() {
            self.mech = mech;
            self.damping = damping;
            self.drag = drag;
            self.update_damping();
        }
    }

    /// Sets the multirotor error dynamics with velocity damping `k` (1/s)
    /// over the INS's drag.
    fn set_damping(&mut self, k: f64) {
        if let Some(d) = self.damping {
            let _ = self.eskf.set_multirotor(Some(MultirotorDynamics {
                drag_per_s: k,
                ins_drag_per_s: d.drag_per_s,
                model_noise_mps2_per_rthz: d.model_noise_mps2_per_rthz,
            }));
        }
    }

    /// The model's damping as it should be now: the drag while a velocity
    /// measurement aids the filter (the damping stands for the velocity
    /// information the IMU lacks, which the measurement supplies), the
    /// configured damping otherwise.
    fn update_damping(&mut self) {
        if let Some(d) = self.damping {
            let k = if self.eskf.time_s() < self.aided_until_s {
                d.drag_per_s
            } else {
                d.damping_per_s
            };
            if self.eskf.multirotor().map(|m| m.drag_per_s) != Some(k) {
                self.set_damping(k);
            }
        }
    }

    /// Weights each anchor pair by the noise `calibration` measured on it
    /// ([`TightConfig::calibrated_noise`]); `None`, or the setting off,
    /// treats every pair alike.
    #[must_use]
    pub fn with_calibration(mut self, calibration: Option<&SiteCalibration>) -> Self {
        self.pair_scale = match calibration {
            Some(c) if self.cfg.calibrated_noise => pair_scales(c),
            _ => BTreeMap::new(),
        };
        self
    }

    /// Pseudo-measurements (drag, velocity constraints) applied and
    /// gated out.
    #[must_use]
    pub fn pseudo_counts(&self) -> (u64, u64) {
        (self.pseudo_applied, self.pseudo_rejected)
    }

    /// Uses the velocity aiding's settings `aiding`: each source's scale
    /// factor starts at its prior, and is observed on baselines at least
    /// `scale_baseline_m` long between UWB fixes (`loose.scale_baseline_m`,
    /// as the loose filters do: [`crate::aiding`]).
    #[must_use]
    pub fn with_aiding(mut self, aiding: &AidingConfig, scale_baseline_m: f64) -> Self {
        self.scales = VelocityScales::new(aiding);
        self.scale_baseline_m = scale_baseline_m;
        self.height = aiding.height;
        self
    }

    /// The range finder's heights applied and gated out.
    #[must_use]
    pub fn height_counts(&self) -> (u64, u64) {
        (self.height_applied, self.height_rejected)
    }

    /// The radio's height error and its sigma, m, once a range finder's
    /// height has turned that state on ([`HeightConfig`]).
    #[must_use]
    pub fn radio_height_error(&self) -> Option<(f64, f64)> {
        self.eskf.radio_height_error()
    }

    /// Body-velocity components (odometry, flow) applied and gated out.
    #[must_use]
    pub fn velocity_counts(&self) -> (u64, u64) {
        (self.velocity_applied, self.velocity_rejected)
    }

    /// The online drag coefficient estimate, 1/s (multirotor only).
    #[must_use]
    pub fn drag_per_s(&self) -> Option<f64> {
        self.drag.as_ref().map(DragMeter::drag_per_s)
    }

    /// Propagates the covariance over the accumulated INS intervals.
    fn propagate(&mut self) {
        let dt_s = self.acc_dt_s;
        if dt_s <= 0.0 {
            return;
        }
        let f = if self.acc_n == 1 {
            self.acc_last_f
        } else {
            self.acc_f.map(|v| v / dt_s)
        };
        let (quat, vel) = (self.acc_quat, self.acc_vel);
        self.acc_dt_s = 0.0;
        self.acc_f = [0.0; 3];
        self.acc_n = 0;
        let max_dt = self.eskf.config().max_dt_s;
        // Split a long interval (an IMU gap) into equal steps the ESKF accepts.
        let Some((n, step)) = split_interval(dt_s, max_dt) else {
            self.predict_errors += 1;
            return;
        };
        self.update_damping();
        for _ in 0..n {
            if self.eskf.predict_moving(step, quat, f, vel).is_err() {
                self.predict_errors += 1;
                return;
            }
        }
    }

    fn pseudo(&mut self, h: &StateVector, innovation: f64, r: f64) {
        self.propagate();
        match self.eskf.update_pseudo(h, innovation, r) {
            Ok(rep) if rep.applied => self.pseudo_applied += 1,
            Ok(_) => self.pseudo_rejected += 1,
            Err(_) => self.update_errors += 1,
        }
    }

    /// The drag measurement of body axis `i` (x, y): `f_i - c_i = -k v_b,i`,
    /// with `v_b = C^T v` and, to first order, `v_b,true = v_b,ins -
    /// C^T δv - C^T [v x] δθ`: `H = k [(C e_i)^T on δv, ((C e_i) x v)^T on δθ]`.
    fn drag_update(&mut self, nav: &NavState, d: &DragMeasurement) {
        let Some((att, vel)) = att_vel(nav) else {
            return;
        };
        for i in 0..2 {
            let axis = att * Vector3::ith(i, 1.0);
            let mut h = StateVector::zeros();
            h.fixed_rows_mut::<3>(IDX_VEL)
                .copy_from(&(axis * d.drag_per_s));
            h.fixed_rows_mut::<3>(IDX_ATT)
                .copy_from(&(axis.cross(&vel) * d.drag_per_s));
            let predicted = -d.drag_per_s * d.body_vel_lp_mps[i];
            self.pseudo(
                &h,
                d.force_mps2[i] - predicted,
                d.sigma_mps2[i] * d.sigma_mps2[i],
            );
        }
    }

    /// The ground robot's zero lateral (body y) and vertical (body z, when
    /// configured) velocity: `H = -[(C e_i)^T on δv, ((C e_i) x v)^T on δθ]`.
    fn ground_update(&mut self, nav: &NavState, g: &GroundConfig) {
        let Some((att, vel)) = att_vel(nav) else {
            return;
        };
        for (i, sigma) in [(1, g.lateral_sigma_mps), (2, g.vertical_sigma_mps)] {
            if sigma <= 0.0 {
                continue;
            }
            let axis = att * Vector3::ith(i, 1.0);
            let mut h = StateVector::zeros();
            h.fixed_rows_mut::<3>(IDX_VEL).copy_from(&(-axis));
            h.fixed_rows_mut::<3>(IDX_ATT)
                .copy_from(&(-axis.cross(&vel)));
            self.pseudo(&h, -axis.dot(&vel), sigma * sigma);
        }
    }

    /// Adds the velocity noise of the vibration the IMU measures to the
    /// accelerometer's ([`crate::vibration`]; off with the default settings).
    #[must_use]
    pub fn with_vibration(mut self, cfg: VibrationConfig) -> Self {
        self.vib_cfg = cfg;
        self
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
    /// `crate::estimator::MAX_PREDICT_SPLIT` times `max_dt_s`).
    #[must_use]
    pub fn predict_errors(&self) -> u64 {
        self.predict_errors
    }

    /// TDOA measurements the ESKF refused (non-finite input, antenna on an anchor).
    #[must_use]
    pub fn update_errors(&self) -> u64 {
        self.update_errors
    }

    /// What a TDOA or range update did, for the engine; a refused one
    /// (a non-finite input, an antenna on an anchor) is counted.
    fn uwb_info(
        &mut self,
        res: Result<insuwb_eskf::TdoaUpdateReport, insuwb_eskf::TdoaUpdateError>,
    ) -> UpdateInfo {
        match res {
            Ok(r) => report_to_info(&r),
            Err(_) => {
                self.update_errors += 1;
                UpdateInfo {
                    rejected: true,
                    divergence: self.eskf.needs_reset(),
                    ..UpdateInfo::default()
                }
            }
        }
    }
}

/// The attitude and velocity of an INS state, if finite.
fn att_vel(nav: &NavState) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    let q = nav.quat;
    if !q.iter().chain(&nav.vel_mps).all(|v| v.is_finite()) {
        return None;
    }
    let att = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
    Some((att, Vector3::from(nav.vel_mps)))
}

/// The engine's record of one scalar TDOA update.
fn report_to_info(r: &TdoaUpdateReport) -> UpdateInfo {
    let mut info = UpdateInfo {
        dim: 1,
        nis: r.nis,
        // The tight filter's adaptive factor is its process-noise scale.
        fading: r.q_scale,
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
        let free = nav.header.flags & NavState::FLAG_FREE != 0;
        if free != self.handed_over.is_some() {
            self.follow_handover(free);
        }
        let a = model_accel_nav(
            self.mech,
            nav.quat,
            nav.vel_mps,
            nav.accel_nav_mps2,
            self.gravity_mps2,
        );
        // The meter's state serves only this noise: off, it is not run.
        let vib = if self.cfg.vibration_noise {
            self.vib.push(&self.vib_cfg, dt_s, nav)
        } else {
            0.0
        };
        let q = vib + gap_velocity_noise(dt_s, nav);
        self.eskf.set_extra_velocity_noise(q);
        let raw = [a[0], a[1], a[2] + self.gravity_mps2];
        let tau = self.cfg.specific_force_tau_s;
        let f = match self.f_smooth {
            Some(prev) if tau > 0.0 && raw.iter().all(|v| v.is_finite()) => {
                let w = 1.0 - (-dt_s / tau).exp();
                let next = [0, 1, 2].map(|i| prev[i] + w * (raw[i] - prev[i]));
                self.f_smooth = Some(next);
                next
            }
            _ => {
                self.f_smooth = Some(raw);
                raw
            }
        };
        if !f.iter().all(|v| v.is_finite()) {
            self.predict_errors += 1;
            return;
        }
        self.acc_dt_s += dt_s;
        for (acc, fi) in self.acc_f.iter_mut().zip(f) {
            *acc += fi * dt_s;
        }
        self.acc_n = self.acc_n.saturating_add(1);
        self.acc_last_f = f;
        self.acc_quat = nav.quat;
        self.acc_vel = nav.vel_mps;
        if self.acc_dt_s >= self.cfg.predict_period_s {
            self.propagate();
        }
        if let Some(meter) = self.drag.as_mut() {
            let m = meter.push(
                dt_s,
                nav.quat,
                nav.vel_mps,
                nav.accel_nav_mps2,
                self.gravity_mps2,
            );
            if let Some(m) = m {
                self.drag_update(nav, &m);
            }
        }
        if let Some((g, since)) = self.ground.as_mut() {
            *since += dt_s;
            if *since >= g.period_s {
                *since = 0.0;
                let g = g.clone();
                self.ground_update(nav, &g);
            }
        }
    }

    fn flush_predict(&mut self) {
        self.propagate();
    }

    /// No update (the filter takes the TDOA differences the fix was
    /// built from); a velocity source's baseline that is long enough is an
    /// observation of its scale factor: the fixes are the UWB alone, which
    /// the source does not drive ([`crate::aiding`]).
    fn update_fix(&mut self, ins: &InsAt, fix: &UwbFix) -> Option<UpdateInfo> {
        let c = fix.pos_cov_m2;
        let usable = [c[0][0], c[1][1]].iter().all(|v| v.is_finite() && *v > 0.0)
            && c[0][1].is_finite()
            && c[1][0].is_finite()
            && fix.pos_m.iter().all(|v| v.is_finite());
        if !usable {
            return None;
        }
        let q = ins.quat;
        let att =
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
        // The body's position: the fix less the lever arm (rotated).
        let arm = att * Vector3::from(self.cfg.lever_arm_m);
        let body = [fix.pos_m[0] - arm.x, fix.pos_m[1] - arm.y];
        let cov = [[c[0][0], c[0][1]], [c[1][0], c[1][1]]];
        self.scales
            .on_fix(fix.header.meas_time_ns, body, cov, self.scale_baseline_m);
        None
    }

    fn update_tdoa(&mut self, ins: &InsAt, m: &UwbTdoa) -> Option<UpdateInfo> {
        self.propagate();
        if !self.pair_scale.is_empty() {
            let key = (m.anchor_a.min(m.anchor_b), m.anchor_a.max(m.anchor_b));
            let scale = self.pair_scale.get(&key).copied().unwrap_or(1.0);
            self.eskf.set_tdoa_sigma_scale(scale);
        }
        let res = self.eskf.update_tdoa(
            ins.pos_m,
            ins.quat,
            self.cfg.lever_arm_m,
            m.anchor_a_pos_m,
            m.anchor_b_pos_m,
            m.diff_m,
        );
        Some(self.uwb_info(res))
    }

    fn update_range(&mut self, ins: &InsAt, m: &UwbRange) -> Option<UpdateInfo> {
        self.propagate();
        let res = self.eskf.update_range(
            ins.pos_m,
            ins.quat,
            self.cfg.lever_arm_m,
            m.anchor_pos_m,
            m.range_m,
        );
        Some(self.uwb_info(res))
    }

    /// Each measured axis `i` of the body velocity: `z_i = (C e_i) . v`,
    /// `H = -[(C e_i)^T on δv, ((C e_i) x v)^T on δθ]` (as the ground
    /// constraint's), weighted and gated as every pseudo-measurement.
    fn update_velocity(&mut self, ins: &InsAt, m: &BodyVelocity) -> Option<UpdateInfo> {
        self.propagate();
        let q = ins.quat;
        let att =
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
        let vel = Vector3::from(ins.vel_mps);
        let mut info = UpdateInfo {
            fading: 1.0,
            ..UpdateInfo::default()
        };
        let scale = self.scales.on_sample(m, &att)?;
        let mut measured = 0;
        for i in 0..3 {
            if m.sigma_mps[i] <= 0.0 {
                continue;
            }
            measured += 1;
            let axis = att * Vector3::ith(i, 1.0);
            // The filter's body velocity on this axis.
            let predicted = axis.dot(&vel);
            let (z, sigma) = scale_corrected(scale, m.vel_mps[i], m.sigma_mps[i], predicted);
            let mut h = StateVector::zeros();
            h.fixed_rows_mut::<3>(IDX_VEL).copy_from(&(-axis));
            h.fixed_rows_mut::<3>(IDX_ATT)
                .copy_from(&(-axis.cross(&vel)));
            let innovation = z - predicted;
            let r = sigma * sigma;
            let k = info.dim as usize;
            match self.eskf.update_body_velocity(&h, innovation, r) {
                Ok(rep) => {
                    if let (Some(inn), Some(rd)) =
                        (info.innovation.get_mut(k), info.r_diag.get_mut(k))
                    {
                        *inn = innovation;
                        *rd = r;
                    }
                    if rep.applied {
                        self.velocity_applied += 1;
                        self.aided_until_s = self.eskf.time_s() + AIDED_HOLD_S;
                        info.nis += rep.nis;
                        info.dim += 1;
                    } else {
                        self.velocity_rejected += 1;
                        info.outlier = true;
                    }
                }
                Err(_) => self.update_errors += 1,
            }
        }
        if measured == 0 {
            return None;
        }
        info.rejected = info.dim == 0;
        info.divergence = self.eskf.needs_reset();
        Some(info)
    }

    /// The range finder's height as one update: `z = (range +
    /// range_offset_m) R33` against the INS height, `H = -1` on the
    /// position's z (the tilt's part of `R33` is second order at level
    /// flight and left out), weighted and gated as every
    /// pseudo-measurement; the first one turns the radio's height state on.
    /// `None` while height updates are off.
    fn update_height(&mut self, ins: &InsAt, m: &Height) -> Option<UpdateInfo> {
        let q = ins.quat;
        let att =
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
        let c = self.height;
        let z = c.height_m(m, &att)?;
        self.propagate();
        let mut info = UpdateInfo {
            fading: 1.0,
            ..UpdateInfo::default()
        };
        if !self
            .eskf
            .enable_radio_height(c.radio_sigma_m, c.radio_corr_time_s)
        {
            self.update_errors += 1;
            return None;
        }
        let mut h = StateVector::zeros();
        h[IDX_POS + 2] = -1.0;
        let innovation = z - ins.pos_m[2];
        let r = c.sigma_m * c.sigma_m;
        info.innovation[0] = innovation;
        info.r_diag[0] = r;
        match self.eskf.update_pseudo(&h, innovation, r) {
            Ok(rep) if rep.applied => {
                self.height_applied += 1;
                info.nis = rep.nis;
                info.dim = 1;
            }
            Ok(_) => {
                self.height_rejected += 1;
                info.outlier = true;
                info.rejected = true;
            }
            Err(_) => {
                self.update_errors += 1;
                return None;
            }
        }
        info.divergence = self.eskf.needs_reset();
        Some(info)
    }

    fn aiding_scales(&self) -> Option<[(f64, f64); 2]> {
        Some(self.scales.scales())
    }

    fn take_correction(&mut self) -> Delta {
        self.propagate();
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
        self.acc_dt_s = 0.0;
        self.acc_f = [0.0; 3];
        self.acc_n = 0;
        self.scales.break_baselines();
        self.eskf.reset();
    }

    fn is_tight(&self) -> bool {
        true
    }

    fn covariance_snapshot(&self, out: &mut Vec<f64>) {
        let p = self.eskf.covariance();
        out.clear();
        out.extend((0..N_STATES).flat_map(|i| (0..N_STATES).map(move |j| p[(i, j)])));
    }

    /// The filter's learnt noise scales, then, while it is on, the
    /// radio's height state and its sigma (a memory of a minute and more,
    /// which a restarted stage should not learn again).
    fn adaptive_snapshot(&self, out: &mut Vec<f64>) {
        out.clear();
        out.extend_from_slice(&self.eskf.adaptive_state());
        if let Some((b, sigma)) = self.eskf.radio_height_error() {
            out.extend_from_slice(&[b, sigma]);
        }
    }

    /// Restores an [`Self::adaptive_snapshot`]: three values (the noise
    /// scales), or five (and the radio's height state, resumed where
    /// height updates are on; left at its start where they are off).
    fn restore_adaptive(&mut self, s: &[f64]) -> bool {
        let (learnt, radio) = match s {
            [a, b, c] => ([*a, *b, *c], None),
            [a, b, c, h, hs] => ([*a, *b, *c], Some((*h, *hs))),
            _ => return false,
        };
        let c = self.height;
        if let Some((h, hs)) = radio {
            if !(h.is_finite() && hs.is_finite() && hs > 0.0) {
                return false;
            }
            if !self.eskf.restore_adaptive_state(&learnt) {
                return false;
            }
            if c.sigma_m > 0.0 {
                return self
                    .eskf
                    .restore_radio_height(c.radio_sigma_m, c.radio_corr_time_s, h, hs);
            }
            return true;
        }
        self.eskf.restore_adaptive_state(&learnt)
    }

    fn restore_covariance(&mut self, p: &[f64]) -> bool {
        if p.len() != N_STATES * N_STATES {
            return false;
        }
        let m = Covariance::from_fn(|i, j| p.get(i * N_STATES + j).copied().unwrap_or(f64::NAN));
        let _ = self.eskf.take_correction();
        self.eskf.reset_with_covariance(&m).is_ok()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use insuwb_msg::{Header, ImuSample, LAYOUT_VERSION};

    use super::*;
    use crate::config::{build_estimator, FusionConfig};
    use crate::runner;

    const G: f64 = 9.80665;

    fn level_nav(t_ns: u64) -> NavState {
        NavState {
            header: Header::new(0, t_ns),
            quat: [1.0, 0.0, 0.0, 0.0],
            // At rest: kinematic acceleration zero (the INS removed gravity).
            accel_nav_mps2: [0.0; 3],
            ..NavState::default()
        }
    }

    /// A state flagged by an INS that handed over to the free model turns
    /// the multirotor's error dynamics off while the flag lasts.
    #[test]
    fn the_free_flag_of_the_ins_turns_the_multirotor_dynamics_off() {
        let mr = crate::vehicle::MultirotorConfig::default();
        let ground = GroundConfig::default();
        let mut e = estimator([0.0; 3]).with_vehicle(&VehicleSettings {
            kind: insuwb_nav::vehicle::VehicleKind::Multirotor,
            multirotor: &mr,
            ground: &ground,
        });
        e.predict(0.01, &level_nav(10_000_000));
        assert!(e.eskf().multirotor().is_some());
        let mut nav = level_nav(20_000_000);
        nav.header.flags |= NavState::FLAG_FREE;
        e.predict(0.01, &nav);
        e.flush_predict();
        assert!(e.eskf().multirotor().is_none());
        nav.header.seq = 3;
        nav.header.meas_time_ns = 30_000_000;
        e.predict(0.01, &nav);
        assert!(e.eskf().multirotor().is_none());
        // A restarted INS integrating the multirotor's model again.
        e.predict(0.01, &level_nav(40_000_000));
        e.flush_predict();
        assert!(e.eskf().multirotor().is_some());
    }

    /// A multirotor's model damps the velocity at `damping_per_s` over the
    /// INS's drag while no velocity measurement aids it, and at the drag
    /// alone for a second after each applied one.
    #[test]
    fn damping_is_the_drag_while_a_velocity_measurement_aids() {
        let mr = crate::vehicle::MultirotorConfig {
            drag_per_s: 0.5,
            damping_per_s: 1.5,
            ..crate::vehicle::MultirotorConfig::default()
        };
        let ground = GroundConfig::default();
        let mut e = estimator([0.0; 3]).with_vehicle(&VehicleSettings {
            kind: insuwb_nav::vehicle::VehicleKind::Multirotor,
            multirotor: &mr,
            ground: &ground,
        });
        let damping = |e: &TightEstimator| {
            e.eskf()
                .multirotor()
                .map(|m| (m.drag_per_s, m.ins_drag_per_s))
        };
        assert_eq!(damping(&e), Some((1.5, 0.5)));
        let mut t_ns = 0;
        let step = |e: &mut TightEstimator, t_ns: &mut u64| {
            *t_ns += 10_000_000;
            e.predict(0.01, &level_nav(*t_ns));
            e.flush_predict();
        };
        step(&mut e, &mut t_ns);
        let flow = BodyVelocity {
            header: Header::new(0, t_ns),
            vel_mps: [0.0; 3],
            sigma_mps: [0.3, 0.3, 0.0],
            source: BodyVelocity::SOURCE_FLOW,
            range_mm: 0,
        };
        assert!(e.update_velocity(&ins_at([0.0; 3]), &flow).is_some());
        step(&mut e, &mut t_ns);
        assert_eq!(damping(&e), Some((0.5, 0.5)), "aided: the drag");
        for _ in 0..110 {
            step(&mut e, &mut t_ns);
        }
        assert_eq!(damping(&e), Some((1.5, 0.5)), "a second later: the damping");
    }

    /// A checkpoint carries the radio's height state while it is on, and a
    /// restarted filter with height updates resumes it (one without them
    /// takes the noise scales only); a checkpoint of three values (the
    /// state off, or written before it was kept) still restores, and bad
    /// values are refused.
    #[test]
    fn the_radio_height_state_goes_through_the_checkpoint() {
        let aiding = crate::aiding::height_aiding();
        let mut e = estimator([0.0; 3]).with_aiding(&aiding, 2.0);
        let mut s = Vec::new();
        e.adaptive_snapshot(&mut s);
        assert_eq!(s.len(), 3, "off: the noise scales only");
        assert!(e.restore_adaptive(&s));
        assert!(e.radio_height_error().is_none());
        let resumed = [s[0], s[1], s[2], -0.4, 0.05];
        assert!(e.restore_adaptive(&resumed));
        let (b, sigma) = e.radio_height_error().unwrap();
        assert!((b + 0.4).abs() < 1e-15 && (sigma - 0.05).abs() < 1e-12);
        let mut back = Vec::new();
        e.adaptive_snapshot(&mut back);
        assert_eq!(back.len(), 5);
        let mut fresh = estimator([0.0; 3]).with_aiding(&aiding, 2.0);
        assert!(fresh.restore_adaptive(&back));
        assert_eq!(fresh.radio_height_error(), e.radio_height_error());
        let mut off = estimator([0.0; 3]).with_aiding(&AidingConfig::default(), 2.0);
        assert!(off.restore_adaptive(&back));
        assert!(off.radio_height_error().is_none());
        for bad in [
            &[s[0], s[1], s[2], f64::NAN, 0.05][..],
            &[s[0], s[1], s[2], 0.1, 0.0],
            &[s[0], s[1], s[2], 0.1],
        ] {
            let mut g = estimator([0.0; 3]).with_aiding(&aiding, 2.0);
            assert!(!g.restore_adaptive(bad), "{bad:?}");
            assert!(g.radio_height_error().is_none());
        }
    }

    /// A range finder's height is an update once height aiding is on:
    /// `(range + offset) R33` against the INS height, its innovation and
    /// variance as configured, and the first one turns the radio's height
    /// state on; with height aiding off it is no update and leaves the
    /// height alone; a flow velocity is never a height.
    #[test]
    fn a_range_finder_height_updates_the_height() {
        let aiding = crate::aiding::height_aiding();
        // Tilted 0.2 rad about body x: R33 = cos 0.2.
        let tilt = 0.2_f64;
        let quat = [(tilt / 2.0).cos(), (tilt / 2.0).sin(), 0.0, 0.0];
        let ins = InsAt {
            quat,
            ..ins_at([0.0, 0.0, 1.0])
        };
        let range = Height {
            header: Header::new(0, 0),
            range_m: 1.2,
            source: Height::SOURCE_RANGE_FINDER,
        };
        let flow = BodyVelocity {
            header: Header::new(0, 0),
            vel_mps: [0.0; 3],
            sigma_mps: [0.3, 0.3, 0.0],
            source: BodyVelocity::SOURCE_FLOW,
            range_mm: 1200,
        };
        let mut e = estimator([0.0; 3]).with_aiding(&aiding, 2.0);
        assert!(e.radio_height_error().is_none());
        assert_eq!(e.update_velocity(&ins, &flow).unwrap().dim, 2);
        assert!(
            e.radio_height_error().is_none(),
            "a flow velocity is no height"
        );
        let info = e.update_height(&ins, &range).unwrap();
        assert_eq!((info.dim, info.rejected), (1, false));
        let want = (1.2 + 0.05) * tilt.cos() - 1.0;
        assert!((info.innovation[0] - want).abs() < 1e-12, "{info:?}");
        assert!((info.r_diag[0] - 0.03 * 0.03).abs() < 1e-15);
        assert_eq!(e.height_counts(), (1, 0));
        let (b, sigma) = e.radio_height_error().unwrap();
        assert_eq!(b, 0.0);
        assert!(
            (sigma - aiding.height.radio_sigma_m).abs() < 1e-9,
            "{sigma}"
        );
        assert!(e.take_correction().d_pos_m[2] < 0.0, "the INS is moved up");
        let mut off = estimator([0.0; 3]).with_aiding(&AidingConfig::default(), 2.0);
        assert!(off.update_height(&ins, &range).is_none());
        assert_eq!(off.height_counts(), (0, 0));
        assert!(off.radio_height_error().is_none());
        assert_eq!(off.take_correction().d_pos_m[2], 0.0);
    }

    fn ins_at(pos_m: [f64; 3]) -> InsAt {
        InsAt {
            t_ns: 0,
            pos_m,
            vel_mps: [0.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
        }
    }

    /// A calibration's per-pair noise sets each pair's TDOA sigma relative
    /// to the median pair's, within the bounds: pair (0, 1) measured twice
    /// as noisy as the median is weighted with 1.5 times the sigma, its
    /// innovation variance is the known one; with the setting off, or no
    /// calibration, the configured sigma.
    #[test]
    fn a_calibrated_pair_noise_sets_its_sigma() {
        let text = "format_version = 1\n[site]\nfamily = \"pair_constant\"\n\
            anchors = [{ id = 0, pos_m = [-4, 0, 1.1] }, { id = 1, pos_m = [4, 0, 1.1] }, \
            { id = 2, pos_m = [0, 4, 1.1] }]\n\
            [[pairs]]\na = 0\nb = 1\nbias_m = 0\nnoise_m = 0.4\n\
            [[pairs]]\na = 0\nb = 2\nbias_m = 0\nnoise_m = 0.2\n\
            [[pairs]]\na = 1\nb = 2\nbias_m = 0\nnoise_m = 0.05\n";
        let cal = SiteCalibration::from_toml(text, "test").unwrap();
        let scales = pair_scales(&cal);
        assert_eq!(scales.get(&(0, 1)), Some(&1.5), "2x the median, bounded");
        assert_eq!(scales.get(&(0, 2)), Some(&1.0));
        assert_eq!(scales.get(&(1, 2)), Some(&0.7), "0.25x, bounded");
        let c = EskfConfig::default();
        let (a, b) = ([-4.0, 0.0, 1.1], [4.0, 0.0, 1.1]);
        let var = |cfg: TightConfig, cal: Option<&SiteCalibration>| {
            let mut e = TightEstimator::new(EskfConfig::default(), cfg, G)
                .unwrap()
                .with_calibration(cal);
            let info = e
                .update_tdoa(&ins_at([0.0, 0.0, 1.0]), &tdoa(0, a, b, 0.0))
                .unwrap();
            info.innovation_var[0]
        };
        let r = c.tdoa_sigma_m.powi(2);
        let off = TightConfig {
            calibrated_noise: false,
            ..TightConfig::default()
        };
        // H P H^T + sigma^2: the same H P H^T, the sigma 1.5 times.
        let plain = var(off, Some(&cal));
        let weighted = var(TightConfig::default(), Some(&cal));
        assert!(
            (weighted - plain - 1.25 * r).abs() < 1e-12,
            "{weighted} {plain}"
        );
        assert!((var(TightConfig::default(), None) - plain).abs() < 1e-15);
    }

    fn tdoa(t_ns: u64, a: [f64; 3], b: [f64; 3], diff_m: f64) -> UwbTdoa {
        UwbTdoa {
            header: Header::new(0, t_ns),
            anchor_a: 0,
            anchor_b: 1,
            diff_m,
            anchor_a_pos_m: a,
            anchor_b_pos_m: b,
        }
    }

    fn estimator(lever_arm_m: [f64; 3]) -> TightEstimator {
        TightEstimator::new(
            EskfConfig::default(),
            TightConfig {
                lever_arm_m,
                ..TightConfig::default()
            },
            G,
        )
        .unwrap()
    }

    /// One TDOA update, hand-computed: anchors on the east axis, the antenna
    /// 0.1 m above the IMU, the INS 0.1 m west of the truth.
    #[test]
    fn tdoa_update_known_answer() {
        let c = EskfConfig::default();
        let mut e = estimator([0.0, 0.0, 0.1]);
        let (a, b) = ([-4.0, 0.0, 1.1], [4.0, 0.0, 1.1]);
        // True antenna at (0.1, 0, 1.1): |p - b| - |p - a| = 3.9 - 4.1.
        let m = tdoa(0, a, b, 3.9 - 4.1);
        // The INS puts the IMU at (0, 0, 1), the antenna at (0, 0, 1.1):
        // predicted 0, innovation -0.2. u = (p-b)/|p-b| - (p-a)/|p-a| =
        // (-2, 0, 0); H = [-u, 0, u x (C l), 0, 0] = [2,0,0, 0,0,0, 0,0.2,0, ...].
        let info = e.update_tdoa(&ins_at([0.0, 0.0, 1.0]), &m).unwrap();
        let (sp2, sr2) = (
            c.init_pos_sigma_m.powi(2),
            c.init_roll_pitch_sigma_rad.powi(2),
        );
        let hph = 4.0 * sp2 + 0.04 * sr2;
        let r = c.tdoa_sigma_m.powi(2); // first measurement of the pair: no inflation
        assert_eq!(info.dim, 1);
        assert!((info.innovation[0] + 0.2).abs() < 1e-12, "{info:?}");
        assert!((info.innovation_var[0] - (hph + r)).abs() < 1e-12);
        assert!((info.lambda[0] - 1.0).abs() < 1e-12 && !info.outlier && !info.rejected);
        let d = e.take_correction();
        // K v: INS minus truth is -0.1 m east; one update of a P0 of 0.5 m gets most of it.
        let dx = 2.0 * sp2 / (hph + r) * -0.2;
        assert!((d.d_pos_m[0] - dx).abs() < 1e-12, "{d:?}");
        assert!((d.d_att_rad[1] - 0.2 * sr2 / (hph + r) * -0.2).abs() < 1e-12);
        for v in [d.d_pos_m[1], d.d_pos_m[2], d.d_att_rad[0], d.d_att_rad[2]] {
            assert!(v.abs() < 1e-15);
        }
        assert!(d
            .d_vel_mps
            .iter()
            .chain(&d.d_accel_bias_mps2)
            .all(|v| v.abs() < 1e-15));
        // Closed loop: the error state is zero again.
        assert!(e.take_correction().is_zero());
    }

    /// `P_pp = s_p^2 + dt^2 s_v^2`, `P_pv = dt s_v^2`,
    /// `P_vv,east = s_v^2 + dt^2 (g^2 s_rp^2 + s_ba^2) + s_a^2 dt`: the
    /// specific force holds gravity again (the tilt term), from the INS's gravity.
    #[test]
    fn predict_uses_gravity_and_attitude() {
        let c = EskfConfig::default();
        let mut e = estimator([0.0; 3]);
        let dt = 0.01;
        e.predict(dt, &level_nav(10_000_000));
        let p = e.pos_vel_cov();
        let (sp2, sv2) = (c.init_pos_sigma_m.powi(2), c.init_vel_sigma_mps.powi(2));
        let (sr2, sba2) = (
            c.init_roll_pitch_sigma_rad.powi(2),
            c.init_accel_bias_sigma_mps2.powi(2),
        );
        assert!((p[0][0] - (sp2 + dt * dt * sv2)).abs() < 1e-15);
        assert!((p[0][3] - dt * sv2).abs() < 1e-15);
        let vv = sv2 + dt * dt * (G * G * sr2 + sba2) + c.accel_noise_mps2_per_rthz.powi(2) * dt;
        assert!((p[3][3] - vv).abs() < 1e-12, "{} vs {vv}", p[3][3]);
        // Vertical velocity: no tilt coupling (the force is along z).
        let vz = sv2 + dt * dt * sba2 + c.accel_noise_mps2_per_rthz.powi(2) * dt;
        assert!((p[5][5] - vz).abs() < 1e-12);
        assert_eq!(e.predict_errors(), 0);
    }

    /// With `specific_force_tau_s`, `F` sees the low-passed specific force:
    /// one interval's spike of 50 m/s^2 east (a vibration peak) after 0.1 s
    /// at rest couples the yaw to the north velocity about a hundred times
    /// less than when passed raw.
    #[test]
    fn vibration_is_low_passed_before_it_reaches_f() {
        let shaking = |tau: f64| {
            let mut e = TightEstimator::new(
                EskfConfig::default(),
                TightConfig {
                    specific_force_tau_s: tau,
                    ..TightConfig::default()
                },
                G,
            )
            .unwrap();
            for k in 0..=100u64 {
                let mut n = level_nav(k * 1_000_000);
                if k == 100 {
                    n.accel_nav_mps2[0] = 50.0;
                }
                e.predict(1e-3, &n);
            }
            // Cross-covariance of north velocity and yaw.
            e.eskf().covariance()[(4, 8)].abs()
        };
        let (raw, smooth) = (shaking(0.0), shaking(0.1));
        assert!(raw > 0.0 && smooth < 0.05 * raw, "{smooth} vs {raw}");
        let bad = TightConfig {
            specific_force_tau_s: -0.1,
            ..TightConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("specific_force_tau_s"));
        let bad = TightConfig {
            predict_period_s: 0.5,
            ..TightConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("predict_period_s"));
    }

    /// Propagating every 10 ms instead of every 1 ms INS interval: an
    /// update still sees the covariance propagated to its own time (the
    /// accumulated intervals are flushed first), within the first-order
    /// difference of one long step against ten short ones.
    #[test]
    fn accumulated_propagation_is_flushed_before_an_update() {
        let mut every = estimator([0.0; 3]);
        let mut accumulated = TightEstimator::new(
            EskfConfig::default(),
            TightConfig {
                predict_period_s: 0.01,
                ..TightConfig::default()
            },
            G,
        )
        .unwrap();
        let (a, b) = ([-4.0, 0.0, 1.1], [4.0, 0.0, 1.1]);
        for i in 1..=25u64 {
            let nav = level_nav(i * 1_000_000);
            every.predict(0.001, &nav);
            accumulated.predict(0.001, &nav);
        }
        // 25 ms: two 10 ms steps propagated, 5 ms pending until the update.
        let p_every = every.eskf().covariance()[(0, 0)];
        let p_acc = accumulated.eskf().covariance()[(0, 0)];
        assert!(p_acc < p_every, "{p_acc} against {p_every}");
        let m = tdoa(25_000_000, a, b, -0.2);
        let ie = every.update_tdoa(&ins_at([0.0, 0.0, 1.0]), &m).unwrap();
        let ia = accumulated
            .update_tdoa(&ins_at([0.0, 0.0, 1.0]), &m)
            .unwrap();
        let rel = (ie.innovation_var[0] - ia.innovation_var[0]).abs() / ie.innovation_var[0];
        // The 5 ms left unpropagated would differ by 8e-5; one 10 ms step
        // against ten 1 ms steps differs by 9e-8.
        assert!((p_every - p_acc) / p_every > 1e-5);
        assert!(rel < 1e-6, "{ie:?} against {ia:?}");
    }

    #[test]
    fn long_intervals_are_split_and_absurd_ones_refused() {
        let mut one = estimator([0.0; 3]);
        let mut split = estimator([0.0; 3]);
        // 0.25 s with max_dt_s = 0.1: three steps of 1/12 s.
        split.predict(0.25, &level_nav(0));
        for _ in 0..3 {
            one.predict(0.25 / 3.0, &level_nav(0));
        }
        assert_eq!(split.pos_vel_cov(), one.pos_vel_cov());
        assert_eq!(split.predict_errors(), 0);
        let before = split.pos_vel_cov();
        split.predict(100.0, &level_nav(0));
        split.predict(f64::NAN, &level_nav(0));
        assert_eq!(split.predict_errors(), 1);
        assert_eq!(split.pos_vel_cov(), before);
    }

    #[test]
    fn outliers_are_rejected_and_reset_restores_p0() {
        let mut e = estimator([0.0; 3]);
        let p0 = e.pos_vel_cov();
        let (a, b) = ([-4.0, 0.0, 1.0], [4.0, 0.0, 1.0]);
        let info = e
            .update_tdoa(&ins_at([0.0, 0.0, 1.0]), &tdoa(0, a, b, 50.0))
            .unwrap();
        assert!(info.rejected && info.outlier && info.lambda[0] == 0.0);
        assert!(e.take_correction().is_zero());
        // A refused input (antenna on an anchor) is reported, not applied.
        let info = e.update_tdoa(&ins_at(a), &tdoa(0, a, b, 0.0)).unwrap();
        assert!(info.rejected);
        assert_eq!(e.update_errors(), 1);
        e.update_tdoa(&ins_at([0.0, 0.0, 1.0]), &tdoa(0, a, b, 0.1))
            .unwrap();
        assert_ne!(e.pos_vel_cov(), p0);
        e.reset();
        assert_eq!(e.pos_vel_cov(), p0);
        assert!(e.take_correction().is_zero());
        assert!(e
            .update_fix(&ins_at([0.0; 3]), &UwbFix::default())
            .is_none());
    }

    #[test]
    fn covariance_snapshot_round_trip() {
        let mut e = estimator([0.0; 3]);
        e.predict(0.05, &level_nav(0));
        let mut snap = Vec::new();
        e.covariance_snapshot(&mut snap);
        assert_eq!(snap.len(), N_STATES * N_STATES);
        let mut f = estimator([0.0; 3]);
        assert!(f.restore_covariance(&snap));
        assert_eq!(f.pos_vel_cov(), e.pos_vel_cov());
        assert!(!f.restore_covariance(&snap[1..]));
        let mut bad = snap.clone();
        bad[0] = -1.0;
        assert!(!f.restore_covariance(&bad));
    }

    #[test]
    fn config_errors_name_the_key() {
        let e = TightEstimator::new(
            EskfConfig::default(),
            TightConfig {
                lever_arm_m: [0.0, f64::NAN, 0.0],
                ..TightConfig::default()
            },
            G,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("tight.lever_arm_m[1] must be finite"),
            "{e}"
        );
        let e =
            TightEstimator::new(EskfConfig::default(), TightConfig::default(), 1.0).unwrap_err();
        assert!(e.to_string().contains("gravity_mps2"), "{e}");
        let bad = EskfConfig {
            kappa: -1.0,
            ..EskfConfig::default()
        };
        let e = TightEstimator::new(bad, TightConfig::default(), G).unwrap_err();
        assert!(e.to_string().contains("eskf.kappa"), "{e}");
        let t: TightConfig = toml::from_str("lever_arm_m = [0.0, 0.0, 0.1]").unwrap();
        assert_eq!(t.lever_arm_m, [0.0, 0.0, 0.1]);
        assert!(toml::from_str::<TightConfig>("lever_arm = [0.0, 0.0, 0.1]").is_err());
    }

    /// A static, level vehicle whose IMU reads gravity only, 1 kHz, and
    /// noise-free TDOA differences of all pairs of six anchors at 10 Hz;
    /// the INS starts 0.3 m off and the tight filter runs through the whole
    /// lockstep runner (fix builder, engine, INS).
    fn static_scene(start_s: f64, end_s: f64) -> (Vec<ImuSample>, Vec<UwbTdoa>, [f64; 3]) {
        let anchors = [
            [-4.0, -4.0, 0.2],
            [4.0, -4.0, 3.0],
            [4.0, 4.0, 0.2],
            [-4.0, 4.0, 3.0],
            [0.0, -4.5, 1.5],
            [0.0, 4.5, 2.5],
        ];
        let p = [0.7, -0.4, 1.2];
        let dist = |a: [f64; 3]| {
            ((p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2) + (p[2] - a[2]).powi(2)).sqrt()
        };
        let imu: Vec<ImuSample> = (0..=((end_s * 1000.0) as u64))
            .map(|k| ImuSample {
                header: Header::new(k, k * 1_000_000),
                accel_mps2: [0.0, 0.0, G],
                gyro_rps: [0.0; 3],
            })
            .collect();
        let mut tdoa = Vec::new();
        let mut seq = 0;
        let mut t_ns = (start_s * 1e9) as u64;
        while t_ns as f64 * 1e-9 < end_s {
            for i in 0..anchors.len() {
                for j in (i + 1)..anchors.len() {
                    tdoa.push(UwbTdoa {
                        header: Header::new(seq, t_ns),
                        anchor_a: i as u32,
                        anchor_b: j as u32,
                        diff_m: dist(anchors[j]) - dist(anchors[i]),
                        anchor_a_pos_m: anchors[i],
                        anchor_b_pos_m: anchors[j],
                    });
                    seq += 1;
                    t_ns += 1_000_000;
                }
            }
            t_ns += 100_000_000 - 15 * 1_000_000;
        }
        (imu, tdoa, p)
    }

    #[test]
    fn tight_filter_initialises_and_converges_in_the_lockstep_runner() {
        let (imu, tdoa, p) = static_scene(0.0205, 3.0);
        let mut cfg = FusionConfig::default();
        cfg.fix.mode = insuwb_uwb::fix::FixMode::Mode3d;
        cfg.engine.init_from_first_fix = true;
        let out = runner::run(&imu, &tdoa, &cfg, FilterKind::IakfTdoa).unwrap();
        // Initialised from the first fix, then one fused state per 0.1 s epoch.
        assert_eq!(out.fusion.resets, 1, "{:?}", out.fusion);
        assert!(out.fused.len() >= 25, "{}", out.fused.len());
        // Every TDOA difference after the initialisation is an update (15 per epoch).
        assert!(out.fusion.updates >= 15 * 25, "{:?}", out.fusion);
        assert!(out
            .fused
            .iter()
            .all(|f| f.filter_kind == FilterKind::IakfTdoa as u32));
        let last = out.fused.last().unwrap();
        for k in 0..3 {
            assert!(
                (last.pos_m[k] - p[k]).abs() < 1e-3,
                "{:?} vs {p:?}",
                last.pos_m
            );
            assert!(last.vel_mps[k].abs() < 1e-3, "{:?}", last.vel_mps);
        }
        // Each fused state sits at a fix epoch (the last TDOA of its epoch).
        let fix_times: Vec<u64> = out.fixes.iter().map(|f| f.header.meas_time_ns).collect();
        assert!(out
            .fused
            .iter()
            .all(|f| fix_times.contains(&f.header.meas_time_ns)));
        assert!(out
            .diag
            .iter()
            .all(|d| d.header.layout_version == LAYOUT_VERSION));
    }

    #[test]
    fn build_estimator_gives_the_tight_filter() {
        let mut cfg = FusionConfig::default();
        let e = build_estimator(FilterKind::IakfTdoa, &cfg).unwrap();
        assert!(e.is_tight() && e.kind() == FilterKind::IakfTdoa);
        cfg.eskf.tdoa_sigma_m = 0.0;
        let err = build_estimator(FilterKind::IakfTdoa, &cfg).unwrap_err();
        assert!(err.to_string().contains("eskf.tdoa_sigma_m"), "{err}");
        cfg.eskf = EskfConfig::default();
        cfg.tight.lever_arm_m = [20.0, 0.0, 0.0];
        assert!(build_estimator(FilterKind::IakfTdoa, &cfg).is_err());
    }
}
