//! The estimator interface the fusion engine drives, and its two families:
//! the paper's loosely coupled 14-state filters (KF, SHAF, STF, IAKF) fed
//! with UWB fixes, and the tightly coupled 15-state error-state filter fed
//! with each TDOA measurement.

use crate::aiding::{scale_corrected, AidingConfig, HeightConfig, VelocityScales};
use crate::vibration::{VibrationConfig, VibrationMeter};
use insuwb_msg::{BodyVelocity, FilterKind, Height, NavState, UwbFix, UwbRange, UwbTdoa};

/// The acceleration an INS that coasted through an IMU gap missed, m/s^2
/// (a robot's manoeuvres: 1 m/s^2 is a 0.8 m/s loop of 0.64 m radius).
pub const GAP_ACCEL_MPS2: f64 = 1.0;

/// The velocity noise density (m^2/s^3) a filter adds over an INS interval
/// that coasted through an IMU gap (`NavState::FLAG_GAP`: a driver frozen
/// or restarted, samples lost): `GAP_ACCEL_MPS2^2 dt`, so that its
/// velocity error grows by `GAP_ACCEL_MPS2 dt` and its position error by
/// about `GAP_ACCEL_MPS2 dt^2 / sqrt(3)` over the gap. Without it the
/// first fixes after the gap read as a radio far noisier than it is, and
/// an adaptive `R` learns that; 0 for any other interval.
#[must_use]
pub fn gap_velocity_noise(dt_s: f64, nav: &NavState) -> f64 {
    if nav.header.flags & NavState::FLAG_GAP != 0 && dt_s.is_finite() && dt_s > 0.0 {
        GAP_ACCEL_MPS2 * GAP_ACCEL_MPS2 * dt_s
    } else {
        0.0
    }
}

/// Most pieces a filter's prediction over one long interval (an IMU gap, a
/// restarted INS) is cut into; a longer one is refused and counted.
pub(crate) const MAX_PREDICT_SPLIT: u32 = 100;

/// `dt_s` cut into equal pieces of at most `max_piece_s`: their number and
/// length, or `None` beyond [`MAX_PREDICT_SPLIT`] pieces.
pub(crate) fn split_interval(dt_s: f64, max_piece_s: f64) -> Option<(u32, f64)> {
    let n = (dt_s / max_piece_s).ceil().max(1.0);
    if n > f64::from(MAX_PREDICT_SPLIT) {
        return None;
    }
    // n is an integer in [1, MAX_PREDICT_SPLIT].
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    Some((n as u32, dt_s / n))
}

/// The INS state at a measurement's epoch (interpolated between two samples).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct InsAt {
    /// Epoch, ns.
    pub t_ns: u64,
    /// Position, ENU, m.
    pub pos_m: [f64; 3],
    /// Velocity, ENU, m/s.
    pub vel_mps: [f64; 3],
    /// Attitude `[w, x, y, z]`.
    pub quat: [f64; 4],
}

/// The error estimate to feed back into the INS (convention of
/// [`insuwb_msg::InsCorrection`]: error = INS minus truth).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Delta {
    /// Position error, m.
    pub d_pos_m: [f64; 3],
    /// Velocity error, m/s.
    pub d_vel_mps: [f64; 3],
    /// Attitude error (ENU rotation vector), rad.
    pub d_att_rad: [f64; 3],
    /// Accelerometer bias increment, m/s^2.
    pub d_accel_bias_mps2: [f64; 3],
    /// Gyro bias increment, rad/s.
    pub d_gyro_bias_rps: [f64; 3],
}

impl Delta {
    /// Whether every component is zero.
    #[must_use]
    pub fn is_zero(&self) -> bool {
        self.d_pos_m
            .iter()
            .chain(&self.d_vel_mps)
            .chain(&self.d_att_rad)
            .chain(&self.d_accel_bias_mps2)
            .chain(&self.d_gyro_bias_rps)
            .all(|v| *v == 0.0)
    }

    /// Whether every component is finite.
    #[must_use]
    pub fn is_finite(&self) -> bool {
        self.d_pos_m
            .iter()
            .chain(&self.d_vel_mps)
            .chain(&self.d_att_rad)
            .chain(&self.d_accel_bias_mps2)
            .chain(&self.d_gyro_bias_rps)
            .all(|v| v.is_finite())
    }
}

/// What one update did (copied into [`insuwb_msg::FilterDiag`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UpdateInfo {
    /// Innovation per component.
    pub innovation: [f64; 8],
    /// Innovation variance per component.
    pub innovation_var: [f64; 8],
    /// Outlier weight per component.
    pub lambda: [f64; 8],
    /// R diagonal in use.
    pub r_diag: [f64; 8],
    /// Components used.
    pub dim: u32,
    /// Normalised innovation squared (what the divergence monitor reads,
    /// per component: `nis / dim`).
    pub nis: f64,
    /// Fading factor (1: none).
    pub fading: f64,
    /// The filter's own divergence test fired (the IAKF's eq. 27, which
    /// triggers its fading; the tight filter: its covariance is no longer
    /// finite). The engine's monitor is apart from it.
    pub divergence: bool,
    /// A component was weighted as an outlier.
    pub outlier: bool,
    /// The measurement was rejected outright (no state change).
    pub rejected: bool,
}

/// An error-state estimator driven by the fusion engine.
pub trait Estimator: std::fmt::Debug + Send {
    /// Which filter this is.
    fn kind(&self) -> FilterKind;
    /// Propagates over one INS interval ending at `nav` (`dt_s` seconds),
    /// using the nominal state `nav`.
    fn predict(&mut self, dt_s: f64, nav: &NavState);
    /// Flushes any accumulated prediction before an update.
    fn flush_predict(&mut self) {}
    /// Updates with a UWB fix (loose coupling); `None` when it does not use fixes.
    fn update_fix(&mut self, ins: &InsAt, fix: &UwbFix) -> Option<UpdateInfo>;
    /// Updates with one TDOA measurement (tight coupling); `None` when it does not use them.
    fn update_tdoa(&mut self, ins: &InsAt, m: &UwbTdoa) -> Option<UpdateInfo>;
    /// Updates with one two-way range (tight coupling); `None` when it does
    /// not use them (default: the loose filters use the range fixes).
    fn update_range(&mut self, _ins: &InsAt, _m: &UwbRange) -> Option<UpdateInfo> {
        None
    }
    /// Updates with a body-frame velocity (odometry, flow); `None` when it
    /// does not use them (default).
    fn update_velocity(&mut self, _ins: &InsAt, _m: &BodyVelocity) -> Option<UpdateInfo> {
        None
    }
    /// Updates with a height (a range finder's, [`crate::aiding::HeightConfig`]);
    /// `None` when it is not an update of its own (default).
    fn update_height(&mut self, _ins: &InsAt, _m: &Height) -> Option<UpdateInfo> {
        None
    }
    /// Returns the navigation error estimate and zeroes it (closed loop).
    fn take_correction(&mut self) -> Delta;
    /// The navigation error estimate not taken yet, left in place: what
    /// [`Estimator::take_correction`] would return now. A loose filter's
    /// body-velocity updates and vehicle constraints move its estimate
    /// between fixes without a correction going out (it goes out with the
    /// next fix's); an output built on the INS meanwhile (the coasting
    /// state) applies this. Default zero: every correction goes out with
    /// its update.
    fn pending_correction(&self) -> Delta {
        Delta::default()
    }
    /// The online scale factor estimates (`measured / true`) and their
    /// standard deviations of the velocity sources, `[flow, odometry]`
    /// ([`crate::aiding::ScaleEstimator`]); `None` when the estimator has
    /// none (default).
    fn aiding_scales(&self) -> Option<[(f64, f64); 2]> {
        None
    }
    /// Covariance of `[pe, pn, pu, ve, vn, vu]`.
    fn pos_vel_cov(&self) -> [[f64; 6]; 6];
    /// Whether the estimator asks to be reset because it broke down
    /// numerically (a covariance that is no longer finite). A finite but
    /// inconsistent filter is found by the engine's divergence monitor,
    /// the same for every estimator, from [`UpdateInfo::nis`].
    fn needs_reset(&self) -> bool {
        false
    }
    /// Resets the covariance to its initial value and the state to zero.
    fn reset(&mut self);
    /// Whether it consumes TDOA measurements (else UWB fixes).
    fn is_tight(&self) -> bool {
        false
    }
    /// Writes the full error covariance, row-major, into `out` (for
    /// checkpoints; left empty when not supported). Reuses `out`'s capacity:
    /// no allocation once it holds a snapshot.
    fn covariance_snapshot(&self, out: &mut Vec<f64>) {
        out.clear();
    }
    /// Restores a covariance from [`Estimator::covariance_snapshot`] (state zero);
    /// false when the snapshot does not fit or is not a covariance.
    fn restore_covariance(&mut self, _p: &[f64]) -> bool {
        false
    }
    /// Writes what the estimator learnt from its innovations (its adaptive
    /// `R`, its noise scales) into `out` (cleared; left empty when there is
    /// nothing), for checkpoints beside [`Estimator::covariance_snapshot`].
    fn adaptive_snapshot(&self, out: &mut Vec<f64>) {
        out.clear();
    }
    /// Restores an [`Estimator::adaptive_snapshot`] after
    /// [`Estimator::restore_covariance`]; false when it does not fit.
    fn restore_adaptive(&mut self, _s: &[f64]) -> bool {
        false
    }
    /// Runs the work of an update once on a scratch copy of the filter,
    /// leaving the estimate unchanged, so that the code and data of the next
    /// real update are in the caches (the fusion stage calls it shortly
    /// before a fix is due). No allocation. Default: nothing.
    fn warm_up(&mut self) {}
}

