//! Process noise from the vibration the IMU measures.
//!
//! A multirotor's accelerometer error in flight is dominated by its motors'
//! vibration, and that differs between vehicles by a factor of several (the
//! standard deviation of the specific-force norm in flight is 0.04-0.30 g
//! over the shared UTIL flights). A fixed velocity noise density fits one
//! kind of vehicle: too small and the filter trusts a drifting INS over the
//! radio, too large and it throws away a good IMU. The vibration is
//! observable from the IMU alone, so every filter reads it there:
//!
//! 1. `a_lp += (a - a_lp) min(1, dt / lowpass_s)` on the horizontal
//!    kinematic acceleration of each INS state (ENU east and north);
//! 2. `v += ((|a - a_lp|^2 / 2) - v) min(1, dt / window_s)`: the running
//!    mean square per axis of what lies above the low-pass (m^2/s^4);
//! 3. the filters add `q = v corr_time_s` (m^2/s^3) to their horizontal
//!    velocity noise density: a white acceleration error of variance `v`
//!    held for `corr_time_s`.
//!
//! Pure and deterministic: a function of the INS states only, so `eval`,
//! replay and the fusion stage compute the same value.

use insuwb_msg::NavState;
use serde::{Deserialize, Serialize};

/// Settings of the vibration meter (`[fusion.vibration]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VibrationConfig {
    /// How long a vibration-induced acceleration error persists, s: the
    /// velocity noise density added is the measured mean square times this.
    /// Default 0 (off: the model's fixed densities only, as in the paper).
    pub corr_time_s: f64,
    /// Time constant of the low-pass that separates the motion from the
    /// vibration, s. Default 0.1 (the 10 Hz the UWB updates at: slower
    /// acceleration is motion the filter tracks).
    pub lowpass_s: f64,
    /// Time constant of the running mean square, s. Default 1.0 (a change of
    /// throttle is taken up within a second).
    pub window_s: f64,
}

impl Default for VibrationConfig {
    fn default() -> Self {
        Self {
            corr_time_s: 0.0,
            lowpass_s: 0.1,
            window_s: 1.0,
        }
    }
}

/// A [`VibrationConfig`] value out of range.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("vibration.{key} must be {requirement}, got {value}")]
pub struct VibrationConfigError {
    /// Key under `vibration`.
    pub key: &'static str,
    /// What the value must satisfy.
    pub requirement: &'static str,
    /// The offending value.
    pub value: f64,
}

impl VibrationConfig {
    /// Checks every setting, naming the first offending key.
    ///
    /// # Errors
    /// The first value out of range.
    pub fn validate(&self) -> Result<(), VibrationConfigError> {
        let checks = [
            (
                "corr_time_s",
                self.corr_time_s,
                "finite and in [0, 10]",
                (0.0..=10.0).contains(&self.corr_time_s),
            ),
            (
                "lowpass_s",
                self.lowpass_s,
                "finite and in (0, 10]",
                self.lowpass_s > 0.0 && self.lowpass_s <= 10.0,
            ),
            (
                "window_s",
                self.window_s,
                "finite and in (0, 100]",
                self.window_s > 0.0 && self.window_s <= 100.0,
            ),
        ];
        for (key, value, requirement, ok) in checks {
            if !ok {
                return Err(VibrationConfigError {
                    key,
                    requirement,
                    value,
                });
            }
        }
        Ok(())
    }
}

/// The running vibration level of one vehicle (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VibrationMeter {
    lowpass: Option<[f64; 2]>,
    mean_square: f64,
}

