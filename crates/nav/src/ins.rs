//! Strapdown INS mechanisation: owns the navigation state (position, velocity,
//! attitude, sensor-bias estimates) and its propagation by IMU samples.
//!
//! Model: full 3D, ENU navigation frame, **flat earth** for indoor use: no
//! earth rotation rate, no transport rate, constant gravity `[0, 0, -g]` with
//! `g` from [`InsConfig::gravity_mps2`] (default 9.80665 m/s^2, the standard
//! value; a real log may override it with the local value or the static
//! specific-force norm of its own accelerometer).
//!
//! One [`Ins::step`] integrates from the previous sample time to the new one
//! with the bias-compensated samples at both ends:
//! - attitude: `q1 = q0 * Exp(phi)`, the exact rotation-vector exponential
//!   (the paper's quaternion method), with
//!   `phi = (w0 + w1)/2 * dt + (w0*dt x w1*dt)/12` (trapezoidal rate plus the
//!   two-sample coning term, exact for a rate that is constant or varies
//!   linearly about a fixed axis);
//! - velocity: trapezoid of the specific force rotated to ENU at both ends,
//!   `v1 = v0 + ((q0 f0 + q1 f1)/2 - [0,0,g]) dt` (no further sculling term);
//! - position: trapezoid of the velocity, `p1 = p0 + (v0 + v1)/2 dt`, exact for
//!   constant acceleration.
//!
//! Gaps: a step longer than [`InsConfig::max_step_s`] (an IMU dropout) is not
//! extrapolated from two samples: attitude and velocity integrate the IMU over
//! `max_step_s` only, and position then coasts at the new velocity for the
//! rest of the gap. The cost of a step is therefore bounded, whatever the gap,
//! and the output says so ([`NavOutput::gap_clamped`]).
//!
//! Sensor model: `accel_meas = f_true + accel_bias`, `gyro_meas = w_true +
//! gyro_bias`; the INS subtracts its bias estimates from each sample.
//!
//! Everything is fixed-size (`nalgebra` `Vector3`/`UnitQuaternion`); a step
//! does not allocate.

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::vehicle::{thrust_drag_force, Mechanisation};

/// Standard gravity, m/s^2 (the default of [`InsConfig::gravity_mps2`]).
pub const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;

/// Configuration of the INS mechanisation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InsConfig {
    /// Gravity magnitude, m/s^2. Default 9.80665 (standard gravity); a real
    /// log may set the local value or its accelerometer's static norm.
    /// Valid range [9.0, 10.6].
    pub gravity_mps2: f64,
    /// Largest interval integrated from the IMU in one step, s. A longer gap
    /// (dropout) integrates attitude and velocity over this much and coasts
    /// position for the rest. Default 0.05 s (5 samples at 100 Hz, 50 at
    /// 1 kHz: longer is a dropout). Valid range (0, 1].
    pub max_step_s: f64,
    /// The vehicle model integrated ([`crate::vehicle`]); set from the
    /// fusion settings' `vehicle`, not from this table. Default free.
    #[serde(skip)]
    pub mechanisation: Mechanisation,
}

impl Default for InsConfig {
    fn default() -> Self {
        Self {
            gravity_mps2: STANDARD_GRAVITY_MPS2,
            max_step_s: 0.05,
            mechanisation: Mechanisation::Free,
        }
    }
}

/// Why an [`InsConfig`] was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum InsConfigError {
    /// `gravity_mps2` is outside [9.0, 10.6] or not finite.
    #[error("ins.gravity_mps2 must be in [9.0, 10.6] m/s^2, got {0}")]
    Gravity(f64),
    /// `max_step_s` is outside (0, 1] or not finite.
    #[error("ins.max_step_s must be in (0, 1] s, got {0}")]
    MaxStep(f64),
    /// The multirotor drag coefficient is negative, not finite or above 10/s.
    #[error("multirotor.drag_per_s must be finite and in [0, 10] 1/s, got {0}")]
    Drag(f64),
}

impl InsConfig {
    /// Check every field against its documented range.
    ///
    /// # Errors
    /// The first field out of range, with its value.
    pub fn validate(&self) -> Result<(), InsConfigError> {
        if !(9.0..=10.6).contains(&self.gravity_mps2) {
            return Err(InsConfigError::Gravity(self.gravity_mps2));
        }
        if !(self.max_step_s > 0.0 && self.max_step_s <= 1.0) {
            return Err(InsConfigError::MaxStep(self.max_step_s));
        }
        if let Mechanisation::ThrustDrag { drag_per_s } = self.mechanisation {
            if !(drag_per_s.is_finite() && (0.0..=10.0).contains(&drag_per_s)) {
                return Err(InsConfigError::Drag(drag_per_s));
            }
        }
        Ok(())
    }
}