/// Settings of the loosely coupled paper filters inside the engine.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LooseConfig {
    /// Fuse the UWB velocity (eq. 13) when the fix carries a valid one; else
    /// position only.
    pub use_velocity: bool,
    /// How the random-walk acceleration-error states are fed back (only with
    /// `model.bias_random_walk`). Default `bias`.
    pub accel_feedback: AccelFeedback,
    /// The paper's filter is 2D: on a 3D vehicle the INS height and vertical
    /// velocity drift without bound. A value > 0 steers them to the height of
    /// 3D UWB fixes with a second-order, critically damped complementary loop
    /// of this natural frequency `w`, rad/s: per fix, with `T` the time since
    /// the previous fix (clamped to [0.01, 1] s) and `dz` the INS height
    /// minus the fix's, `d_pos_z = 2 w T dz`, `d_vel_z = w^2 T dz`. Default 0
    /// (off, the paper's 2D filter).
    pub vertical_bandwidth_rps: f64,
    /// The UWB antenna's position in the body frame (the IMU's), m: a fix
    /// is compared with the INS position plus this arm rotated by the INS
    /// attitude. The arm's velocity (rotation rate x arm) is neglected: the
    /// velocity of a fix is a regression over about a second. Default zero.
    pub lever_arm_m: [f64; 3],
    /// Body-velocity updates (odometry, flow: [`Estimator::update_velocity`]),
    /// one per measured axis: an axis whose innovation is beyond this many
    /// standard deviations of its prediction is weighted down by
    /// `velocity_kappa / ratio` (its noise inflated by the square of the
    /// inverse), as the tight filter's `eskf.kappa`. Default 3.
    pub velocity_kappa: f64,
    /// Body-velocity updates: an axis beyond this many standard deviations
    /// is rejected, as the tight filter's `eskf.hard_gate_sigma`. Default 8.
    pub velocity_gate_sigma: f64,
    /// The scale factor of a velocity source (`[fusion.aiding]`) is
    /// observed on baselines: the distance its samples integrate to between
    /// two UWB fixes at least this far apart (m) against the distance
    /// between the fixes. The filter's own velocity is no observation of
    /// it: the source's updates pull that velocity to the source's reading
    /// over the current factor, whatever the factor. Default 2.
    pub scale_baseline_m: f64,
}

impl Default for LooseConfig {
    fn default() -> Self {
        Self {
            use_velocity: true,
            accel_feedback: AccelFeedback::Bias,
            vertical_bandwidth_rps: 0.0,
            lever_arm_m: [0.0; 3],
            velocity_kappa: 3.0,
            velocity_gate_sigma: 8.0,
            scale_baseline_m: 2.0,
        }
    }
}

/// How the random-walk acceleration-error states (`model.bias_random_walk`,
/// erratum 19) are fed back into the INS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AccelFeedback {
    /// As an accelerometer bias, rotated into the body frame with the current
    /// attitude (default).
    #[default]
    Bias,
    /// As the tilt (roll/pitch) error that causes it: a level INS tilted by
    /// the ENU rotation vector `d_att` sees `g [d_att_n, -d_att_e]` of false
    /// horizontal acceleration, so `d_att = [d_a_n, -d_a_e, 0] / g`. On a 3D
    /// vehicle whose attitude drifts (the UTIL quadrotor: gyro errors under
    /// fast yaw), the error is a tilt, fixed in the navigation frame, which a
    /// body-frame bias only matches until the vehicle turns.
    Tilt,
}

/// The tilt (ENU rotation vector, INS minus truth, east and north
/// components, rad) that makes a level INS see the horizontal acceleration
/// error `d a = a_true - a_meas` (erratum 4) under gravity `g`: the INS's
/// error `-d a` is `g [d_att_n, -d_att_e]`, so `d_att = [d_a_n, -d_a_e] / g`.
#[must_use]
pub fn tilt_from_accel_error(d_a_e_mps2: f64, d_a_n_mps2: f64, gravity_mps2: f64) -> [f64; 2] {
    [d_a_n_mps2 / gravity_mps2, -d_a_e_mps2 / gravity_mps2]
}

/// A [`LooseConfig`] value out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LooseConfigError {
    /// `vertical_bandwidth_rps` is negative, not finite or above 10 rad/s.
    #[error("loose.vertical_bandwidth_rps must be in [0, 10] rad/s, got {0}")]
    VerticalBandwidth(f64),
    /// A lever-arm component is not finite or longer than 10 m.
    #[error("loose.lever_arm_m[{index}] must be finite and within [-10, 10] m, got {value}")]
    LeverArm {
        /// The component.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// `velocity_kappa` is not finite and within (0, 100].
    #[error("loose.velocity_kappa must be in (0, 100], got {0}")]
    VelocityKappa(f64),
    /// `velocity_gate_sigma` is not finite, above `velocity_kappa` and at most 1000.
    #[error(
        "loose.velocity_gate_sigma must be > velocity_kappa ({kappa}) and <= 1000, got {value}"
    )]
    VelocityGate {
        /// Its value.
        value: f64,
        /// `velocity_kappa`.
        kappa: f64,
    },
    /// `scale_baseline_m` is not finite and within (0, 1000] m.
    #[error("loose.scale_baseline_m must be in (0, 1000] m, got {0}")]
    ScaleBaseline(f64),
}

