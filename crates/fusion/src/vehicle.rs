//! The vehicle model of a run (`[fusion] vehicle`, `[fusion.multirotor]`,
//! `[fusion.ground]`): its settings, what the INS integrates
//! ([`VehicleSettings::mechanisation`]), and the measurements a filter
//! draws from it.
//!
//! - `free`: the paper's INS, every accelerometer axis integrated.
//! - `multirotor`: thrust along body z plus linear rotor drag in body x/y
//!   (`insuwb_nav::vehicle`); the accelerometer's horizontal channels,
//!   low-passed, are drag measurements of the body velocity
//!   ([`DragMeter`]), and the drag coefficient is estimated online around a
//!   configured prior (regularised least squares with forgetting, together
//!   with each channel's offset: the vibration-rectified bias of a
//!   multirotor's accelerometer is a few m/s^2 and changes at lift-off).
//! - `ground`: zero lateral and vertical body velocity, fused as
//!   pseudo-measurements (the tight filter: lateral and vertical; the loose
//!   filters, whose state is horizontal: lateral); the INS integrates
//!   freely.

use insuwb_nav::vehicle::{Mechanisation, VehicleKind};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Settings of the multirotor model (`[fusion.multirotor]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MultirotorConfig {
    /// Prior linear drag coefficient, 1/s (body x/y force per body
    /// velocity): what the INS integrates, and the prior of the online
    /// estimate. Default 0.3 (a Crazyflie 2.x: about 0.2-0.35 from its
    /// rotor-drag identification, Förster 2015).
    pub drag_per_s: f64,
    /// Velocity damping of the tight filter's model of the vehicle, 1/s:
    /// the drag plus what stands for the velocity information the IMU
    /// lacks between UWB updates (the thrust's tilt carries little over a
    /// second on small quadrotors, and without damping the filter's
    /// velocity wanders with the radio's slow errors). The INS, and with it
    /// every loose filter, integrates `drag_per_s`; the tight filter's
    /// error state takes up the difference. Values at or below
    /// `drag_per_s` (default 0) use the drag.
    pub damping_per_s: f64,
    /// Standard deviation of the prior on the drag coefficient, 1/s; 0
    /// holds it at the prior (no online estimate). Default 0.15.
    pub drag_prior_sigma_per_s: f64,
    /// Random walk of each horizontal channel's offset (the
    /// accelerometer's vibration-rectified bias), m/s^2/sqrt(s). Default 0.3.
    pub offset_walk_mps2_per_rts: f64,
    /// White-noise density of the unmodelled body x/y force (gusts,
    /// thrust asymmetry, model error), m/s^2/sqrt(Hz). Default 0.5.
    pub model_noise_mps2_per_rthz: f64,
    /// Time constant of the low-pass on the horizontal accelerometer
    /// channels that make the drag measurement, s. Default 0.1.
    pub drag_lowpass_s: f64,
    /// Standard deviation of one drag measurement (the low-passed channel's
    /// vibration), m/s^2; 0 turns the drag measurements off. Default 0.5.
    pub drag_sigma_mps2: f64,
    /// Interval between drag measurements, s. Default 0.1.
    pub drag_period_s: f64,
    /// Hand over to the free model when the accelerometer's horizontal
    /// channels carry more than this many times their vibration in slow
    /// variation over the first `signal_window_s` of integration
    /// ([`insuwb_nav::vehicle::HorizontalSignal`]): a vehicle whose IMU
    /// measures its horizontal acceleration is better integrated on every
    /// axis. 0 (default): never.
    pub free_above_signal_ratio: f64,
    /// Seconds of integration the hand-over is judged over. Default 10.
    pub signal_window_s: f64,
}

impl Default for MultirotorConfig {
    fn default() -> Self {
        Self {
            drag_per_s: 0.3,
            damping_per_s: 0.0,
            drag_prior_sigma_per_s: 0.15,
            offset_walk_mps2_per_rts: 0.3,
            model_noise_mps2_per_rthz: 0.5,
            drag_lowpass_s: 0.1,
            drag_sigma_mps2: 0.5,
            drag_period_s: 0.1,
            free_above_signal_ratio: 0.0,
            signal_window_s: 10.0,
        }
    }
}

/// Settings of the ground model (`[fusion.ground]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GroundConfig {
    /// Standard deviation of the zero-lateral-velocity pseudo-measurement,
    /// m/s (wheel slip and the constraint's linearisation about the
    /// filter's own heading). Default 0.5. On the paper's scenario (20
    /// runs, `insuwb eval --scenario paper-3.4 --runs 20 --vehicle ground`)
    /// the tight filter reads 0.061 m with it against 0.058 m free, and
    /// 0.170 m with 0.05 m/s (NEES 30: the constraint, repeated as if
    /// independent each time, makes its heading overconfident); the IAKF
    /// reads 0.0111 m either way (0.0108 m with 0.05 m/s).
    pub lateral_sigma_mps: f64,
    /// Standard deviation of the zero-vertical-velocity pseudo-measurement
    /// of the tight filter, m/s; 0 (default) leaves it out: the ground
    /// scenarios hold the INS in the plane (`ins.planar`) already.
    pub vertical_sigma_mps: f64,
    /// Interval between pseudo-measurements, s. Default 0.1.
    pub period_s: f64,
}

impl Default for GroundConfig {
    fn default() -> Self {
        Self {
            lateral_sigma_mps: 0.5,
            vertical_sigma_mps: 0.0,
            period_s: 0.1,
        }
    }
}

/// A vehicle setting out of range; the message names the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key} must be {expected}, got {value}")]
pub struct VehicleConfigError {
    /// The key, e.g. `multirotor.drag_per_s`.
    pub key: &'static str,
    /// The range it must be in.
    pub expected: &'static str,
    /// The value given.
    pub value: f64,
}

/// The vehicle of a run: its kind and the settings of each model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleSettings<'a> {
    /// Which model.
    pub kind: VehicleKind,
    /// The multirotor's settings (used when `kind` is multirotor).
    pub multirotor: &'a MultirotorConfig,
    /// The ground robot's settings (used when `kind` is ground).
    pub ground: &'a GroundConfig,
}

