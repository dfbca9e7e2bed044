//! Configuration of the error-state filter: noise densities, initial
//! uncertainty, TDOA noise and correlation handling, robust weighting and the
//! divergence monitor, with defaults for a Crazyflie-class MEMS IMU at 1 kHz
//! and the UTIL UWB TDOA system.

use serde::{Deserialize, Serialize};

/// Largest NIS window the monitor can hold (the ring buffer is a fixed array).
pub const MAX_NIS_WINDOW: usize = 256;

/// How a measurement whose normalised innovation exceeds `kappa` is limited.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RobustMode {
    /// Scale the innovation by `lambda = kappa / r` (Huber clipping at
    /// `kappa` sigma); the gain and covariance update are the nominal ones
    /// (READING.md erratum 13, default).
    #[default]
    Huber,
    /// Keep the innovation and inflate the gain's `R` by `1 / lambda^2 =
    /// (r / kappa)^2`, which keeps `P` consistent (erratum 13, option).
    InflateR,
}

/// Statistic of the divergence monitor over the last `nis_window` updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NisStatistic {
    /// Median NIS of the window (robust to the 10-20 % NLOS outliers of real
    /// data; about 0.45 for a consistent filter).
    #[default]
    Median,
    /// Mean NIS of the window, each NIS clipped at `hard_gate_sigma^2`
    /// (about 1 for a consistent filter without outliers).
    Mean,
}