impl LooseConfig {
    /// Checks every value, naming the first offending key.
    ///
    /// # Errors
    /// [`LooseConfigError`] naming the key and its value.
    pub fn validate(&self) -> Result<(), LooseConfigError> {
        for (index, &value) in self.lever_arm_m.iter().enumerate() {
            if !(value.is_finite() && value.abs() <= 10.0) {
                return Err(LooseConfigError::LeverArm { index, value });
            }
        }
        let w = self.vertical_bandwidth_rps;
        if !(w.is_finite() && (0.0..=10.0).contains(&w)) {
            return Err(LooseConfigError::VerticalBandwidth(w));
        }
        let kappa = self.velocity_kappa;
        if !(kappa.is_finite() && kappa > 0.0 && kappa <= 100.0) {
            return Err(LooseConfigError::VelocityKappa(kappa));
        }
        let gate = self.velocity_gate_sigma;
        if !(gate.is_finite() && gate > kappa && gate <= 1000.0) {
            return Err(LooseConfigError::VelocityGate { value: gate, kappa });
        }
        let b = self.scale_baseline_m;
        if !(b.is_finite() && b > 0.0 && b <= 1000.0) {
            return Err(LooseConfigError::ScaleBaseline(b));
        }
        Ok(())
    }
}

/// The paper's filters (KF, SHAF, STF, IAKF) as an [`Estimator`].
///
/// Prediction runs once per AR step of the model (`model.ar_rate_hz`): INS
/// intervals are accumulated until one AR step is reached, with the mean
/// kinematic acceleration over it. Closed loop: the position, velocity and
/// heading errors are fed back into the INS after every update and the whole
/// error state is zeroed (the AR states too: the fitted AR(3) of a MEMS sensor
/// is nearly white (erratum 19), so their estimate decorrelates within a few
/// samples and is not worth a protocol field).
///
/// Body velocities (odometry, flow) update the error state between fixes
/// ([`Estimator::update_velocity`]) without a correction of their own: the
/// state they leave is propagated with the model like any other
/// (`x <- Phi x` in each prediction, the next update's innovation taken
/// against `H x`), fed back with the next fix's correction, and shown
/// meanwhile by [`Estimator::pending_correction`].
#[derive(Debug)]
pub struct PaperEstimator {
    filter: Box<dyn insuwb_filter::ErrorFilter>,
    cfg: LooseConfig,
    p0: insuwb_filter::model::Mat14,
    step_s: f64,
    acc_dt: f64,
    acc_ae: f64,
    acc_an: f64,
    predict_errors: u64,
    /// Attitude of the last INS state seen (to express bias feedback in the body frame).
    last_quat: [f64; 4],
    /// The model's AR blocks are random-walk biases (erratum 19): feed them back.
    bias_feedback: bool,
    gravity_mps2: f64,
    /// Vertical correction of the last fix, not yet taken: `(d_pos_z, d_vel_z)`.
    vertical: Option<(f64, f64)>,
    last_fix_t_ns: Option<u64>,
    /// A filter of the same kind for [`Estimator::warm_up`].
    scratch: Box<dyn insuwb_filter::ErrorFilter>,
    /// Whether the last fix update used the velocity (the warm-up runs the
    /// same kind of update: another size is other code).
    last_update_vel: bool,
    /// Vibration settings and meter ([`crate::vibration`]).
    vib_cfg: VibrationConfig,
    vib: VibrationMeter,
    /// What the INS integrates ([`PaperEstimator::with_vehicle`]).
    mech: insuwb_nav::vehicle::Mechanisation,
    /// The vehicle's own (`mech` while the INS has not handed over).
    vehicle_mech: insuwb_nav::vehicle::Mechanisation,
    /// The ground robot's lateral-velocity constraint and the time since
    /// its last update, s.
    ground: Option<(crate::vehicle::GroundConfig, f64)>,
    /// Constraint updates refused by the filter.
    constraint_errors: u64,
    /// The online scale factors of flow and odometry ([`crate::aiding`])
    /// and the baselines they are observed on.
    scales: VelocityScales,
    /// Body-velocity components applied (weighted down included), rejected
    /// by the gate, and refused by the filter.
    velocity_applied: u64,
    velocity_rejected: u64,
    velocity_errors: u64,
    /// The range finder's height ([`HeightConfig`]) and the last one,
    /// `(t_ns, z)`: the vertical loop's target instead of the fix's height
    /// while it is recent.
    height: HeightConfig,
    range_height: Option<(u64, f64)>,
}

/// How long a range finder's height stays the vertical loop's target, ns.
const RANGE_HEIGHT_MAX_AGE_NS: u64 = 500_000_000;

impl PaperEstimator {
    /// Wraps a built filter; `p0` is used on reset.
    #[must_use]
    pub fn new(
        filter: Box<dyn insuwb_filter::ErrorFilter>,
        cfg: LooseConfig,
        p0: insuwb_filter::model::Mat14,
    ) -> Self {
        let step_s = filter.model().ar_step_s();
        let bias_feedback = filter.model().config().bias_random_walk.is_some();
        Self {
            last_quat: [1.0, 0.0, 0.0, 0.0],
            bias_feedback,
            gravity_mps2: insuwb_nav::ins::STANDARD_GRAVITY_MPS2,
            vertical: None,
            last_fix_t_ns: None,
            height: HeightConfig::default(),
            range_height: None,
            scratch: filter.clone_boxed(),
            last_update_vel: false,
            vib_cfg: VibrationConfig::default(),
            vib: VibrationMeter::default(),
            mech: insuwb_nav::vehicle::Mechanisation::Free,
            vehicle_mech: insuwb_nav::vehicle::Mechanisation::Free,
            ground: None,
            constraint_errors: 0,
            scales: VelocityScales::default(),
            velocity_applied: 0,
            velocity_rejected: 0,
            velocity_errors: 0,
            filter,
            cfg,
            p0,
            step_s,
            acc_dt: 0.0,
            acc_ae: 0.0,
            acc_an: 0.0,
            predict_errors: 0,
        }
    }

    /// Sets the gravity magnitude of the tilt feedback (m/s^2; the INS's
    /// `ins.gravity_mps2`, default standard gravity). A value that is not
    /// finite and positive is ignored.
    #[must_use]
    pub fn with_gravity(mut self, gravity_mps2: f64) -> Self {
        if gravity_mps2.is_finite() && gravity_mps2 > 0.0 {
            self.gravity_mps2 = gravity_mps2;
        }
        self
    }