/// The INS navigation state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsState {
    /// Position, ENU, m.
    pub pos_m: Vector3<f64>,
    /// Velocity, ENU, m/s.
    pub vel_mps: Vector3<f64>,
    /// Attitude, body (FLU) to ENU.
    pub att: UnitQuaternion<f64>,
    /// Accelerometer bias estimate (body), m/s^2, subtracted from each sample.
    pub accel_bias_mps2: Vector3<f64>,
    /// Gyro bias estimate (body), rad/s, subtracted from each sample.
    pub gyro_bias_rps: Vector3<f64>,
    /// Time of the state, ns.
    pub t_ns: u64,
}

impl Default for InsState {
    /// At the origin, at rest, level and facing east, zero biases, time 0.
    fn default() -> Self {
        Self {
            pos_m: Vector3::zeros(),
            vel_mps: Vector3::zeros(),
            att: UnitQuaternion::identity(),
            accel_bias_mps2: Vector3::zeros(),
            gyro_bias_rps: Vector3::zeros(),
            t_ns: 0,
        }
    }
}

/// Why an [`InsState`] was refused (by [`Ins::new`] or [`Ins::reset`]).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum InsStateError {
    /// A field holds a NaN or an infinity.
    #[error("INS state field {field}[{index}] is not finite: {value}")]
    NonFinite {
        /// Field name.
        field: &'static str,
        /// Component index.
        index: usize,
        /// Offending value.
        value: f64,
    },
    /// The attitude quaternion is not of unit norm (|q| - 1 beyond 1e-6).
    #[error("INS state attitude quaternion has norm {0}, expected 1")]
    NotUnit(f64),
}

/// Why [`Ins::new`] failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum InsNewError {
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] InsConfigError),
    /// The initial state is invalid.
    #[error(transparent)]
    State(#[from] InsStateError),
}

/// Why [`Ins::step`] refused a sample; the INS state is unchanged.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum InsStepError {
    /// A component of the sample is NaN or infinite.
    #[error("IMU sample {field}[{index}] is not finite: {value}")]
    NonFinite {
        /// `accel_b` or `gyro_b`.
        field: &'static str,
        /// Component index.
        index: usize,
        /// Offending value.
        value: f64,
    },
    /// The sample time does not come after the previous one (repeated or backwards).
    #[error(
        "IMU sample time {t_ns} ns does not come after the previous sample time {prev_t_ns} ns"
    )]
    TimeNotIncreasing {
        /// Time of the refused sample, ns.
        t_ns: u64,
        /// Time of the state, ns.
        prev_t_ns: u64,
    },
}

/// Why [`Ins::apply_correction`] refused a correction; the state is unchanged.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CorrectionError {
    /// A component of the correction is NaN or infinite.
    #[error("INS correction {field}[{index}] is not finite: {value}")]
    NonFinite {
        /// Argument name.
        field: &'static str,
        /// Component index.
        index: usize,
        /// Offending value.
        value: f64,
    },
}

/// What the INS gives for one sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NavOutput {
    /// Time of the state, ns.
    pub t_ns: u64,
    /// Position, ENU, m.
    pub pos_m: [f64; 3],
    /// Velocity, ENU, m/s.
    pub vel_mps: [f64; 3],
    /// Attitude `[w, x, y, z]`, body to ENU.
    pub quat: [f64; 4],
    /// Heading, rad, counter-clockwise from east: `atan2` of the body x axis in ENU.
    pub yaw_rad: f64,
    /// Kinematic acceleration in ENU at the sample (bias compensated, gravity
    /// removed): the paper's `a_e, a_n` (and `a_u`), m/s^2.
    pub accel_nav_mps2: [f64; 3],
    /// Bias-compensated body rate rotated to ENU; its z is the paper's omega, rad/s.
    pub omega_nav_rps: [f64; 3],
    /// Accelerometer bias estimate (body), m/s^2.
    pub accel_bias_mps2: [f64; 3],
    /// Gyro bias estimate (body), rad/s.
    pub gyro_bias_rps: [f64; 3],
    /// Time since the previous sample, s (0 on the first sample).
    pub dt_s: f64,
    /// The step was longer than `max_step_s` and was clamped (IMU dropout).
    pub gap_clamped: bool,
}

/// Raw IMU input of the last accepted sample.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ImuInput {
    accel_b: Vector3<f64>,
    gyro_b: Vector3<f64>,
}

/// Strapdown INS (see the module documentation for the model).
#[derive(Debug, Clone, PartialEq)]
pub struct Ins {
    cfg: InsConfig,
    state: InsState,
    prev: Option<ImuInput>,
    last_dt_s: f64,
    last_gap_clamped: bool,
}

/// Heading of an attitude, rad, counter-clockwise from east: `atan2` of the
/// body x axis expressed in ENU (the Euler ZYX yaw).
#[must_use]
pub fn yaw_of(att: &UnitQuaternion<f64>) -> f64 {
    let x_enu = att * Vector3::x();
    x_enu.y.atan2(x_enu.x)
}