/// Everything the [`crate::Eskf`] needs, in physical units.
///
/// The defaults target a Crazyflie-class quadrotor (BMI088-type MEMS IMU,
/// firmware-filtered, 1 kHz) flying among UTIL's DWM1000 TDOA anchors; the
/// UWB figures were measured on the four UTIL logs in `shared/data/util`
/// (flight segment, residuals against motion capture, see each field).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EskfConfig {
    /// Accelerometer white noise density, m/s^2/sqrt(Hz). Default 0.06: UTIL's
    /// published ESKF uses 2 m/s^2 per 1 kHz sample (= 0.063 m/s^2/sqrt(Hz));
    /// the data README measures 0.4-0.8 m/s^2 RMS of vibration and
    /// unmodelled acceleration error, coloured (the logged IMU is low-pass
    /// filtered by the firmware), which white noise of this density covers
    /// on the time scale of the UWB updates.
    pub accel_noise_mps2_per_rthz: f64,
    /// Gyro white noise density, rad/s/sqrt(Hz). Default 3e-3: UTIL's ESKF
    /// uses 0.1 rad/s per 1 kHz sample (= 3.2e-3); the BMI088 datasheet
    /// value (2.4e-4) is exceeded about tenfold under motor vibration.
    pub gyro_noise_rps_per_rthz: f64,
    /// Accelerometer bias random walk, m/s^3/sqrt(Hz). Default 2e-3: lets the
    /// bias wander about 0.015 m/s^2 over a 60 s flight (thermal drift); the
    /// turn-on bias itself (up to 0.37 m/s^2, data README) is in
    /// `init_accel_bias_sigma_mps2`.
    pub accel_bias_rw_mps3_per_rthz: f64,
    /// Gyro bias random walk, rad/s^2/sqrt(Hz). Default 1e-4: about
    /// 0.05 deg/s of drift over 60 s.
    pub gyro_bias_rw_rps2_per_rthz: f64,
    /// Initial position sigma per axis, m. Default 0.5: the INS is set from a
    /// UWB multilateration fix (UWB-only RMSE 0.14-0.18 m in flight, worse
    /// near the floor, data README).
    pub init_pos_sigma_m: f64,
    /// Initial velocity sigma per axis, m/s. Default 0.3 (start at rest, or
    /// velocity from differenced fixes).
    pub init_vel_sigma_mps: f64,
    /// Initial roll and pitch sigma, rad. Default 0.05 (2.9 deg): levelling
    /// from the accelerometer with an unknown bias of up to 0.37 m/s^2
    /// leaves up to 0.037 rad.
    pub init_roll_pitch_sigma_rad: f64,
    /// Initial yaw sigma, rad. Default 1.8: no magnetometer, so the heading is
    /// unknown (a uniform heading has a sigma of pi/sqrt(3) = 1.81 rad); it
    /// becomes observable from horizontal acceleration against UWB, never
    /// from ground truth. The filter is linearised: expect convergence from
    /// errors up to a few tens of degrees, slower from larger ones.
    pub init_yaw_sigma_rad: f64,
    /// Initial accelerometer bias sigma per axis, m/s^2. Default 0.2: biases
    /// up to 0.37 m/s^2 measured (data README) when no static phase allows
    /// the INS to fit them.
    pub init_accel_bias_sigma_mps2: f64,
    /// Initial gyro bias sigma per axis, rad/s. Default 0.01 (0.6 deg/s):
    /// turn-on bias of a MEMS gyro left after the firmware's at-rest
    /// calibration.
    pub init_gyro_bias_sigma_rps: f64,
    /// Sigma of one TDOA measurement, m (marginal, used for the outlier test
    /// and the NIS). Default 0.17: robust SD of the in-flight residuals is
    /// 0.14-0.19 m, inlier SD 0.16-0.17 m plus per-pair biases of about
    /// 0.07 m RMS (measured on the four UTIL logs).
    pub tdoa_sigma_m: f64,
    /// Correlation time of the TDOA errors, s, for the rate-adaptive
    /// inflation: a pair's `R` used in the gain is multiplied by
    /// `max(1, 2 tau / dt_pair)`, `dt_pair` the time since that pair's last
    /// applied measurement (floored at 1 ms), so each pair contributes at
    /// most the information of one independent measurement per `2 tau`
    /// whatever its rate (50 Hz per pair in TDOA2, 3-15 Hz in TDOA3).
    /// Default 0.25: the residual autocorrelation (bias removed, inliers) is
    /// 0.65-0.72 at 20 ms, 0.5 at 0.2 s, 0.2 at 0.5 s on all four logs, whose
    /// integral time scale `2 * integral(rho)` is about 0.5 s. 0 disables.
    pub tdoa_corr_time_s: f64,
    /// Constant factor on the gain's TDOA `R` (on top of the rate-adaptive
    /// one), for correlation between pairs sharing an anchor. Default 1.
    pub tdoa_r_inflation: f64,
    /// Minimum interval between two applied measurements of the same anchor
    /// pair (unordered), s; earlier ones are skipped (decimated). Default 0
    /// (off): the rate-adaptive inflation already bounds the information,
    /// and all measurements help average the white part and vote out
    /// outliers.
    pub min_interval_per_pair_s: f64,
    /// How outliers beyond `kappa` are limited. Default Huber (erratum 13).
    pub robust_mode: RobustMode,
    /// Normalised innovation `|v| / sqrt(S)` above which a measurement is
    /// down-weighted. Default 3 (READING.md erratum 12).
    pub kappa: f64,
    /// Normalised innovation above which a measurement is rejected and
    /// counted. Default 8: the in-flight NLOS errors of 0.3-1 m stay below it
    /// (and are clipped at `kappa`), take-off errors of metres are rejected.
    pub hard_gate_sigma: f64,
    /// Number of recent updates (decimated ones excluded) the divergence
    /// monitor looks at, at most [`MAX_NIS_WINDOW`]. Default 200 (0.5 s of
    /// TDOA2 data at 400 Hz).
    pub nis_window: usize,
    /// Statistic of the window compared with `nis_threshold`. Default median.
    pub nis_statistic: NisStatistic,
    /// Threshold on the window statistic above which `needs_reset` is raised.
    /// Default 9 (for the median: half the measurements beyond 3 sigma; for
    /// the mean a value near 9 also suits).
    pub nis_threshold: f64,
    /// Consecutive rejections lasting longer than this, s, raise
    /// `needs_reset`. Default 1.0.
    pub max_reject_run_s: f64,
    /// Largest accepted prediction step, s. Default 0.1 (IMU gaps of up to
    /// 42 ms occur in the UTIL logs; longer gaps must be handled by the
    /// caller).
    pub max_dt_s: f64,
    /// Time constant of the innovation-based process-noise scale, s; 0
    /// (default) keeps the configured noise densities. When positive, every
    /// applied TDOA update feeds exponentially weighted sums (this time
    /// constant) of its clipped innovation energy beyond the measurement's
    /// own variance, `min(v^2, kappa^2 S) / c(kappa) - sigma^2`, and of its
    /// predicted part `H P H^T`; their ratio says how much larger the INS's
    /// error growth is than the process noise claims, and the scale `alpha`
    /// on `Q` follows it (`d ln alpha / dt = ln(ratio) / q_adapt_time_s`,
    /// `alpha` in `[1, q_scale_max]`). The vibration-induced accelerometer
    /// error differs about tenfold between vehicles of one fleet (UTIL: 0.04
    /// to 0.7 m/s^2/sqrt(Hz) equivalent on 0.1-0.5 s scales), which no fixed
    /// density serves.
    pub q_adapt_time_s: f64,
    /// How much slower the scale falls than it rises (its time constant
    /// when the innovations say it is too high is `q_adapt_time_s` times
    /// this). Default 20.
    pub q_adapt_decay_factor: f64,
    /// Largest process-noise scale `alpha` (multiplies every density's
    /// square). Default 100 (densities up to tenfold).
    pub q_scale_max: f64,
    /// Horizontal specific force below which the TDOA updates leave the yaw
    /// and the yaw-rate bias alone, m/s^2; 0 (default) always updates them.
    /// Without a magnetometer the yaw is observable only through horizontal
    /// acceleration; near hover, velocity errors from an accelerometer bias
    /// not yet learnt (vibration rectification, UTIL: up to 3.6 m/s^2 at
    /// lift-off) would otherwise be read as a heading error, tens of degrees
    /// of it.
    pub yaw_min_excitation_mps2: f64,
    /// Apply the reset Jacobian `G = I - [d_att / 2 x]` to the attitude block
    /// of `P` when a correction is taken (Sola 2017, eq. 287). Default true;
    /// false keeps `P` unchanged (identity Jacobian).
    pub reset_jacobian: bool,
}