    /// The INS state moved to the UWB antenna ([`LooseConfig::lever_arm_m`]).
    fn antenna(&self, ins: &InsAt) -> InsAt {
        let l = self.cfg.lever_arm_m;
        if l == [0.0; 3] {
            return *ins;
        }
        let q = ins.quat;
        let r = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[0], q[1], q[2], q[3],
        ));
        let arm = r * nalgebra::Vector3::new(l[0], l[1], l[2]);
        let mut a = *ins;
        for (p, d) in a.pos_m.iter_mut().zip(arm.iter()) {
            *p += d;
        }
        a
    }

    /// The vertical loop's correction for a fix ([`LooseConfig::vertical_bandwidth_rps`]).
    fn vertical_correction(&mut self, ins: &InsAt, fix: &UwbFix) -> Option<(f64, f64)> {
        let w = self.cfg.vertical_bandwidth_rps;
        let t = fix.header.meas_time_ns;
        let prev = self.last_fix_t_ns.replace(t);
        if w <= 0.0 || fix.header.flags & UwbFix::FLAG_2D != 0 {
            return None;
        }
        let dt_s = prev
            .map_or(0.1, |p| t.saturating_sub(p) as f64 * 1e-9)
            .clamp(0.01, 1.0);
        // The range finder's height while it is recent, else the fix's.
        let target = match self.range_height {
            Some((tr, z)) if t.abs_diff(tr) <= RANGE_HEIGHT_MAX_AGE_NS => z,
            _ => fix.pos_m[2],
        };
        let dz = ins.pos_m[2] - target;
        Some((2.0 * w * dt_s * dz, w * w * dt_s * dz))
    }

    /// The correction for the error state `x` and the vertical loop's
    /// `(d_pos_z, d_vel_z)`.
    fn delta_from(&self, x: &insuwb_filter::model::Vec14, (dz, dvz): (f64, f64)) -> Delta {
        let mut d = Delta {
            d_pos_m: [x[0], x[1], dz],
            d_vel_mps: [x[2], x[3], dvz],
            d_att_rad: [0.0, 0.0, x[4]],
            ..Delta::default()
        };
        if self.bias_feedback && self.cfg.accel_feedback == AccelFeedback::Tilt {
            // `d a = a_true - a_meas` (erratum 4): the INS's own error is
            // `-d a = g [d_att_n, -d_att_e]`.
            let q = self.last_quat;
            let r = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                q[0], q[1], q[2], q[3],
            ));
            let bg = r.inverse() * nalgebra::Vector3::new(0.0, 0.0, -x[11]);
            let [tilt_e, tilt_n] = tilt_from_accel_error(x[5], x[8], self.gravity_mps2);
            d.d_att_rad = [tilt_e, tilt_n, x[4]];
            d.d_gyro_bias_rps = [bg.x, bg.y, bg.z];
        } else if self.bias_feedback {
            // States 5, 8, 11 are `d a = a_true - a_meas` (ENU) and `d w`
            // (erratum 4): the INS bias (subtracted from the samples) moves by
            // minus their body-frame value.
            let q = self.last_quat;
            let r = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                q[0], q[1], q[2], q[3],
            ));
            let ba = r.inverse() * nalgebra::Vector3::new(-x[5], -x[8], 0.0);
            let bg = r.inverse() * nalgebra::Vector3::new(0.0, 0.0, -x[11]);
            d.d_accel_bias_mps2 = [ba.x, ba.y, ba.z];
            d.d_gyro_bias_rps = [bg.x, bg.y, bg.z];
        }
        d
    }

    /// Adds the velocity noise of the vibration the IMU measures to the
    /// filter's ([`crate::vibration`]; off with the default settings).
    #[must_use]
    pub fn with_vibration(mut self, cfg: VibrationConfig) -> Self {
        self.vib_cfg = cfg;
        self
    }

    /// Linearises about the vehicle model the INS integrates
    /// (`insuwb_nav::vehicle`): the heading coupling uses the model's
    /// horizontal acceleration (for a multirotor, the thrust's tilt and the
    /// drag) instead of the accelerometer's.
    /// A ground robot's zero lateral velocity is fused as a constraint
    /// ([`insuwb_filter::ErrorFilter::update_constraint`]) every
    /// `ground.period_s`.
    #[must_use]
    pub fn with_vehicle(mut self, vehicle: &crate::vehicle::VehicleSettings<'_>) -> Self {
        self.mech = vehicle.mechanisation();
        self.vehicle_mech = self.mech;
        self.ground = (vehicle.kind == insuwb_nav::vehicle::VehicleKind::Ground)
            .then(|| (vehicle.ground.clone(), 0.0));
        self
    }

    /// Constraint updates the filter refused.
    #[must_use]
    pub fn constraint_errors(&self) -> u64 {
        self.constraint_errors
    }

    /// Uses the velocity aiding's settings `aiding`: each source's scale
    /// factor starts at its prior.
    #[must_use]
    pub fn with_aiding(mut self, aiding: &AidingConfig) -> Self {
        self.scales = VelocityScales::new(aiding);
        self.height = aiding.height;
        self
    }

    /// Body-velocity components applied (weighted down included), rejected
    /// by the gate (`loose.velocity_gate_sigma`), and refused by the filter.
    #[must_use]
    pub fn velocity_counts(&self) -> (u64, u64, u64) {
        (
            self.velocity_applied,
            self.velocity_rejected,
            self.velocity_errors,
        )
    }

    /// At a UWB fix: each velocity source's baseline that is long enough
    /// is an observation of its scale factor ([`LooseConfig::scale_baseline_m`]).
    fn observe_scales(&mut self, ins: &InsAt, antenna: &InsAt, fix: &UwbFix) {
        // The body's position: the fix less the lever arm (rotated).
        let body = [
            fix.pos_m[0] - (antenna.pos_m[0] - ins.pos_m[0]),
            fix.pos_m[1] - (antenna.pos_m[1] - ins.pos_m[1]),
        ];
        let c = fix.pos_cov_m2;
        let r = self.filter.r();
        let cov = if [c[0][0], c[1][1]].iter().all(|v| v.is_finite() && *v > 0.0)
            && c[0][1].is_finite()
            && c[1][0].is_finite()
        {
            [[c[0][0], c[0][1]], [c[1][0], c[1][1]]]
        } else {
            [[r[(0, 0)], 0.0], [0.0, r[(1, 1)]]]
        };
        self.scales.on_fix(
            fix.header.meas_time_ns,
            body,
            cov,
            self.cfg.scale_baseline_m,
        );
    }

    /// The ground robot's zero lateral velocity: with yaw `psi` (INS minus
    /// truth heading error `x[THETA]`), `v_lat = -sin(psi) v_e +
    /// cos(psi) v_n`, and to first order `v_lat,ins = -s δv_e + c δv_n -
    /// v_fwd δpsi` when the true lateral velocity is zero.
    fn ground_update(&mut self, nav: &NavState, sigma_mps: f64) {
        use insuwb_filter::model::idx;
        let q = nav.quat;
        let att = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[0], q[1], q[2], q[3],
        ));
        let psi = insuwb_nav::ins::yaw_of(&att);
        let (s, c) = psi.sin_cos();
        let [ve, vn, _] = nav.vel_mps;
        let mut h = insuwb_filter::model::Vec14::zeros();
        h[idx::VE] = -s;
        h[idx::VN] = c;
        h[idx::THETA] = -(c * ve + s * vn);
        let z = -s * ve + c * vn;
        if self
            .filter
            .update_constraint(&h, z, sigma_mps * sigma_mps)
            .is_err()
        {
            self.constraint_errors += 1;
        }
    }

    /// The wrapped filter.
    #[must_use]
    pub fn filter(&self) -> &dyn insuwb_filter::ErrorFilter {
        self.filter.as_ref()
    }

    /// Predict intervals the model refused.
    #[must_use]
    pub fn predict_errors(&self) -> u64 {
        self.predict_errors
    }

    fn run_predict(&mut self) {
        if self.acc_dt <= 0.0 {
            return;
        }
        let (ae, an) = (self.acc_ae / self.acc_dt, self.acc_an / self.acc_dt);
        // A long interval (an IMU gap, a restarted INS) in equal pieces the
        // model accepts: its covariance must grow by the whole interval, or
        // the filter would trust an INS that coasted through the gap.
        let chunk_s =
            self.step_s * f64::from(self.filter.model().config().max_steps_per_predict.max(1));
        match split_interval(self.acc_dt, chunk_s) {
            None => self.predict_errors += 1,
            Some((n, dt)) => {
                for _ in 0..n {
                    if self.filter.predict(dt, ae, an).is_err() {
                        self.predict_errors += 1;
                        break;
                    }
                }
            }
        }
        self.acc_dt = 0.0;
        self.acc_ae = 0.0;
        self.acc_an = 0.0;
    }
}