/// `Exp` of a rotation vector (rad) as a unit quaternion, exact at any angle.
fn exp_rotvec(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let angle_sq = phi.norm_squared();
    let angle = angle_sq.sqrt();
    let half = 0.5 * angle;
    // sin(a/2)/a, by its series where a is tiny (the error is below 1e-30 there).
    let s = if angle < 1e-6 {
        0.5 - angle_sq / 48.0
    } else {
        half.sin() / angle
    };
    UnitQuaternion::new_unchecked(Quaternion::new(half.cos(), phi.x * s, phi.y * s, phi.z * s))
}

fn check_finite<E>(
    v: &[f64; 3],
    field: &'static str,
    err: impl Fn(&'static str, usize, f64) -> E,
) -> Result<(), E> {
    for (index, &value) in v.iter().enumerate() {
        if !value.is_finite() {
            return Err(err(field, index, value));
        }
    }
    Ok(())
}

fn validate_state(s: &InsState) -> Result<(), InsStateError> {
    let err = |field, index, value| InsStateError::NonFinite {
        field,
        index,
        value,
    };
    check_finite(&s.pos_m.into(), "pos_m", err)?;
    check_finite(&s.vel_mps.into(), "vel_mps", err)?;
    check_finite(&s.accel_bias_mps2.into(), "accel_bias_mps2", err)?;
    check_finite(&s.gyro_bias_rps.into(), "gyro_bias_rps", err)?;
    let q = s.att.quaternion();
    for (index, &value) in [q.w, q.i, q.j, q.k].iter().enumerate() {
        if !value.is_finite() {
            return Err(err("att", index, value));
        }
    }
    let n = q.norm();
    if (n - 1.0).abs() > 1e-6 {
        return Err(InsStateError::NotUnit(n));
    }
    Ok(())
}

impl Ins {
    /// An INS with a validated configuration, starting from `init`.
    ///
    /// The first [`Ins::step`] only sets the time (and remembers the sample).
    ///
    /// # Errors
    /// An invalid configuration or a non-finite / non-unit initial state.
    pub fn new(cfg: InsConfig, init: InsState) -> Result<Self, InsNewError> {
        cfg.validate()?;
        validate_state(&init)?;
        let mut state = init;
        state.att.renormalize();
        Ok(Self {
            cfg,
            state,
            prev: None,
            last_dt_s: 0.0,
            last_gap_clamped: false,
        })
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &InsConfig {
        &self.cfg
    }

    /// Integrates from the next sample on with `mechanisation` (a vehicle
    /// model chosen at run time, [`crate::vehicle::HorizontalSignal`]).
    ///
    /// # Errors
    /// A drag coefficient out of range; the INS is then unchanged.
    pub fn set_mechanisation(
        &mut self,
        mechanisation: Mechanisation,
    ) -> Result<(), InsConfigError> {
        let cfg = InsConfig {
            mechanisation,
            ..self.cfg.clone()
        };
        cfg.validate()?;
        self.cfg = cfg;
        Ok(())
    }

    /// The current state.
    #[must_use]
    pub fn state(&self) -> &InsState {
        &self.state
    }

    /// Whether a sample has been seen (a step integrates rather than only setting the time).
    #[must_use]
    pub fn is_started(&self) -> bool {
        self.prev.is_some()
    }

    /// Integrate the IMU sample taken at `t_ns` (specific force `accel_b`,
    /// m/s^2, and rate `gyro_b`, rad/s, both raw, in the body frame) from the
    /// previous sample time. The first call only sets the time.
    ///
    /// # Errors
    /// A non-finite component, or `t_ns` not after the previous sample time;
    /// the state is then unchanged.
    pub fn step(
        &mut self,
        t_ns: u64,
        accel_b: [f64; 3],
        gyro_b: [f64; 3],
    ) -> Result<NavOutput, InsStepError> {
        let err = |field, index, value| InsStepError::NonFinite {
            field,
            index,
            value,
        };
        check_finite(&accel_b, "accel_b", err)?;
        check_finite(&gyro_b, "gyro_b", err)?;
        let cur = ImuInput {
            accel_b: Vector3::from(accel_b),
            gyro_b: Vector3::from(gyro_b),
        };
        let Some(prev) = self.prev else {
            self.prev = Some(cur);
            self.state.t_ns = t_ns;
            self.last_dt_s = 0.0;
            self.last_gap_clamped = false;
            return Ok(self.output());
        };
        if t_ns <= self.state.t_ns {
            return Err(InsStepError::TimeNotIncreasing {
                t_ns,
                prev_t_ns: self.state.t_ns,
            });
        }
        // u64 difference to f64: exact below 2^53 ns (104 days).
        let dt_s = (t_ns - self.state.t_ns) as f64 * 1e-9;
        let gap_clamped = dt_s > self.cfg.max_step_s;
        let dt_imu_s = if gap_clamped {
            self.cfg.max_step_s
        } else {
            dt_s
        };

        let s = &mut self.state;
        let mut f0 = prev.accel_b - s.accel_bias_mps2;
        let mut f1 = cur.accel_b - s.accel_bias_mps2;
        let w0 = prev.gyro_b - s.gyro_bias_rps;
        let w1 = cur.gyro_b - s.gyro_bias_rps;

        // Attitude: trapezoidal rotation vector plus the two-sample coning term.
        let a0 = w0 * dt_imu_s;
        let a1 = w1 * dt_imu_s;
        let phi = (a0 + a1) * 0.5 + a0.cross(&a1) / 12.0;
        let q0 = s.att;
        let mut q1 = q0 * exp_rotvec(&phi);
        q1.renormalize();
        if let Mechanisation::ThrustDrag { drag_per_s } = self.cfg.mechanisation {
            // Drag at the start of the step's velocity (explicit: the drag
            // time constant, seconds, is far longer than a step).
            f0 = thrust_drag_force(&f0, &q0, &s.vel_mps, drag_per_s);
            f1 = thrust_drag_force(&f1, &q1, &s.vel_mps, drag_per_s);
        }

        // Velocity: trapezoid of the ENU specific force, minus gravity.
        let g = Vector3::new(0.0, 0.0, self.cfg.gravity_mps2);
        let acc = (q0 * f0 + q1 * f1) * 0.5 - g;
        let v0 = s.vel_mps;
        let v1 = v0 + acc * dt_imu_s;

        // Position: trapezoid of the velocity, then coast through any gap.
        s.pos_m += (v0 + v1) * (0.5 * dt_imu_s) + v1 * (dt_s - dt_imu_s);
        s.vel_mps = v1;
        s.att = q1;
        s.t_ns = t_ns;
        self.prev = Some(cur);
        self.last_dt_s = dt_s;
        self.last_gap_clamped = gap_clamped;
        Ok(self.output())
    }

    /// The output for the current state and the last sample (kinematic
    /// acceleration and ENU rate use the current attitude and bias estimates;
    /// they are zero before the first sample).
    #[must_use]
    pub fn output(&self) -> NavOutput {
        let s = &self.state;
        let (accel_nav, omega_nav) = match self.prev {
            Some(p) => (
                s.att * (p.accel_b - s.accel_bias_mps2)
                    - Vector3::new(0.0, 0.0, self.cfg.gravity_mps2),
                s.att * (p.gyro_b - s.gyro_bias_rps),
            ),
            None => (Vector3::zeros(), Vector3::zeros()),
        };
        let q = s.att.quaternion();
        NavOutput {
            t_ns: s.t_ns,
            pos_m: s.pos_m.into(),
            vel_mps: s.vel_mps.into(),
            quat: [q.w, q.i, q.j, q.k],
            yaw_rad: yaw_of(&s.att),
            accel_nav_mps2: accel_nav.into(),
            omega_nav_rps: omega_nav.into(),
            accel_bias_mps2: s.accel_bias_mps2.into(),
            gyro_bias_rps: s.gyro_bias_rps.into(),
            dt_s: self.last_dt_s,
            gap_clamped: self.last_gap_clamped,
        }
    }

    /// Fold an error estimate into the state, convention "error = INS minus truth":
    /// - `pos -= d_pos_m`, `vel -= d_vel_mps` (ENU);
    /// - attitude: the INS attitude is taken as rotated by the small ENU-frame
    ///   rotation vector `d_att_rad` from the truth, `q_ins = Exp(d_att) q_true`,
    ///   so `q <- Exp(-d_att) q` (a heading error `dtheta` is `d_att = [0, 0, dtheta]`:
    ///   INS yaw minus true yaw);
    /// - bias estimates are incremented: `accel_bias += d_accel_bias_mps2`,
    ///   `gyro_bias += d_gyro_bias_rps` (body frame).
    ///
    /// # Errors
    /// A non-finite component; the state is then unchanged.
    pub fn apply_correction(
        &mut self,
        d_pos_m: [f64; 3],
        d_vel_mps: [f64; 3],
        d_att_rad: [f64; 3],
        d_accel_bias_mps2: [f64; 3],
        d_gyro_bias_rps: [f64; 3],
    ) -> Result<(), CorrectionError> {
        let err = |field, index, value| CorrectionError::NonFinite {
            field,
            index,
            value,
        };
        check_finite(&d_pos_m, "d_pos_m", err)?;
        check_finite(&d_vel_mps, "d_vel_mps", err)?;
        check_finite(&d_att_rad, "d_att_rad", err)?;
        check_finite(&d_accel_bias_mps2, "d_accel_bias_mps2", err)?;
        check_finite(&d_gyro_bias_rps, "d_gyro_bias_rps", err)?;
        let s = &mut self.state;
        s.pos_m -= Vector3::from(d_pos_m);
        s.vel_mps -= Vector3::from(d_vel_mps);
        let mut q = exp_rotvec(&-Vector3::from(d_att_rad)) * s.att;
        q.renormalize();
        s.att = q;
        s.accel_bias_mps2 += Vector3::from(d_accel_bias_mps2);
        s.gyro_bias_rps += Vector3::from(d_gyro_bias_rps);
        Ok(())
    }

    /// Replace the state (a re-initialisation from a fused solution).
    ///
    /// The next [`Ins::step`] integrates from `state.t_ns`, taking the last
    /// sample seen as the input at the start of the interval; before any
    /// sample it only sets the time.
    ///
    /// # Errors
    /// A non-finite or non-unit state; the INS is then unchanged.
    pub fn reset(&mut self, state: InsState) -> Result<(), InsStateError> {
        validate_state(&state)?;
        self.state = state;
        self.state.att.renormalize();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    const G: f64 = STANDARD_GRAVITY_MPS2;

    fn ins_at(att: UnitQuaternion<f64>) -> Ins {
        Ins::new(
            InsConfig::default(),
            InsState {
                att,
                ..InsState::default()
            },
        )
        .unwrap()
    }

    fn arr(v: Vector3<f64>) -> [f64; 3] {
        v.into()
    }

    /// Run `n + 1` samples at `dt_ns` starting at t = 0 with constant inputs.
    fn run_const(ins: &mut Ins, n: u64, dt_ns: u64, f_b: [f64; 3], w_b: [f64; 3]) -> NavOutput {
        let mut out = ins.step(0, f_b, w_b).unwrap();
        for k in 1..=n {
            out = ins.step(k * dt_ns, f_b, w_b).unwrap();
        }
        out
    }

    #[test]
    fn stationary_level_stays_put_for_10_s() {
        let mut ins = ins_at(UnitQuaternion::identity());
        let out = run_const(&mut ins, 10_000, 1_000_000, [0.0, 0.0, G], [0.0; 3]);
        assert_eq!(out.t_ns, 10_000_000_000);
        for i in 0..3 {
            assert!(out.pos_m[i].abs() < 1e-9, "{:?}", out.pos_m);
            assert!(out.vel_mps[i].abs() < 1e-9, "{:?}", out.vel_mps);
            assert!(out.accel_nav_mps2[i].abs() < 1e-12);
        }
        assert_eq!(out.quat, [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn stationary_rolled_30_deg_has_zero_velocity() {
        let att = UnitQuaternion::from_euler_angles(30f64.to_radians(), 0.0, 0.7);
        let f_b = att.inverse() * Vector3::new(0.0, 0.0, G);
        // Hand check of the specific force of a 30 deg roll: g*[0, sin30, cos30].
        assert!((f_b - Vector3::new(0.0, 0.5 * G, 0.75f64.sqrt() * G)).norm() < 1e-12);
        let mut ins = ins_at(att);
        let out = run_const(&mut ins, 10_000, 1_000_000, arr(f_b), [0.0; 3]);
        for i in 0..3 {
            assert!(out.vel_mps[i].abs() < 1e-9, "{:?}", out.vel_mps);
            assert!(out.pos_m[i].abs() < 1e-9, "{:?}", out.pos_m);
        }
        assert!((out.yaw_rad - 0.7).abs() < 1e-12);
    }

    #[test]
    fn constant_yaw_rate_gives_one_radian_in_10_s() {
        let mut ins = ins_at(UnitQuaternion::identity());
        let out = run_const(&mut ins, 1000, 10_000_000, [0.0, 0.0, G], [0.0, 0.0, 0.1]);
        assert!((out.yaw_rad - 1.0).abs() < 1e-9, "yaw {}", out.yaw_rad);
        let expect = UnitQuaternion::from_euler_angles(0.0, 0.0, 1.0);
        assert!(ins.state().att.angle_to(&expect) < 1e-9);
        assert!((out.omega_nav_rps[2] - 0.1).abs() < 1e-12);
        for i in 0..3 {
            assert!(out.pos_m[i].abs() < 1e-9);
        }
    }

    #[test]
    fn linearly_increasing_yaw_rate_is_integrated_by_the_trapezoid() {
        // w(t) = alpha t about z: yaw = alpha t^2 / 2 = 1.0 rad at t = 10 s.
        // A rectangle rule would be off by alpha*t*dt/2 = 1e-3 rad.
        let alpha = 0.02;
        let mut ins = ins_at(UnitQuaternion::identity());
        let dt_ns = 10_000_000u64;
        let mut out = ins.step(0, [0.0, 0.0, G], [0.0; 3]).unwrap();
        for k in 1..=1000u64 {
            let t = k as f64 * 0.01;
            out = ins
                .step(k * dt_ns, [0.0, 0.0, G], [0.0, 0.0, alpha * t])
                .unwrap();
        }
        assert!((out.yaw_rad - 1.0).abs() < 1e-9, "yaw {}", out.yaw_rad);
    }

    #[test]
    fn constant_body_rate_about_a_tilted_axis_matches_the_exponential() {
        // q(t) = q0 * Exp(w_b t): checks the body-frame (right) multiplication.
        let q0 = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let w_b = Vector3::new(0.1, 0.2, -0.3);
        let mut ins = ins_at(q0);
        run_const(&mut ins, 1000, 10_000_000, [0.0, 0.0, G], arr(w_b));
        let expect = q0 * UnitQuaternion::from_scaled_axis(w_b * 10.0);
        let got = ins.state().att;
        assert!(got.angle_to(&expect) < 1e-9, "{}", got.angle_to(&expect));
    }

    #[test]
    fn constant_enu_acceleration_in_a_tilted_body() {
        let att = UnitQuaternion::from_euler_angles(10f64.to_radians(), -20f64.to_radians(), 0.7);
        let a = Vector3::new(0.3, -0.2, 0.1);
        let f_b = att.inverse() * (a + Vector3::new(0.0, 0.0, G));
        let mut ins = ins_at(att);
        // 5 s at 100 Hz.
        let out = run_const(&mut ins, 500, 10_000_000, arr(f_b), [0.0; 3]);
        let p = a * 12.5; // 0.5 a t^2, t = 5
        let v = a * 5.0;
        for i in 0..3 {
            assert!(
                (out.pos_m[i] - p[i]).abs() < 1e-6,
                "{:?} vs {p:?}",
                out.pos_m
            );
            assert!((out.vel_mps[i] - v[i]).abs() < 1e-9);
            assert!((out.accel_nav_mps2[i] - a[i]).abs() < 1e-12);
        }
        // Hand values: p = [3.75, -2.5, 1.25] m.
        assert!((out.pos_m[0] - 3.75).abs() < 1e-6 && (out.pos_m[1] + 2.5).abs() < 1e-6);
    }

    #[test]
    fn turning_body_with_constant_body_thrust_follows_the_analytic_path() {
        // Level body turning at w about z with a constant forward specific
        // force c: a(t) = c [cos wt, sin wt, 0], v = (c/w) [sin wt, 1 - cos wt],
        // p = (c/w) [(1 - cos wt)/w, t - sin(wt)/w]. Trapezoid error is
        // O(dt^2) (~1e-5); using only one end of the step would be ~c dt/2 = 5e-3.
        let (c, w) = (1.0, 0.5);
        let mut ins = ins_at(UnitQuaternion::identity());
        let out = run_const(&mut ins, 1000, 10_000_000, [c, 0.0, G], [0.0, 0.0, w]);
        let t = 10.0f64;
        let (s, co) = (w * t).sin_cos();
        let v = [c / w * s, c / w * (1.0 - co)];
        let p = [c / w * (1.0 - co) / w, c / w * (t - s / w)];
        for i in 0..2 {
            assert!(
                (out.vel_mps[i] - v[i]).abs() < 1e-4,
                "{:?} vs {v:?}",
                out.vel_mps
            );
            assert!(
                (out.pos_m[i] - p[i]).abs() < 1e-3,
                "{:?} vs {p:?}",
                out.pos_m
            );
        }
        assert!(out.vel_mps[2].abs() < 1e-12 && out.pos_m[2].abs() < 1e-12);
    }

    #[test]
    fn coning_term_makes_a_linear_rate_about_a_moving_axis_exact() {
        // w_b(t) = [0.5, 0.6 t, -0.2]: the axis moves, so the rotation vector is
        // not the rate integral. At 100 Hz the two-sample coning term matches a
        // 100 kHz reference to ~1e-11 rad; without it the error is ~5e-6 rad.
        let rate = |t: f64| [0.5, 0.6 * t, -0.2];
        let run = |hz: u64| {
            let mut ins = ins_at(UnitQuaternion::identity());
            let dt_ns = 1_000_000_000 / hz;
            for k in 0..=2 * hz {
                ins.step(k * dt_ns, [0.0, 0.0, G], rate((k * dt_ns) as f64 * 1e-9))
                    .unwrap();
            }
            ins.state().att
        };
        let err = run(100).angle_to(&run(100_000));
        assert!(err < 1e-9, "{err}");
    }

    #[test]
    fn yaw_and_enu_rate_conventions() {
        // Body x pointing north: yaw +pi/2 (counter-clockwise from east).
        let att = UnitQuaternion::from_euler_angles(0.0, 0.0, PI / 2.0);
        assert!((yaw_of(&att) - PI / 2.0).abs() < 1e-12);
        // Level, yaw 90 deg: a rate about body x is a rate about north (ENU y).
        let mut ins = ins_at(att);
        let out = ins.step(0, [0.0, 0.0, G], [0.2, 0.0, 0.0]).unwrap();
        assert!((out.omega_nav_rps[0]).abs() < 1e-12 && (out.omega_nav_rps[1] - 0.2).abs() < 1e-12);
        let q = out.quat;
        let h = (0.5f64).sqrt();
        assert!(
            (q[0] - h).abs() < 1e-12 && (q[3] - h).abs() < 1e-12,
            "{q:?}"
        );
    }

    #[test]
    fn refuses_bad_samples_and_keeps_state() {
        let mut ins = ins_at(UnitQuaternion::identity());
        ins.step(1_000, [0.0, 0.0, G], [0.0; 3]).unwrap();
        ins.step(2_000, [0.1, 0.0, G], [0.0; 3]).unwrap();
        let before = ins.clone();
        assert_eq!(
            ins.step(2_000, [0.0, 0.0, G], [0.0; 3]),
            Err(InsStepError::TimeNotIncreasing {
                t_ns: 2_000,
                prev_t_ns: 2_000
            })
        );
        assert!(ins.step(1_500, [0.0, 0.0, G], [0.0; 3]).is_err());
        let e = ins.step(3_000, [0.0, f64::NAN, G], [0.0; 3]).unwrap_err();
        assert!(matches!(
            e,
            InsStepError::NonFinite {
                field: "accel_b",
                index: 1,
                ..
            }
        ));
        assert!(e.to_string().contains("accel_b[1]"), "{e}");
        assert!(ins
            .step(3_000, [0.0, 0.0, G], [f64::INFINITY, 0.0, 0.0])
            .is_err());
        assert_eq!(ins, before);
    }

    #[test]
    fn first_step_only_sets_time() {
        let mut ins = Ins::new(
            InsConfig::default(),
            InsState {
                vel_mps: Vector3::new(1.0, 0.0, 0.0),
                t_ns: 5,
                ..InsState::default()
            },
        )
        .unwrap();
        let out = ins
            .step(1_000_000_000, [3.0, 0.0, G], [0.0, 0.0, 1.0])
            .unwrap();
        assert_eq!(out.t_ns, 1_000_000_000);
        assert_eq!(out.pos_m, [0.0; 3]);
        assert_eq!(out.dt_s, 0.0);
        assert!((out.accel_nav_mps2[0] - 3.0).abs() < 1e-12);
    }

    #[test]
    fn gap_integrates_imu_over_max_step_and_coasts_position() {
        let mut ins = Ins::new(
            InsConfig::default(),
            InsState {
                vel_mps: Vector3::new(1.0, 0.0, 0.0),
                ..InsState::default()
            },
        )
        .unwrap();
        ins.step(0, [0.0, 0.0, G], [0.0, 0.0, 0.1]).unwrap();
        // A 1 s dropout.
        let out = ins
            .step(1_000_000_000, [0.0, 0.0, G], [0.0, 0.0, 0.1])
            .unwrap();
        assert!(out.gap_clamped);
        assert!((out.dt_s - 1.0).abs() < 1e-15);
        // Yaw advances by 0.1 rad/s * 0.05 s only; position coasts at 1 m/s.
        assert!((out.yaw_rad - 0.005).abs() < 1e-12, "{}", out.yaw_rad);
        assert!((out.pos_m[0] - 1.0).abs() < 1e-12, "{:?}", out.pos_m);
        // With acceleration: v = 1 + 0.2*0.05 = 1.01; p = (1 + 1.01)/2*0.05 + 1.01*0.95.
        let mut ins = Ins::new(
            InsConfig::default(),
            InsState {
                vel_mps: Vector3::new(1.0, 0.0, 0.0),
                ..InsState::default()
            },
        )
        .unwrap();
        ins.step(0, [0.2, 0.0, G], [0.0; 3]).unwrap();
        let out = ins.step(1_000_000_000, [0.2, 0.0, G], [0.0; 3]).unwrap();
        assert!((out.vel_mps[0] - 1.01).abs() < 1e-12);
        assert!((out.pos_m[0] - (1.005 * 0.05 + 1.01 * 0.95)).abs() < 1e-12);
    }

    #[test]
    fn correction_brings_a_perturbed_ins_back_to_truth() {
        let truth = InsState {
            pos_m: Vector3::new(1.0, 2.0, 0.5),
            vel_mps: Vector3::new(0.3, -0.1, 0.0),
            att: UnitQuaternion::from_euler_angles(0.1, -0.05, 2.0),
            accel_bias_mps2: Vector3::new(0.05, -0.02, 0.1),
            gyro_bias_rps: Vector3::new(0.001, 0.002, -0.003),
            t_ns: 0,
        };
        let d_pos = Vector3::new(0.4, -0.3, 0.1);
        let d_vel = Vector3::new(-0.2, 0.1, 0.05);
        let d_att = Vector3::new(0.01, -0.02, 0.05);
        let d_ba = Vector3::new(0.01, 0.02, -0.03);
        let d_bg = Vector3::new(-0.001, 0.0005, 0.002);
        // INS = truth + error; its bias estimates lack the increments.
        let perturbed = InsState {
            pos_m: truth.pos_m + d_pos,
            vel_mps: truth.vel_mps + d_vel,
            att: UnitQuaternion::from_scaled_axis(d_att) * truth.att,
            accel_bias_mps2: truth.accel_bias_mps2 - d_ba,
            gyro_bias_rps: truth.gyro_bias_rps - d_bg,
            t_ns: 0,
        };
        let mut ins = Ins::new(InsConfig::default(), perturbed).unwrap();
        // A pure heading error: INS yaw is truth yaw + 0.05.
        assert!((yaw_of(&perturbed.att) - yaw_of(&truth.att) - 0.05).abs() < 2e-3);
        ins.apply_correction(arr(d_pos), arr(d_vel), arr(d_att), arr(d_ba), arr(d_bg))
            .unwrap();
        let s = ins.state();
        assert!((s.pos_m - truth.pos_m).norm() < 1e-12);
        assert!((s.vel_mps - truth.vel_mps).norm() < 1e-12);
        assert!(s.att.angle_to(&truth.att) < 1e-12);
        assert!((s.accel_bias_mps2 - truth.accel_bias_mps2).norm() < 1e-12);
        assert!((s.gyro_bias_rps - truth.gyro_bias_rps).norm() < 1e-12);
        // Non-finite corrections are refused, state unchanged.
        let before = ins.clone();
        assert!(ins
            .apply_correction([0.0; 3], [0.0; 3], [f64::NAN, 0.0, 0.0], [0.0; 3], [0.0; 3])
            .is_err());
        assert_eq!(ins, before);
    }

    #[test]
    fn heading_correction_sign() {
        // INS yaw 0.3, truth 0.25: error +0.05 about ENU z; correcting gives 0.25.
        let mut ins = ins_at(UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3));
        ins.apply_correction([0.0; 3], [0.0; 3], [0.0, 0.0, 0.05], [0.0; 3], [0.0; 3])
            .unwrap();
        assert!((yaw_of(&ins.state().att) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn accel_bias_estimate_is_compensated() {
        // Sensor reads f + b; after the bias increment the INS stays at rest.
        let b = Vector3::new(0.05, -0.04, 0.02);
        let mut ins = ins_at(UnitQuaternion::identity());
        ins.apply_correction([0.0; 3], [0.0; 3], [0.0; 3], arr(b), [0.0, 0.0, 0.01])
            .unwrap();
        let f = [b.x, b.y, G + b.z];
        let out = run_const(&mut ins, 1000, 1_000_000, f, [0.0, 0.0, 0.01]);
        for i in 0..3 {
            assert!(out.vel_mps[i].abs() < 1e-12 && out.accel_nav_mps2[i].abs() < 1e-12);
        }
        assert!(out.yaw_rad.abs() < 1e-15);
    }

    #[test]
    fn reset_continues_from_the_new_state() {
        let mut ins = ins_at(UnitQuaternion::identity());
        ins.step(0, [0.0, 0.0, G], [0.0; 3]).unwrap();
        ins.step(10_000_000, [0.0, 0.0, G], [0.0; 3]).unwrap();
        let s = InsState {
            pos_m: Vector3::new(5.0, 0.0, 0.0),
            vel_mps: Vector3::new(0.0, 1.0, 0.0),
            t_ns: 10_000_000,
            ..InsState::default()
        };
        ins.reset(s).unwrap();
        let out = ins.step(20_000_000, [0.0, 0.0, G], [0.0; 3]).unwrap();
        assert!((out.pos_m[0] - 5.0).abs() < 1e-15 && (out.pos_m[1] - 0.01).abs() < 1e-15);
        let bad = InsState {
            pos_m: Vector3::new(f64::NAN, 0.0, 0.0),
            ..s
        };
        assert!(matches!(
            ins.reset(bad),
            Err(InsStateError::NonFinite {
                field: "pos_m",
                index: 0,
                ..
            })
        ));
    }

    #[test]
    fn config_validation_names_the_key() {
        assert!(InsConfig::default().validate().is_ok());
        let e = InsConfig {
            max_step_s: 0.0,
            ..InsConfig::default()
        }
        .validate()
        .unwrap_err();
        assert_eq!(e.to_string(), "ins.max_step_s must be in (0, 1] s, got 0");
        let e = InsConfig {
            gravity_mps2: f64::NAN,
            ..InsConfig::default()
        };
        assert!(Ins::new(e, InsState::default()).is_err());
    }

    #[test]
    fn exp_rotvec_is_exact_and_small_angle_safe() {
        for v in [
            Vector3::new(0.3, -1.2, 2.0),
            Vector3::new(1e-9, 0.0, -2e-9),
            Vector3::zeros(),
        ] {
            let q = exp_rotvec(&v);
            let r = UnitQuaternion::from_scaled_axis(v);
            assert!(q.angle_to(&r) < 1e-15 && (q.quaternion().norm() - 1.0).abs() < 1e-15);
        }
    }
}