fn check(
    key: &'static str,
    value: f64,
    lo: f64,
    hi: f64,
    expected: &'static str,
) -> Result<(), VehicleConfigError> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(VehicleConfigError {
            key,
            expected,
            value,
        })
    }
}

impl VehicleSettings<'_> {
    /// Checks the settings of the model in use.
    ///
    /// # Errors
    /// [`VehicleConfigError`] naming the first key out of range.
    pub fn validate(&self) -> Result<(), VehicleConfigError> {
        let m = self.multirotor;
        check(
            "multirotor.drag_per_s",
            m.drag_per_s,
            0.0,
            10.0,
            "in [0, 10] 1/s",
        )?;
        check(
            "multirotor.damping_per_s",
            m.damping_per_s,
            0.0,
            10.0,
            "in [0, 10] 1/s",
        )?;
        check(
            "multirotor.drag_prior_sigma_per_s",
            m.drag_prior_sigma_per_s,
            0.0,
            10.0,
            "in [0, 10] 1/s",
        )?;
        check(
            "multirotor.offset_walk_mps2_per_rts",
            m.offset_walk_mps2_per_rts,
            0.0,
            100.0,
            "in [0, 100] m/s^2/sqrt(s)",
        )?;
        check(
            "multirotor.model_noise_mps2_per_rthz",
            m.model_noise_mps2_per_rthz,
            0.0,
            100.0,
            "in [0, 100] m/s^2/sqrt(Hz)",
        )?;
        check(
            "multirotor.drag_lowpass_s",
            m.drag_lowpass_s,
            0.0,
            10.0,
            "in [0, 10] s",
        )?;
        check(
            "multirotor.drag_sigma_mps2",
            m.drag_sigma_mps2,
            0.0,
            100.0,
            "in [0, 100] m/s^2",
        )?;
        check(
            "multirotor.drag_period_s",
            m.drag_period_s,
            0.001,
            10.0,
            "in [0.001, 10] s",
        )?;
        check(
            "multirotor.free_above_signal_ratio",
            m.free_above_signal_ratio,
            0.0,
            100.0,
            "0 (never) or in (0, 100]",
        )?;
        check(
            "multirotor.signal_window_s",
            m.signal_window_s,
            0.5,
            600.0,
            "in [0.5, 600] s",
        )?;
        let g = self.ground;
        check(
            "ground.lateral_sigma_mps",
            g.lateral_sigma_mps,
            1e-4,
            100.0,
            "in [1e-4, 100] m/s",
        )?;
        if g.vertical_sigma_mps != 0.0 {
            check(
                "ground.vertical_sigma_mps",
                g.vertical_sigma_mps,
                1e-4,
                100.0,
                "0 (off) or in [1e-4, 100] m/s",
            )?;
        }
        check(
            "ground.period_s",
            g.period_s,
            0.001,
            10.0,
            "in [0.001, 10] s",
        )?;
        Ok(())
    }

    /// What the INS integrates for this vehicle.
    #[must_use]
    pub fn mechanisation(&self) -> Mechanisation {
        match self.kind {
            VehicleKind::Multirotor => Mechanisation::ThrustDrag {
                drag_per_s: self.multirotor.drag_per_s,
            },
            // The constraint is the filters' (pseudo-measurements with their
            // noise): a projection of the INS velocity would break the loose
            // filters' error model (paper-3.4, 20 runs: IAKF 0.019 m with
            // it, against 0.011 m free).
            VehicleKind::Free | VehicleKind::Ground => Mechanisation::Free,
        }
    }
}