/// The covariance of `[pe, pn, pu, ve, vn, vu]` in a paper filter's `p`.
fn pos_vel_cov_of(p: &insuwb_filter::model::Mat14) -> [[f64; 6]; 6] {
    // Filter states 0..4 are pe, pn, ve, vn; output order pe, pn, pu, ve, vn, vu.
    let map = [Some(0usize), Some(1), None, Some(2), Some(3), None];
    let mut c = [[0.0; 6]; 6];
    for (i, mi) in map.iter().enumerate() {
        for (j, mj) in map.iter().enumerate() {
            if let (Some(a), Some(b)) = (mi, mj) {
                c[i][j] = p[(*a, *b)];
            }
        }
    }
    c
}

fn report_to_info(r: &insuwb_filter::UpdateReport) -> UpdateInfo {
    let mut i = UpdateInfo {
        dim: u32::try_from(r.dim).unwrap_or(0),
        nis: r.nis,
        fading: r.fading,
        divergence: r.divergence,
        outlier: r.outlier,
        ..UpdateInfo::default()
    };
    for k in 0..4 {
        i.innovation[k] = r.innovation[k];
        i.innovation_var[k] = r.innovation_var[k];
        i.lambda[k] = r.lambda[k];
        i.r_diag[k] = r.r_diag[k];
    }
    i
}

impl Estimator for PaperEstimator {
    fn kind(&self) -> FilterKind {
        self.filter.kind()
    }

    fn predict(&mut self, dt_s: f64, nav: &NavState) {
        if !(dt_s > 0.0 && dt_s.is_finite()) {
            return;
        }
        self.last_quat = nav.quat;
        // The INS's hand-over to the free model, while it lasts.
        self.mech = if nav.header.flags & NavState::FLAG_FREE != 0 {
            insuwb_nav::vehicle::Mechanisation::Free
        } else {
            self.vehicle_mech
        };
        let q = self.vib.push(&self.vib_cfg, dt_s, nav) + gap_velocity_noise(dt_s, nav);
        self.filter.set_extra_velocity_noise(q);
        let a = insuwb_nav::vehicle::model_accel_nav(
            self.mech,
            nav.quat,
            nav.vel_mps,
            nav.accel_nav_mps2,
            self.gravity_mps2,
        );
        self.acc_dt += dt_s;
        self.acc_ae += a[0] * dt_s;
        self.acc_an += a[1] * dt_s;
        if self.acc_dt >= self.step_s * (1.0 - 1e-6) {
            self.run_predict();
        }
        if let Some((g, since)) = self.ground.as_mut() {
            *since += dt_s;
            if *since >= g.period_s && self.acc_dt == 0.0 {
                *since = 0.0;
                let sigma = g.lateral_sigma_mps;
                self.ground_update(nav, sigma);
            }
        }
    }

    fn flush_predict(&mut self) {
        // A remainder shorter than half an AR step waits for the next interval.
        if self.acc_dt >= 0.5 * self.step_s {
            self.run_predict();
        }
    }

    fn warm_up(&mut self) {
        // The copy reads the whole state; one AR step of prediction and an
        // update of the last update's size with a zero INS-UWB difference
        // on it run the code of a fix epoch (with the state zero after each
        // correction, the innovation is zero too: the usual path, no
        // outlier), then the report, the correction and the output
        // covariance as the engine takes them. Errors are the copy's.
        if !self.filter.copy_to(self.scratch.as_mut()) {
            return;
        }
        let _ = self.scratch.predict(self.step_s, 0.0, 0.0);
        // `H x`: a zero innovation also when velocity updates or
        // constraints left the state away from zero.
        let x = *self.scratch.state();
        let rep = if self.last_update_vel {
            self.scratch
                .update(&nalgebra::SVector::<f64, 4>::new(x[0], x[1], x[2], x[3]))
        } else {
            self.scratch
                .update_pos(&nalgebra::SVector::<f64, 2>::new(x[0], x[1]))
        };
        if let Ok(r) = rep {
            std::hint::black_box(report_to_info(&r));
        }
        let x = self.scratch.take_correction();
        std::hint::black_box(self.delta_from(&x, (0.0, 0.0)));
        std::hint::black_box(pos_vel_cov_of(self.scratch.covariance()));
    }

    fn update_fix(&mut self, ins: &InsAt, fix: &UwbFix) -> Option<UpdateInfo> {
        let antenna = self.antenna(ins);
        self.observe_scales(ins, &antenna, fix);
        let ins = &antenna;
        self.vertical = self.vertical_correction(ins, fix);
        let dp = [ins.pos_m[0] - fix.pos_m[0], ins.pos_m[1] - fix.pos_m[1]];
        let vel_ok = self.cfg.use_velocity && fix.header.flags & UwbFix::FLAG_VEL_VALID != 0;
        self.last_update_vel = vel_ok;
        let rep = if vel_ok {
            let z = nalgebra::SVector::<f64, 4>::new(
                dp[0],
                dp[1],
                ins.vel_mps[0] - fix.vel_mps[0],
                ins.vel_mps[1] - fix.vel_mps[1],
            );
            self.filter.update(&z)
        } else {
            self.filter
                .update_pos(&nalgebra::SVector::<f64, 2>::new(dp[0], dp[1]))
        };
        Some(match rep {
            Ok(r) => report_to_info(&r),
            Err(_) => UpdateInfo {
                rejected: true,
                ..UpdateInfo::default()
            },
        })
    }

    fn update_tdoa(&mut self, _ins: &InsAt, _m: &UwbTdoa) -> Option<UpdateInfo> {
        None
    }