impl VibrationMeter {
    /// Takes one INS interval of `dt_s` ending at `nav`; returns the
    /// velocity noise density to add, m^2/s^3 (0 while off, before the
    /// second state, or for a non-finite input, which is skipped).
    pub fn push(&mut self, cfg: &VibrationConfig, dt_s: f64, nav: &NavState) -> f64 {
        if cfg.corr_time_s <= 0.0 {
            return 0.0;
        }
        let a = [nav.accel_nav_mps2[0], nav.accel_nav_mps2[1]];
        if !(dt_s > 0.0 && dt_s.is_finite() && a.iter().all(|v| v.is_finite())) {
            return self.noise_density(cfg);
        }
        let Some(lp) = self.lowpass.as_mut() else {
            self.lowpass = Some(a);
            return 0.0;
        };
        let k = (dt_s / cfg.lowpass_s).min(1.0);
        let mut sq = 0.0;
        for (l, v) in lp.iter_mut().zip(a) {
            *l += (v - *l) * k;
            sq += (v - *l) * (v - *l);
        }
        self.mean_square += (0.5 * sq - self.mean_square) * (dt_s / cfg.window_s).min(1.0);
        self.noise_density(cfg)
    }

    /// The mean square vibration per horizontal axis, m^2/s^4.
    #[must_use]
    pub fn mean_square(&self) -> f64 {
        self.mean_square
    }

    /// The velocity noise density it adds, m^2/s^3.
    #[must_use]
    pub fn noise_density(&self, cfg: &VibrationConfig) -> f64 {
        self.mean_square * cfg.corr_time_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nav(a: [f64; 2]) -> NavState {
        NavState {
            accel_nav_mps2: [a[0], a[1], 0.0],
            ..NavState::default()
        }
    }

    #[test]
    fn a_sine_above_the_lowpass_reads_as_its_mean_square() {
        let cfg = VibrationConfig {
            corr_time_s: 0.5,
            ..VibrationConfig::default()
        };
        let mut m = VibrationMeter::default();
        let dt = 1e-3;
        // 2 m/s^2 amplitude at 80 Hz on east, plus a slow 0.5 Hz manoeuvre on north.
        let mut q = 0.0;
        for i in 0..20_000 {
            let t = f64::from(i) * dt;
            let a = [
                2.0 * (2.0 * std::f64::consts::PI * 80.0 * t).sin(),
                1.0 * (2.0 * std::f64::consts::PI * 0.5 * t).sin(),
            ];
            q = m.push(&cfg, dt, &nav(a));
        }
        // East: 2^2 / 2 = 2 m^2/s^4 (less the ~2 % the low-pass keeps);
        // north: the manoeuvre passes the low-pass (a few %). Per axis: ~1.
        let ms = m.mean_square();
        assert!((0.9..1.1).contains(&ms), "mean square {ms}");
        assert!((q - 0.5 * ms).abs() < 1e-12);
    }

    #[test]
    fn off_by_default_and_skips_bad_input() {
        let mut m = VibrationMeter::default();
        assert_eq!(
            m.push(&VibrationConfig::default(), 1e-3, &nav([5.0, 5.0])),
            0.0
        );
        let cfg = VibrationConfig {
            corr_time_s: 1.0,
            ..VibrationConfig::default()
        };
        assert_eq!(m.push(&cfg, 1e-3, &nav([0.0, 0.0])), 0.0);
        let q = m.push(&cfg, 1e-3, &nav([1.0, 0.0]));
        assert!(q > 0.0);
        assert_eq!(m.push(&cfg, 1e-3, &nav([f64::NAN, 0.0])), q);
        assert_eq!(m.push(&cfg, f64::NAN, &nav([1.0, 0.0])), q);
    }

    #[test]
    fn validation_names_the_key() {
        let bad = VibrationConfig {
            lowpass_s: 0.0,
            ..VibrationConfig::default()
        };
        let e = bad.validate().unwrap_err();
        assert_eq!(e.key, "lowpass_s");
        assert!(e.to_string().starts_with("vibration.lowpass_s"));
        let nan = VibrationConfig {
            corr_time_s: f64::NAN,
            ..VibrationConfig::default()
        };
        assert_eq!(nan.validate().unwrap_err().key, "corr_time_s");
    }
}