/// Initial standard deviation of each channel's offset, m/s^2 (a
/// multirotor's vibration-rectified accelerometer bias is a few m/s^2).
const OFFSET_SIGMA0_MPS2: f64 = 5.0;

/// The multirotor's drag measurements: the accelerometer's horizontal
/// channels low-passed, an online estimate of the drag coefficient `k`
/// and of each channel's offset `c_i` in `f_i = -k v_b,i + c_i` (`i` =
/// body x, y), and the drag measurement of the body velocity they yield.
///
/// The estimate is a three-state Kalman filter on `[k, c_x, c_y]`: `k`
/// constant with the configured prior, each offset a random walk
/// (`offset_walk_mps2_per_rts`: the vibration rectification changes with
/// the motor speed, by up to 3.6 m/s^2 at lift-off on UTIL's vehicles), fed
/// the low-passed channels against the INS's low-passed body velocity.
/// Deterministic: a function of the sequence of INS states it is given.
#[derive(Debug, Clone, PartialEq)]
pub struct DragMeter {
    cfg: MultirotorConfig,
    /// Low-passed body x/y specific force, m/s^2, and body x/y velocity, m/s.
    f_lp: Option<[f64; 2]>,
    v_lp: [f64; 2],
    /// Estimate of `[k, c_x, c_y]` and its covariance.
    theta: Vector3<f64>,
    p: Matrix3<f64>,
    /// Time since the last drag measurement, s.
    since_s: f64,
}

/// One drag measurement: the low-passed channels less their offsets, the
/// drag coefficient, and the body-frame velocity they measure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DragMeasurement {
    /// `f_i - c_i` for body x and y, m/s^2 (measures `-k v_b,i`).
    pub force_mps2: [f64; 2],
    /// The drag coefficient estimate, 1/s.
    pub drag_per_s: f64,
    /// Standard deviation of each channel (the measurement's noise and
    /// the offset's uncertainty), m/s^2.
    pub sigma_mps2: [f64; 2],
    /// The same low-pass applied to the INS's body x/y velocity, m/s: the
    /// measurement's prediction is `-k` times it.
    pub body_vel_lp_mps: [f64; 2],
}

impl DragMeter {
    /// A meter with these settings.
    #[must_use]
    pub fn new(cfg: &MultirotorConfig) -> Self {
        let s2 = OFFSET_SIGMA0_MPS2 * OFFSET_SIGMA0_MPS2;
        Self {
            cfg: cfg.clone(),
            f_lp: None,
            v_lp: [0.0; 2],
            theta: Vector3::new(cfg.drag_per_s, 0.0, 0.0),
            p: Matrix3::from_diagonal(&Vector3::new(
                cfg.drag_prior_sigma_per_s * cfg.drag_prior_sigma_per_s,
                s2,
                s2,
            )),
            since_s: 0.0,
        }
    }

    /// The drag coefficient estimate now, 1/s (the prior until data come).
    #[must_use]
    pub fn drag_per_s(&self) -> f64 {
        self.theta[0]
    }