impl Default for EskfConfig {
    fn default() -> Self {
        Self {
            accel_noise_mps2_per_rthz: 0.06,
            gyro_noise_rps_per_rthz: 3e-3,
            accel_bias_rw_mps3_per_rthz: 2e-3,
            gyro_bias_rw_rps2_per_rthz: 1e-4,
            init_pos_sigma_m: 0.5,
            init_vel_sigma_mps: 0.3,
            init_roll_pitch_sigma_rad: 0.05,
            init_yaw_sigma_rad: 1.8,
            init_accel_bias_sigma_mps2: 0.2,
            init_gyro_bias_sigma_rps: 0.01,
            tdoa_sigma_m: 0.17,
            tdoa_corr_time_s: 0.25,
            tdoa_r_inflation: 1.0,
            min_interval_per_pair_s: 0.0,
            robust_mode: RobustMode::Huber,
            kappa: 3.0,
            hard_gate_sigma: 8.0,
            nis_window: 200,
            nis_statistic: NisStatistic::Median,
            nis_threshold: 9.0,
            max_reject_run_s: 1.0,
            max_dt_s: 0.1,
            q_adapt_time_s: 0.0,
            q_adapt_decay_factor: 20.0,
            q_scale_max: 100.0,
            yaw_min_excitation_mps2: 0.0,
            reset_jacobian: true,
        }
    }
}

/// A configuration value out of its range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("eskf.{key} must be {requirement}, got {value}")]
pub struct EskfConfigError {
    /// The offending key (without the `eskf.` prefix).
    pub key: &'static str,
    /// What the value must satisfy.
    pub requirement: &'static str,
    /// The value found.
    pub value: f64,
}

fn check(
    key: &'static str,
    value: f64,
    requirement: &'static str,
    ok: impl Fn(f64) -> bool,
) -> Result<(), EskfConfigError> {
    if value.is_finite() && ok(value) {
        Ok(())
    } else {
        Err(EskfConfigError {
            key,
            requirement,
            value,
        })
    }
}

