//! Configuration of the error-state filter: noise densities, initial
//! uncertainty, TDOA noise and correlation handling, and the robust
//! weighting, with defaults for a Crazyflie-class MEMS IMU at 1 kHz and the
//! UTIL UWB TDOA system. Its divergence is watched by the monitor every
//! filter shares (`insuwb_filter::DivergenceMonitor`, run by the fusion
//! engine), not here.

use insuwb_filter::LimitMode;
use serde::{Deserialize, Serialize};

/// Keys of earlier versions, refused with a message naming what replaces
/// them (the configuration loader adds the file and the key).
mod removed {
    use serde::de::{Deserializer, Error};

    macro_rules! removed {
        ($($name:ident => $msg:literal),* $(,)?) => {$(
            pub(super) fn $name<'de, D: Deserializer<'de>>(_: D) -> Result<(), D::Error> {
                Err(D::Error::custom($msg))
            }
        )*};
    }

    removed! {
        robust_mode => "renamed eskf.limit_mode (\"scale_innovation\", also read as \"huber\", or \"inflate_r\"; the IAKF's filter.limit_mode takes the same values)",
        nis_window => "moved to fusion.engine.monitor.window (the one divergence monitor of every filter; it counts TDOA differences for this one)",
        nis_statistic => "removed: fusion.engine.monitor counts the fraction of its window above the gate (fusion.engine.monitor.fraction; 0.5 is the former median)",
        nis_threshold => "moved to fusion.engine.monitor.gate_per_dim (the one divergence monitor of every filter)",
        max_reject_run_s => "moved to fusion.engine.monitor.max_reject_run_s (the one divergence monitor of every filter)",
    }
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
    /// Sigma of one two-way range, m (as `tdoa_sigma_m`, for
    /// [`crate::Eskf::update_range`]; the correlation inflation, the robust
    /// weighting and the gates are the TDOA ones). Default 0.1: the ranging
    /// precision the Qorvo DWM1001 datasheet states (10 cm).
    pub range_sigma_m: f64,
    /// Time constant, s, with which the TDOA sigma used follows the one the
    /// innovations show (the IAKF's adaptive `R`, made robust): the median
    /// squared innovation of the last 128 applied TDOA updates, read as a
    /// variance (divided by chi-square(1)'s median), less the median
    /// predicted part `H P H^T`, bounded in `[sigma_adapt_min_m,
    /// tdoa_sigma_m]`. The configured sigma is the prior and the upper
    /// bound (a radio noisier than configured is what the robust weighting
    /// is for). 0 (default) keeps `tdoa_sigma_m`.
    pub tdoa_sigma_adapt_time_s: f64,
    /// As `tdoa_sigma_adapt_time_s`, for two-way ranges (bounded in
    /// `[sigma_adapt_min_m, range_sigma_m]`). A datasheet's ranging
    /// precision is a bound for the whole product line; a module at rest in
    /// one room ranges several times better (UTIL's static log: 0.016-0.08
    /// m per anchor against the DWM1001's stated 0.1 m). 0 (default) keeps
    /// `range_sigma_m`.
    pub range_sigma_adapt_time_s: f64,
    /// Smallest sigma a learnt UWB noise may reach, m. Default 0.01: the
    /// resolution of the ranging timestamps (15.65 ps, 4.7 mm, doubled).
    pub sigma_adapt_min_m: f64,
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
    /// The same for two-way ranges, per anchor, s. Default 0.25.
    pub range_corr_time_s: f64,
    /// Stationary sigma of each anchor's part of the TDOA error, a
    /// first-order Gauss-Markov state per anchor (eight at a time), m: a
    /// difference reads `β_b - β_a` on top of the geometry (the anchor's
    /// packets' receive-time error enters every difference it is in).
    /// Default 0: no such states, each difference's error its own.
    pub tdoa_anchor_sigma_m: f64,
    /// Correlation time of those states, s. Default 0.2.
    pub tdoa_anchor_corr_time_s: f64,
    /// Time over which each anchor's part averages out, s: the state is
    /// the Gauss-Markov error less its own running mean over this time, so
    /// it carries an anchor's shared error over fractions of a second and
    /// nothing that lasts (a second state per anchor; see
    /// `anchor_error`'s module doc). Default 0: the plain Gauss-Markov
    /// state, lasting part included.
    pub tdoa_anchor_highpass_s: f64,
    /// Constant factor on the gain's TDOA `R` (on top of the rate-adaptive
    /// one), for correlation between pairs sharing an anchor. Default 1.
    pub tdoa_r_inflation: f64,
    /// Minimum interval between two applied measurements of the same anchor
    /// pair (unordered), s; earlier ones are skipped (decimated). Default 0
    /// (off): the rate-adaptive inflation already bounds the information,
    /// and all measurements help average the white part and vote out
    /// outliers.
    pub min_interval_per_pair_s: f64,
    /// How the weight `lambda = kappa / r` of a measurement beyond `kappa`
    /// is applied (erratum 13): `scale_innovation` (default, Huber clipping
    /// of the innovation; `huber` is read as this) or `inflate_r` (the
    /// gain's `R` divided by `lambda^2`, which keeps `P` consistent). The
    /// same vocabulary as the IAKF's `filter.limit_mode`.
    pub limit_mode: LimitMode,
    /// Normalised innovation `|v| / sqrt(S)` above which a measurement is
    /// down-weighted. Default 3 (READING.md erratum 12).
    pub kappa: f64,
    /// Normalised innovation above which a measurement is rejected and
    /// counted. Default 8: the in-flight NLOS errors of 0.3-1 m stay below it
    /// (and are clipped at `kappa`), take-off errors of metres are rejected.
    pub hard_gate_sigma: f64,
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
    /// of it. A body-frame velocity measurement updates them at any specific
    /// force ([`crate::Eskf::update_body_velocity`]): it makes the yaw
    /// observable whenever the vehicle moves.
    pub yaw_min_excitation_mps2: f64,
    /// Apply the reset Jacobian `G = I - [d_att / 2 x]` to the attitude block
    /// of `P` when a correction is taken (Sola 2017, eq. 287). Default true;
    /// false keeps `P` unchanged (identity Jacobian).
    pub reset_jacobian: bool,
    /// Removed key (now `limit_mode`): reading it is an error naming its successor.
    #[doc(hidden)]
    #[serde(default, skip_serializing, deserialize_with = "removed::robust_mode")]
    pub robust_mode: (),
    /// Removed key (now `fusion.engine.monitor.window`).
    #[doc(hidden)]
    #[serde(default, skip_serializing, deserialize_with = "removed::nis_window")]
    pub nis_window: (),
    /// Removed key (the monitor counts the fraction of its window above
    /// the gate, `fusion.engine.monitor.fraction`; 0.5 is the former median).
    #[doc(hidden)]
    #[serde(default, skip_serializing, deserialize_with = "removed::nis_statistic")]
    pub nis_statistic: (),
    /// Removed key (now `fusion.engine.monitor.gate_per_dim`).
    #[doc(hidden)]
    #[serde(default, skip_serializing, deserialize_with = "removed::nis_threshold")]
    pub nis_threshold: (),
    /// Removed key (now `fusion.engine.monitor.max_reject_run_s`).
    #[doc(hidden)]
    #[serde(
        default,
        skip_serializing,
        deserialize_with = "removed::max_reject_run_s"
    )]
    pub max_reject_run_s: (),
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
            range_sigma_m: 0.1,
            tdoa_sigma_adapt_time_s: 0.0,
            range_sigma_adapt_time_s: 0.0,
            sigma_adapt_min_m: 0.01,
            tdoa_corr_time_s: 0.25,
            range_corr_time_s: 0.25,
            tdoa_anchor_sigma_m: 0.0,
            tdoa_anchor_corr_time_s: 0.2,
            tdoa_anchor_highpass_s: 0.0,
            tdoa_r_inflation: 1.0,
            min_interval_per_pair_s: 0.0,
            limit_mode: LimitMode::ScaleInnovation,
            kappa: 3.0,
            hard_gate_sigma: 8.0,
            max_dt_s: 0.1,
            q_adapt_time_s: 0.0,
            q_adapt_decay_factor: 20.0,
            q_scale_max: 100.0,
            yaw_min_excitation_mps2: 0.0,
            reset_jacobian: true,
            robust_mode: (),
            nis_window: (),
            nis_statistic: (),
            nis_threshold: (),
            max_reject_run_s: (),
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
        check("range_sigma_m", self.range_sigma_m, "> 0", pos)?;
        check(
            "tdoa_sigma_adapt_time_s",
            self.tdoa_sigma_adapt_time_s,
            ">= 0",
            non_neg,
        )?;
        check(
            "range_sigma_adapt_time_s",
            self.range_sigma_adapt_time_s,
            ">= 0",
            non_neg,
        )?;
        check("sigma_adapt_min_m", self.sigma_adapt_min_m, "> 0", pos)?;
        check("tdoa_corr_time_s", self.tdoa_corr_time_s, ">= 0", non_neg)?;
        check("range_corr_time_s", self.range_corr_time_s, ">= 0", non_neg)?;
        check(
            "tdoa_anchor_sigma_m",
            self.tdoa_anchor_sigma_m,
            ">= 0",
            non_neg,
        )?;
        check(
            "tdoa_anchor_corr_time_s",
            self.tdoa_anchor_corr_time_s,
            "> 0",
            pos,
        )?;
        check(
            "tdoa_anchor_highpass_s",
            self.tdoa_anchor_highpass_s,
            ">= 0",
            non_neg,
        )?;
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
            serde_json::from_str(r#"{"kappa": 2.5, "limit_mode": "inflate_r"}"#).unwrap();
        assert_eq!(partial.kappa, 2.5);
        assert_eq!(partial.limit_mode, LimitMode::InflateR);
        assert_eq!(partial.tdoa_sigma_m, c.tdoa_sigma_m);
        let huber: EskfConfig = serde_json::from_str(r#"{"limit_mode": "huber"}"#).unwrap();
        assert_eq!(huber.limit_mode, LimitMode::ScaleInnovation);
        assert!(serde_json::from_str::<EskfConfig>(r#"{"kapa": 2.5}"#).is_err());
        assert!(!s.contains("robust_mode") && !s.contains("nis_"), "{s}");
    }

    /// The keys of the former robust weighting and monitor are refused with
    /// the key that replaces them.
    #[test]
    fn removed_keys_name_their_successor() {
        let e = |j: &str| {
            serde_json::from_str::<EskfConfig>(j)
                .unwrap_err()
                .to_string()
        };
        assert!(
            e(r#"{"robust_mode": "inflate_r"}"#).contains("renamed eskf.limit_mode"),
            "{}",
            e(r#"{"robust_mode": "inflate_r"}"#)
        );
        for key in [
            "nis_window",
            "nis_statistic",
            "nis_threshold",
            "max_reject_run_s",
        ] {
            let msg = e(&format!(r#"{{"{key}": 1}}"#));
            assert!(msg.contains("fusion.engine.monitor"), "{key}: {msg}");
        }
    }
}