    /// Feeds one INS interval of `dt_s` (attitude, velocity and measured
    /// kinematic acceleration of its end state, gravity `gravity_mps2`);
    /// returns a drag measurement every `drag_period_s`, unless the
    /// measurements are off (`drag_sigma_mps2 = 0`).
    pub fn push(
        &mut self,
        dt_s: f64,
        quat: [f64; 4],
        vel_nav: [f64; 3],
        accel_nav_meas: [f64; 3],
        gravity_mps2: f64,
    ) -> Option<DragMeasurement> {
        if !(dt_s > 0.0 && dt_s.is_finite()) {
            return None;
        }
        let att = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            quat[0], quat[1], quat[2], quat[3],
        ));
        let f_b = att.inverse() * (Vector3::from(accel_nav_meas) + Vector3::z() * gravity_mps2);
        let v_b = att.inverse() * Vector3::from(vel_nav);
        if !(f_b.iter().all(|v| v.is_finite()) && v_b.iter().all(|v| v.is_finite())) {
            return None;
        }
        let tau = self.cfg.drag_lowpass_s;
        let w = if tau > 0.0 {
            1.0 - (-dt_s / tau).exp()
        } else {
            1.0
        };
        let f_lp = match self.f_lp {
            None => {
                self.v_lp = [v_b.x, v_b.y];
                [f_b.x, f_b.y]
            }
            Some(p) => {
                self.v_lp = [
                    self.v_lp[0] + w * (v_b.x - self.v_lp[0]),
                    self.v_lp[1] + w * (v_b.y - self.v_lp[1]),
                ];
                [p[0] + w * (f_b.x - p[0]), p[1] + w * (f_b.y - p[1])]
            }
        };
        self.f_lp = Some(f_lp);
        let walk = self.cfg.offset_walk_mps2_per_rts;
        let q = walk * walk * dt_s;
        self.p[(1, 1)] += q;
        self.p[(2, 2)] += q;
        self.since_s += dt_s;
        if self.since_s < self.cfg.drag_period_s {
            return None;
        }
        self.since_s = 0.0;
        let sd = self.cfg.drag_sigma_mps2;
        if sd <= 0.0 {
            return None;
        }
        // The measurement as the filter sees it, before this update: the
        // offsets' uncertainty is part of its noise.
        let out = DragMeasurement {
            force_mps2: [f_lp[0] - self.theta[1], f_lp[1] - self.theta[2]],
            drag_per_s: self.theta[0],
            sigma_mps2: [
                (sd * sd + self.p[(1, 1)]).sqrt(),
                (sd * sd + self.p[(2, 2)]).sqrt(),
            ],
            body_vel_lp_mps: self.v_lp,
        };
        // Then the parameters from the two channels: f_i = -k v_i + c_i.
        for i in 0..2 {
            let mut h = Vector3::zeros();
            h[0] = -self.v_lp[i];
            h[i + 1] = 1.0;
            let ph = self.p * h;
            let s = h.dot(&ph) + sd * sd;
            if !(s.is_finite() && s > 0.0) {
                continue;
            }
            let k = ph / s;
            self.theta += k * (f_lp[i] - h.dot(&self.theta));
            self.p -= k * ph.transpose();
            self.p = (self.p + self.p.transpose()) * 0.5;
        }
        self.theta[0] = self.theta[0].clamp(0.0, 10.0);
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Flying level with a body velocity that varies, drag 0.4/s and
    /// offsets (-2, 1) m/s^2 on the channels, against a prior of 0.2/s: the
    /// online fit recovers the simulated drag coefficient.
    #[test]
    fn the_drag_fit_recovers_the_simulated_coefficient() {
        let g = 9.81;
        let cfg = MultirotorConfig {
            drag_per_s: 0.2,
            drag_prior_sigma_per_s: 0.2,
            offset_walk_mps2_per_rts: 0.01,
            ..MultirotorConfig::default()
        };
        let mut m = DragMeter::new(&cfg);
        let (k, c) = (0.4, [-2.0, 1.0]);
        let dt = 0.001;
        let mut last = None;
        for i in 0..40_000 {
            let t = f64::from(i) * dt;
            let v = [1.5 * (0.3 * t).sin(), 1.0 * (0.17 * t).cos(), 0.0];
            // Level and facing east: body = ENU; measured kinematic
            // acceleration = drag + offsets (the low-pass lag of a slow
            // velocity is negligible).
            let a = [-k * v[0] + c[0], -k * v[1] + c[1], 0.0];
            if let Some(d) = m.push(dt, [1.0, 0.0, 0.0, 0.0], v, a, g) {
                last = Some((d, v));
            }
        }
        let (d, v) = last.unwrap();
        assert!((d.drag_per_s - k).abs() < 0.02, "{d:?}");
        assert!((m.drag_per_s() - k).abs() < 0.02);
        // The measurement is the drag itself once the offsets are removed.
        assert!((d.force_mps2[0] + k * v[0]).abs() < 0.05, "{d:?}");
        assert!((d.force_mps2[1] + k * v[1]).abs() < 0.05, "{d:?}");
    }

    /// Hovering (no velocity to fit against): the estimate stays at the prior.
    #[test]
    fn without_motion_the_prior_holds() {
        let cfg = MultirotorConfig::default();
        let mut m = DragMeter::new(&cfg);
        for _ in 0..20_000 {
            let _ = m.push(
                0.001,
                [1.0, 0.0, 0.0, 0.0],
                [0.0; 3],
                [-3.0, 0.5, 0.0],
                9.81,
            );
        }
        assert!((m.drag_per_s() - cfg.drag_per_s).abs() < 1e-6);
    }

    #[test]
    fn out_of_range_settings_name_their_key() {
        let m = MultirotorConfig {
            drag_per_s: -1.0,
            ..MultirotorConfig::default()
        };
        let g = GroundConfig::default();
        let e = VehicleSettings {
            kind: VehicleKind::Multirotor,
            multirotor: &m,
            ground: &g,
        }
        .validate()
        .unwrap_err();
        assert_eq!(e.key, "multirotor.drag_per_s");
        assert!(e.to_string().contains("-1"), "{e}");
    }
}