    /// The range finder's height becomes the vertical loop's target
    /// ([`HeightConfig`]); no update of the planar filter of its own.
    fn update_height(&mut self, ins: &InsAt, m: &Height) -> Option<UpdateInfo> {
        let q = ins.quat;
        let att = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[0], q[1], q[2], q[3],
        ));
        if let Some(z) = self.height.height_m(m, &att) {
            self.range_height = Some((m.header.meas_time_ns, z));
        }
        None
    }

    /// Each measured axis `i` of the body velocity, the unit vector `u =
    /// C e_i` (ENU) of the INS attitude, as a scalar measurement of the
    /// planar error state: the INS's velocity along the axis, `u . v`,
    /// minus the measurement corrected for its source's scale factor (as
    /// known so far: [`crate::aiding`]; the factor is observed on
    /// baselines between fixes, not here), with `H` = `u_e` on `δv_e`,
    /// `u_n` on `δv_n` and `-u_n v_e + u_e v_n` on `δψ` (the axis turned
    /// by the heading error; the ground constraint's `H` for the lateral
    /// axis). Weighted down beyond `loose.velocity_kappa` and rejected
    /// beyond `loose.velocity_gate_sigma`; a plain Kalman update otherwise
    /// (the adaptive estimators of the fix updates untouched). An axis
    /// within 60 deg of the vertical is left out: the filter is planar.
    fn update_velocity(&mut self, ins: &InsAt, m: &BodyVelocity) -> Option<UpdateInfo> {
        use insuwb_filter::model::{idx, Vec14};
        let q = ins.quat;
        let att = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[0], q[1], q[2], q[3],
        ));
        let scale = self.scales.on_sample(m, &att)?;
        let [ve, vn, vu] = ins.vel_mps;
        let (kappa, gate) = (self.cfg.velocity_kappa, self.cfg.velocity_gate_sigma);
        let mut info = UpdateInfo {
            fading: 1.0,
            ..UpdateInfo::default()
        };
        let mut measured = 0usize;
        for (i, (&value, &sigma)) in m.vel_mps.iter().zip(&m.sigma_mps).enumerate() {
            if sigma.is_nan() || sigma <= 0.0 {
                continue;
            }
            let u = att * nalgebra::Vector3::ith(i, 1.0);
            if u.x * u.x + u.y * u.y < 0.25 {
                continue;
            }
            let mut h = Vec14::zeros();
            h[idx::VE] = u.x;
            h[idx::VN] = u.y;
            h[idx::THETA] = -u.y * ve + u.x * vn;
            let ins_axis = u.x * ve + u.y * vn + u.z * vu;
            let x = self.filter.state();
            let hx = h.dot(x);
            let hph = h.dot(&(self.filter.covariance() * h)).max(0.0);
            let (corrected, sd) = scale_corrected(scale, value, sigma, ins_axis - hx);
            // INS minus measured: `H x` plus the noise.
            let z = ins_axis - corrected;
            let r = sd * sd;
            let v = z - hx;
            let s = hph + r;
            let ratio = if s > 0.0 {
                (v * v / s).sqrt()
            } else {
                f64::INFINITY
            };
            let k = measured;
            measured += 1;
            if let Some(slot) = info.innovation.get_mut(k) {
                *slot = v;
            }
            if let Some(slot) = info.innovation_var.get_mut(k) {
                *slot = s;
            }
            if let Some(slot) = info.r_diag.get_mut(k) {
                *slot = r;
            }
            if ratio.is_nan() || ratio > gate {
                self.velocity_rejected += 1;
                info.outlier = true;
                continue;
            }
            let lambda = if ratio > kappa { kappa / ratio } else { 1.0 };
            if lambda < 1.0 {
                info.outlier = true;
            }
            match self.filter.update_constraint(&h, z, r / (lambda * lambda)) {
                Ok(_) => {
                    self.velocity_applied += 1;
                    if let Some(slot) = info.lambda.get_mut(k) {
                        *slot = lambda;
                    }
                    info.nis += v * v / s;
                    info.dim += 1;
                }
                Err(_) => self.velocity_errors += 1,
            }
        }
        if measured == 0 {
            return None;
        }
        info.rejected = info.dim == 0;
        Some(info)
    }

    fn take_correction(&mut self) -> Delta {
        let x = self.filter.take_correction();
        let v = self.vertical.take().unwrap_or((0.0, 0.0));
        self.delta_from(&x, v)
    }

    fn pending_correction(&self) -> Delta {
        self.delta_from(self.filter.state(), self.vertical.unwrap_or((0.0, 0.0)))
    }

    fn aiding_scales(&self) -> Option<[(f64, f64); 2]> {
        Some(self.scales.scales())
    }

    fn pos_vel_cov(&self) -> [[f64; 6]; 6] {
        pos_vel_cov_of(self.filter.covariance())
    }

    fn covariance_snapshot(&self, out: &mut Vec<f64>) {
        let p = self.filter.covariance();
        out.clear();
        out.extend((0..14).flat_map(|i| (0..14).map(move |j| p[(i, j)])));
    }

    fn adaptive_snapshot(&self, out: &mut Vec<f64>) {
        self.filter.adaptive_state(out);
    }

    fn restore_adaptive(&mut self, s: &[f64]) -> bool {
        self.filter.restore_adaptive_state(s)
    }

    fn restore_covariance(&mut self, p: &[f64]) -> bool {
        if p.len() != 14 * 14 {
            return false;
        }
        let m = insuwb_filter::model::Mat14::from_fn(|i, j| p[i * 14 + j]);
        let _ = self.filter.take_correction();
        self.filter.reset(&m).is_ok()
    }

    fn reset(&mut self) {
        let _ = self.filter.take_correction();
        let _ = self.filter.reset(&self.p0);
        self.vertical = None;
        self.scales.break_baselines();
        self.acc_dt = 0.0;
        self.acc_ae = 0.0;
        self.acc_an = 0.0;
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::panic)]

    use insuwb_msg::Header;
    use nalgebra::{UnitQuaternion, Vector3};

    use super::*;
    use crate::config::{build_estimator, FusionConfig};

    const G: f64 = 9.80665;

    /// With a lever arm, a fix at the antenna (arm rotated by the heading)
    /// gives no innovation; without it, the arm is the innovation.
    #[test]
    fn the_lever_arm_moves_the_ins_to_the_antenna() {
        let yaw90 =
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, core::f64::consts::FRAC_PI_2));
        let ins = InsAt {
            t_ns: 1_000_000_000,
            pos_m: [1.0, 2.0, 0.0],
            vel_mps: [0.0; 3],
            quat: [yaw90.w, yaw90.i, yaw90.j, yaw90.k],
        };
        // Arm 0.5 m forward (body x); heading 90 deg: east is body y, so the
        // antenna is 0.5 m north of the IMU.
        let fix = UwbFix {
            header: Header::new(0, 1_000_000_000),
            pos_m: [1.0, 2.5, 0.0],
            ..UwbFix::default()
        };
        for (arm, want_n) in [([0.5, 0.0, 0.0], 0.0), ([0.0; 3], -0.5)] {
            let mut cfg = FusionConfig::default();
            cfg.loose.lever_arm_m = arm;
            cfg.loose.use_velocity = false;
            let mut e = build_estimator(FilterKind::Kf, &cfg).unwrap();
            let info = e.update_fix(&ins, &fix).unwrap();
            assert!(info.innovation[0].abs() < 1e-12, "{info:?}");
            assert!(
                (info.innovation[1] - want_n).abs() < 1e-12,
                "{arm:?}: {info:?}"
            );
        }
        let mut cfg = FusionConfig::default();
        cfg.loose.lever_arm_m = [0.0, 11.0, 0.0];
        assert!(build_estimator(FilterKind::Kf, &cfg).is_err());
    }

    /// A level, static vehicle seen by an INS tilted by `tilt`: the INS's
    /// horizontal acceleration error, turned into `d a`, maps back to `tilt`.
    #[test]
    fn tilt_feedback_inverts_the_ins_tilt_error() {
        let tilt = Vector3::new(0.01, -0.02, 0.0);
        let q_ins = UnitQuaternion::from_scaled_axis(tilt);
        let cfg = insuwb_nav::ins::InsConfig::default();
        let state = insuwb_nav::ins::InsState {
            att: q_ins,
            ..insuwb_nav::ins::InsState::default()
        };
        let mut ins = insuwb_nav::ins::Ins::new(cfg, state).unwrap();
        ins.step(0, [0.0, 0.0, G], [0.0; 3]).unwrap();
        let out = ins.step(1_000_000, [0.0, 0.0, G], [0.0; 3]).unwrap();
        // d a = a_true - a_ins = -a_ins (the vehicle is at rest).
        let [e, n] = tilt_from_accel_error(-out.accel_nav_mps2[0], -out.accel_nav_mps2[1], G);
        assert!(
            (e - tilt.x).abs() < 1e-5 && (n - tilt.y).abs() < 1e-5,
            "{e} {n}"
        );
        // Applying it as a correction levels the INS: q <- Exp(-d_att) q.
        let fixed = UnitQuaternion::from_scaled_axis(-Vector3::new(e, n, 0.0)) * q_ins;
        assert!(fixed.angle() < 1e-5, "{}", fixed.angle());
    }

    fn paper_with(loose: LooseConfig) -> PaperEstimator {
        let mut cfg = FusionConfig::default();
        cfg.model.bias_random_walk = Some(insuwb_filter::model::BiasRandomWalk {
            accel_var_m2_per_s4: 1e-4,
            gyro_var_rad2_per_s2: 1e-9,
        });
        let model = insuwb_filter::PaperModel::new(cfg.model.clone()).unwrap();
        let f = insuwb_filter::build(FilterKind::Kf, model, &cfg.filter, &cfg.setup).unwrap();
        PaperEstimator::new(f, loose, cfg.setup.p0()).with_gravity(G)
    }

    /// A 2 s IMU gap (an INS state 2 s after the last): the covariance grows
    /// as over ten 0.2 s intervals, none refused.
    #[test]
    fn a_long_interval_is_predicted_in_pieces() {
        let nav = NavState {
            quat: [1.0, 0.0, 0.0, 0.0],
            ..NavState::default()
        };
        let mut gap = paper_with(LooseConfig::default());
        gap.predict(2.0, &nav);
        gap.flush_predict();
        let mut steps = paper_with(LooseConfig::default());
        for _ in 0..10 {
            steps.predict(0.2, &nav);
        }
        steps.flush_predict();
        assert_eq!(gap.predict_errors(), 0);
        let (a, b) = (gap.pos_vel_cov(), steps.pos_vel_cov());
        for i in [0, 1, 3, 4] {
            assert!(a[i][i] > 0.0);
            assert!(
                (a[i][i] - b[i][i]).abs() <= 1e-9 * b[i][i],
                "{i}: {} vs {}",
                a[i][i],
                b[i][i]
            );
        }
        // The same interval flagged as an IMU gap: the velocity variance
        // grows by (GAP_ACCEL_MPS2 * 2 s)^2 more.
        let mut flagged = paper_with(LooseConfig::default());
        let mut gap_nav = nav;
        gap_nav.header.flags |= NavState::FLAG_GAP;
        flagged.predict(2.0, &gap_nav);
        flagged.flush_predict();
        let c = flagged.pos_vel_cov();
        let extra = (GAP_ACCEL_MPS2 * 2.0).powi(2);
        for i in [3, 4] {
            assert!(
                (c[i][i] - a[i][i] - extra).abs() < 1e-9 * extra,
                "{i}: {} vs {}",
                c[i][i],
                a[i][i]
            );
        }
        assert!(c[0][0] > a[0][0] + 0.5 * extra);
        // Beyond 100 pieces (20 s): refused and counted, as before.
        let mut long = paper_with(LooseConfig::default());
        long.predict(30.0, &nav);
        long.flush_predict();
        assert_eq!(long.predict_errors(), 1);
    }

    fn ins_at(pos_m: [f64; 3]) -> InsAt {
        InsAt {
            t_ns: 0,
            pos_m,
            vel_mps: [0.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
        }
    }

    fn fix(t_ns: u64, pos_m: [f64; 3], flags: u32) -> UwbFix {
        let mut header = Header::new(0, t_ns);
        header.flags = flags;
        UwbFix {
            header,
            pos_m,
            ..UwbFix::default()
        }
    }

    /// The random-walk acceleration states go back as a tilt (`tilt`) or as a
    /// body accelerometer bias (`bias`, default), never both.
    #[test]
    fn accel_feedback_modes() {
        for mode in [AccelFeedback::Tilt, AccelFeedback::Bias] {
            let mut e = paper_with(LooseConfig {
                accel_feedback: mode,
                use_velocity: false,
                ..LooseConfig::default()
            });
            let nav = NavState {
                quat: [1.0, 0.0, 0.0, 0.0],
                ..NavState::default()
            };
            for _ in 0..100 {
                e.predict(0.01, &nav);
            }
            e.update_fix(
                &ins_at([0.3, -0.2, 0.0]),
                &fix(0, [0.0; 3], UwbFix::FLAG_2D),
            )
            .unwrap();
            let x = *e.filter().state();
            assert!(x[5].abs() > 1e-6 && x[8].abs() > 1e-6, "{x:?}");
            let d = e.take_correction();
            let [te, tn] = tilt_from_accel_error(x[5], x[8], G);
            match mode {
                AccelFeedback::Tilt => {
                    assert_eq!(d.d_att_rad, [te, tn, x[4]]);
                    assert_eq!(d.d_accel_bias_mps2, [0.0; 3]);
                }
                AccelFeedback::Bias => {
                    assert_eq!(d.d_att_rad, [0.0, 0.0, x[4]]);
                    // Level and facing east: body = ENU, bias moves by -d a.
                    assert!((d.d_accel_bias_mps2[0] + x[5]).abs() < 1e-15);
                    assert!((d.d_accel_bias_mps2[1] + x[8]).abs() < 1e-15);
                }
            }
        }
    }

    /// `d_pos_z = 2 w T dz`, `d_vel_z = w^2 T dz`, T the time since the last fix.
    #[test]
    fn vertical_loop_known_answer() {
        let mut e = paper_with(LooseConfig {
            vertical_bandwidth_rps: 1.0,
            ..LooseConfig::default()
        });
        // First fix: T defaults to 0.1 s; INS 0.5 m above the fix.
        e.update_fix(
            &ins_at([0.0, 0.0, 1.5]),
            &fix(1_000_000_000, [0.0, 0.0, 1.0], 0),
        );
        let d = e.take_correction();
        assert!((d.d_pos_m[2] - 0.1).abs() < 1e-12 && (d.d_vel_mps[2] - 0.05).abs() < 1e-12);
        // 0.2 s later, 0.2 m above.
        e.update_fix(
            &ins_at([0.0, 0.0, 1.2]),
            &fix(1_200_000_000, [0.0, 0.0, 1.0], 0),
        );
        let d = e.take_correction();
        assert!((d.d_pos_m[2] - 0.08).abs() < 1e-12 && (d.d_vel_mps[2] - 0.04).abs() < 1e-12);
        // Taken once; 2D fixes carry no height.
        assert_eq!(e.take_correction().d_pos_m[2], 0.0);
        e.update_fix(
            &ins_at([0.0, 0.0, 3.0]),
            &fix(1_300_000_000, [0.0; 3], UwbFix::FLAG_2D),
        );
        assert_eq!(e.take_correction().d_pos_m[2], 0.0);
        // Off by default.
        let mut off = paper_with(LooseConfig::default());
        off.update_fix(&ins_at([0.0, 0.0, 1.5]), &fix(0, [0.0, 0.0, 1.0], 0));
        assert_eq!(off.take_correction().d_pos_m[2], 0.0);
    }

    /// With the range finder's height on, the vertical loop steers to the
    /// last range height while it is at most 0.5 s old, else to the fix's.
    #[test]
    fn the_vertical_loop_steers_to_a_recent_range_height() {
        let aiding = crate::aiding::height_aiding();
        let mut e = paper_with(LooseConfig {
            vertical_bandwidth_rps: 1.0,
            ..LooseConfig::default()
        })
        .with_aiding(&aiding);
        let range = Height {
            header: Header::new(0, 1_000_000_000),
            range_m: 1.2,
            source: Height::SOURCE_RANGE_FINDER,
        };
        assert!(e.update_height(&ins_at([0.0, 0.0, 1.5]), &range).is_none());
        // First fix (T 0.1 s), 0.1 s after the range: the INS 0.25 m above
        // the range's 1.25 m (the fix's 1.0 m is not the target).
        e.update_fix(
            &ins_at([0.0, 0.0, 1.5]),
            &fix(1_100_000_000, [0.0, 0.0, 1.0], 0),
        );
        let d = e.take_correction();
        assert!((d.d_pos_m[2] - 0.05).abs() < 1e-12, "{d:?}");
        assert!((d.d_vel_mps[2] - 0.025).abs() < 1e-12, "{d:?}");
        // 0.7 s after the range: the fix's height again (T 0.6 s).
        e.update_fix(
            &ins_at([0.0, 0.0, 1.2]),
            &fix(1_700_000_000, [0.0, 0.0, 1.0], 0),
        );
        let d = e.take_correction();
        assert!((d.d_pos_m[2] - 0.24).abs() < 1e-12, "{d:?}");
        // Height aiding off: the range is not a target.
        let mut off = paper_with(LooseConfig {
            vertical_bandwidth_rps: 1.0,
            ..LooseConfig::default()
        })
        .with_aiding(&AidingConfig::default());
        let _ = off.update_height(&ins_at([0.0, 0.0, 1.5]), &range);
        off.update_fix(
            &ins_at([0.0, 0.0, 1.5]),
            &fix(1_100_000_000, [0.0, 0.0, 1.0], 0),
        );
        assert!((off.take_correction().d_pos_m[2] - 0.1).abs() < 1e-12);
    }

    fn odometry(t_ns: u64, vel_mps: [f64; 3], sigma_mps: [f64; 3]) -> BodyVelocity {
        BodyVelocity {
            header: Header::new(0, t_ns),
            vel_mps,
            sigma_mps,
            source: BodyVelocity::SOURCE_ODOMETRY,
            range_mm: 0,
        }
    }

    /// A KF with the odometry's factor fixed at 1 (no scale uncertainty).
    fn kf_fixed_scale() -> PaperEstimator {
        let mut cfg = FusionConfig::default();
        cfg.aiding.odometry.prior_sigma = 0.0;
        let model = insuwb_filter::PaperModel::new(cfg.model.clone()).unwrap();
        let f = insuwb_filter::build(FilterKind::Kf, model, &cfg.filter, &cfg.setup).unwrap();
        PaperEstimator::new(f, LooseConfig::default(), cfg.setup.p0()).with_aiding(&cfg.aiding)
    }

    /// Facing north, the INS 1 m/s north and 0.2 m/s east; the wheels read
    /// 0.9 m/s forward and zero to the left (west): the INS is 0.1 m/s too
    /// fast north and 0.2 m/s east (the heading, far better known than the
    /// velocity, takes little of it). The estimate is held (pending) until
    /// taken, and an axis off by far more than its noise is rejected.
    #[test]
    fn a_body_velocity_updates_the_planar_error_state() {
        use insuwb_filter::model::idx;
        let yaw90 =
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, core::f64::consts::FRAC_PI_2));
        let ins = InsAt {
            t_ns: 1_000_000_000,
            pos_m: [0.0; 3],
            vel_mps: [0.2, 1.0, 0.0],
            quat: [yaw90.w, yaw90.i, yaw90.j, yaw90.k],
        };
        let mut e = kf_fixed_scale();
        let p_ve = e.filter().covariance()[(idx::VE, idx::VE)];
        let info = e
            .update_velocity(
                &ins,
                &odometry(1_000_000_000, [0.9, 0.0, 0.0], [0.01, 0.01, 0.0]),
            )
            .unwrap();
        assert_eq!(info.dim, 2);
        assert!(!info.rejected && !info.outlier, "{info:?}");
        // Innovations: forward 1.0 - 0.9, lateral (west) -0.2 - 0 (less
        // what the forward update moved).
        assert!((info.innovation[0] - 0.1).abs() < 1e-12, "{info:?}");
        assert!((info.innovation[1] + 0.2).abs() < 1e-3, "{info:?}");
        let gain = p_ve / (p_ve + 1e-4);
        let x = *e.filter().state();
        assert!((x[idx::VN] - 0.1 * gain).abs() < 3e-3, "{x:?}");
        assert!((x[idx::VE] - 0.2 * gain).abs() < 3e-3, "{x:?}");
        let pending = e.pending_correction();
        assert_eq!(pending.d_vel_mps[..2], [x[idx::VE], x[idx::VN]]);
        assert_eq!(e.take_correction(), pending);
        assert!(e.pending_correction().is_zero());
        // 100 m/s off: beyond the gate, nothing changes.
        let info = e
            .update_velocity(
                &ins,
                &odometry(1_010_000_000, [-99.0, 0.0, 0.0], [0.01, 0.0, 0.0]),
            )
            .unwrap();
        assert!(info.rejected && info.outlier && info.dim == 0, "{info:?}");
        assert!(e.pending_correction().is_zero());
        assert_eq!(e.velocity_counts(), (2, 1, 0));
        // The vertical axis alone: nothing this planar filter can use.
        assert!(e
            .update_velocity(&ins, &odometry(1_020_000_000, [0.0; 3], [0.0, 0.0, 0.1]))
            .is_none());
    }

    /// Driving east at 1 m/s with wheels that read 1.1: the odometry's
    /// displacement between fixes 2 m apart against the fixes' gives the
    /// factor, from a prior of 1 +- 0.1.
    #[test]
    fn the_odometry_scale_is_observed_on_baselines_between_fixes() {
        let mut cfg = FusionConfig::default();
        cfg.loose.use_velocity = false;
        let mut e = build_estimator(FilterKind::Kf, &cfg).unwrap();
        assert_eq!(e.aiding_scales().unwrap()[1], (1.0, 0.1));
        for k in 0..=1000u64 {
            // 100 Hz: odometry every sample, a fix every 10.
            let t_ns = k * 10_000_000;
            let x = k as f64 * 0.01;
            let ins = InsAt {
                t_ns,
                pos_m: [x, 0.0, 0.0],
                vel_mps: [1.0, 0.0, 0.0],
                quat: [1.0, 0.0, 0.0, 0.0],
            };
            let _ = e.update_velocity(&ins, &odometry(t_ns, [1.1, 0.0, 0.0], [0.01, 0.0, 0.0]));
            if k % 10 == 0 {
                let f = UwbFix {
                    header: Header::new(k, t_ns),
                    pos_m: [x, 0.0, 0.0],
                    pos_cov_m2: [[1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-4]],
                    ..UwbFix::default()
                };
                let _ = e.update_fix(&ins, &f);
            }
            let _ = e.take_correction();
        }
        let [flow, (scale, sigma)] = e.aiding_scales().unwrap();
        assert_eq!(flow, (1.0, 0.1));
        assert!((scale - 1.1).abs() < 0.005, "{scale} +- {sigma}");
        assert!(sigma < 0.01, "{sigma}");
    }

    #[test]
    fn loose_config_validation_names_the_key() {
        let bad = LooseConfig {
            vertical_bandwidth_rps: -1.0,
            ..LooseConfig::default()
        };
        let e = bad.validate().unwrap_err();
        assert_eq!(
            e.to_string(),
            "loose.vertical_bandwidth_rps must be in [0, 10] rad/s, got -1"
        );
        let cfg = FusionConfig {
            loose: bad,
            ..FusionConfig::default()
        };
        assert!(build_estimator(FilterKind::Iakf, &cfg).is_err());
        let c: LooseConfig = toml::from_str("accel_feedback = \"tilt\"").unwrap();
        assert_eq!(c.accel_feedback, AccelFeedback::Tilt);
        assert!(c.use_velocity);
        for (c, key) in [
            (
                LooseConfig {
                    velocity_kappa: 0.0,
                    ..LooseConfig::default()
                },
                "loose.velocity_kappa",
            ),
            (
                LooseConfig {
                    velocity_gate_sigma: 2.0,
                    ..LooseConfig::default()
                },
                "loose.velocity_gate_sigma",
            ),
            (
                LooseConfig {
                    scale_baseline_m: f64::NAN,
                    ..LooseConfig::default()
                },
                "loose.scale_baseline_m",
            ),
        ] {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.starts_with(key), "{e}");
        }
    }
}