impl EskfConfig {
    /// Checks every value, naming the first offending key.
    ///
    /// # Errors
    /// [`EskfConfigError`] naming the key, its requirement and its value.
    pub fn validate(&self) -> Result<(), EskfConfigError> {
        let non_neg = |v: f64| v >= 0.0;
        let pos = |v: f64| v > 0.0;
        check(
            "accel_noise_mps2_per_rthz",
            self.accel_noise_mps2_per_rthz,
            ">= 0",
            non_neg,
        )?;
        check(
            "gyro_noise_rps_per_rthz",
            self.gyro_noise_rps_per_rthz,
            ">= 0",
            non_neg,
        )?;
        check(
            "accel_bias_rw_mps3_per_rthz",
            self.accel_bias_rw_mps3_per_rthz,
            ">= 0",
            non_neg,
        )?;
        check(
            "gyro_bias_rw_rps2_per_rthz",
            self.gyro_bias_rw_rps2_per_rthz,
            ">= 0",
            non_neg,
        )?;
        check("init_pos_sigma_m", self.init_pos_sigma_m, "> 0", pos)?;
        check("init_vel_sigma_mps", self.init_vel_sigma_mps, "> 0", pos)?;
        check(
            "init_roll_pitch_sigma_rad",
            self.init_roll_pitch_sigma_rad,
            "> 0",
            pos,
        )?;
        check("init_yaw_sigma_rad", self.init_yaw_sigma_rad, "> 0", pos)?;
        check(
            "init_accel_bias_sigma_mps2",
            self.init_accel_bias_sigma_mps2,
            "> 0",
            pos,
        )?;
        check(
            "init_gyro_bias_sigma_rps",
            self.init_gyro_bias_sigma_rps,
            "> 0",
            pos,
        )?;
        check("tdoa_sigma_m", self.tdoa_sigma_m, "> 0", pos)?;
        check("tdoa_corr_time_s", self.tdoa_corr_time_s, ">= 0", non_neg)?;
        check("tdoa_r_inflation", self.tdoa_r_inflation, ">= 1", |v| {
            v >= 1.0
        })?;
        check(
            "min_interval_per_pair_s",
            self.min_interval_per_pair_s,
            ">= 0",
            non_neg,
        )?;
        check("kappa", self.kappa, "> 0", pos)?;
        check("hard_gate_sigma", self.hard_gate_sigma, "> kappa", |v| {
            v > self.kappa
        })?;
        // usize -> f64 is exact for every window the check accepts.
        #[allow(clippy::cast_precision_loss)]
        let window = self.nis_window as f64;
        check("nis_window", window, "in 1..=256", |v| {
            (1.0..=MAX_NIS_WINDOW as f64).contains(&v)
        })?;
        check("nis_threshold", self.nis_threshold, "> 0", pos)?;
        check("max_reject_run_s", self.max_reject_run_s, "> 0", pos)?;
        check("max_dt_s", self.max_dt_s, "> 0", pos)?;
        check("q_adapt_time_s", self.q_adapt_time_s, ">= 0", non_neg)?;
        check("q_scale_max", self.q_scale_max, ">= 1", |v| v >= 1.0)?;
        check(
            "yaw_min_excitation_mps2",
            self.yaw_min_excitation_mps2,
            ">= 0",
            non_neg,
        )?;
        check(
            "q_adapt_decay_factor",
            self.q_adapt_decay_factor,
            ">= 1",
            |v| v >= 1.0,
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid() {
        assert_eq!(EskfConfig::default().validate(), Ok(()));
    }

    #[test]
    fn validate_names_the_key_and_value() {
        let c = EskfConfig {
            hard_gate_sigma: 2.0,
            ..EskfConfig::default()
        };
        let e = c.validate().unwrap_err();
        assert_eq!(e.key, "hard_gate_sigma");
        assert_eq!(e.to_string(), "eskf.hard_gate_sigma must be > kappa, got 2");
        let c = EskfConfig {
            init_yaw_sigma_rad: f64::NAN,
            ..EskfConfig::default()
        };
        assert_eq!(c.validate().unwrap_err().key, "init_yaw_sigma_rad");
        let c = EskfConfig {
            nis_window: 1000,
            ..EskfConfig::default()
        };
        assert_eq!(
            c.validate().unwrap_err().to_string(),
            "eskf.nis_window must be in 1..=256, got 1000"
        );
        let c = EskfConfig {
            tdoa_r_inflation: 0.5,
            ..EskfConfig::default()
        };
        assert_eq!(c.validate().unwrap_err().key, "tdoa_r_inflation");
    }

    #[test]
    fn serde_round_trip_and_unknown_fields() {
        let c = EskfConfig::default();
        let s = serde_json::to_string(&c).unwrap();
        let back: EskfConfig = serde_json::from_str(&s).unwrap();
        assert_eq!(back, c);
        let partial: EskfConfig =
            serde_json::from_str(r#"{"kappa": 2.5, "robust_mode": "inflate_r"}"#).unwrap();
        assert_eq!(partial.kappa, 2.5);
        assert_eq!(partial.robust_mode, RobustMode::InflateR);
        assert_eq!(partial.tdoa_sigma_m, c.tdoa_sigma_m);
        assert!(serde_json::from_str::<EskfConfig>(r#"{"kapa": 2.5}"#).is_err());
    }
}
