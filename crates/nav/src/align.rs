//! Static alignment: levelling from the mean specific force, gyro bias from a
//! static record, and the [`StaticDetector`] that finds the initial static
//! phase of an IMU stream (whose means feed the alignment).
//!
//! Flat earth, as in [`crate::ins`]: at rest the gyro reads its bias only (no
//! earth rate) and the accelerometer reads `C^T [0, 0, g]`. Yaw is not
//! observable from a level accelerometer: it comes from configuration or a
//! magnetometer.

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::ins::InsState;

/// Smallest mean specific-force norm accepted for levelling, m/s^2: below it
/// the direction of gravity is not defined (free fall, or a broken sensor).
pub const MIN_LEVEL_ACCEL_MPS2: f64 = 1.0;

/// Why an alignment step failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AlignError {
    /// An input component is NaN or infinite.
    #[error("alignment input {field}[{index}] is not finite: {value}")]
    NonFinite {
        /// Input name.
        field: &'static str,
        /// Component index (0 for a scalar).
        index: usize,
        /// Offending value.
        value: f64,
    },
    /// The mean specific force is too small to define the vertical.
    #[error("mean specific force norm {norm_mps2} m/s^2 is below {MIN_LEVEL_ACCEL_MPS2} m/s^2: cannot level")]
    NoGravity {
        /// Norm of the mean specific force, m/s^2.
        norm_mps2: f64,
    },
}

fn finite3(v: &[f64; 3], field: &'static str) -> Result<(), AlignError> {
    for (index, &value) in v.iter().enumerate() {
        if !value.is_finite() {
            return Err(AlignError::NonFinite {
                field,
                index,
                value,
            });
        }
    }
    Ok(())
}

/// Attitude (body to ENU) from the mean static specific force `mean_accel_b`
/// (m/s^2, body) and a given yaw (rad, counter-clockwise from east).
///
/// At rest `f_b = g [-sin(pitch), sin(roll) cos(pitch), cos(roll) cos(pitch)]`
/// for the ZYX attitude `Rz(yaw) Ry(pitch) Rx(roll)`, so
/// `roll = atan2(f_y, f_z)`, `pitch = atan2(-f_x, sqrt(f_y^2 + f_z^2))`.
/// The result's heading ([`crate::ins::yaw_of`]) is `yaw_rad`.
///
/// # Errors
/// A non-finite input, or a mean specific force below [`MIN_LEVEL_ACCEL_MPS2`].
pub fn level_from_accel(
    mean_accel_b: [f64; 3],
    yaw_rad: f64,
) -> Result<UnitQuaternion<f64>, AlignError> {
    finite3(&mean_accel_b, "mean_accel_b")?;
    if !yaw_rad.is_finite() {
        return Err(AlignError::NonFinite {
            field: "yaw_rad",
            index: 0,
            value: yaw_rad,
        });
    }
    let [fx, fy, fz] = mean_accel_b;
    let norm_mps2 = (fx * fx + fy * fy + fz * fz).sqrt();
    if norm_mps2 < MIN_LEVEL_ACCEL_MPS2 {
        return Err(AlignError::NoGravity { norm_mps2 });
    }
    let roll = fy.atan2(fz);
    let pitch = (-fx).atan2((fy * fy + fz * fz).sqrt());
    Ok(UnitQuaternion::from_euler_angles(roll, pitch, yaw_rad))
}

/// Gyro bias (body, rad/s) from the mean gyro reading over a static record:
/// with no earth rate (flat earth) it is the mean itself.
///
/// # Errors
/// A non-finite component.
pub fn gyro_bias_from_static(mean_gyro_b: [f64; 3]) -> Result<Vector3<f64>, AlignError> {
    finite3(&mean_gyro_b, "mean_gyro_b")?;
    Ok(Vector3::from(mean_gyro_b))
}

/// Initial INS state from a static segment: at `pos_m` (ENU, m), at rest,
/// levelled from the segment's mean specific force with heading `yaw_rad`,
/// gyro bias from the segment's mean rate, zero accelerometer bias (not
/// separable from tilt by a static record), at the segment's end time.
///
/// # Errors
/// As [`level_from_accel`] and [`gyro_bias_from_static`], or a non-finite `pos_m`.
pub fn initial_state(
    segment: &StaticSegment,
    yaw_rad: f64,
    pos_m: [f64; 3],
) -> Result<InsState, AlignError> {
    finite3(&pos_m, "pos_m")?;
    Ok(InsState {
        pos_m: Vector3::from(pos_m),
        vel_mps: Vector3::zeros(),
        att: level_from_accel(segment.mean_accel_b, yaw_rad)?,
        accel_bias_mps2: Vector3::zeros(),
        gyro_bias_rps: gyro_bias_from_static(segment.mean_gyro_b)?,
        t_ns: segment.end_ns,
    })
}

/// Configuration of the [`StaticDetector`].
///
/// A sliding window of `window_s` is static when the mean accelerometer norm
/// lies in `[accel_norm_min_mps2, accel_norm_max_mps2]`, the RMS deviation of
/// the accelerometer vector from its window mean (`sqrt` of the trace of its
/// covariance; rotation invariant, and unlike the norm's spread it also sees
/// horizontal vibration) is at most `accel_dev_max_mps2`, and the mean gyro
/// norm is at most `gyro_norm_max_rps`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StaticDetectorConfig {
    /// Length of the sliding window, s. Default 0.05 s: short enough to see
    /// the ~0.17 s static start of the UTIL flight logs. Valid range (0, 10].
    pub window_s: f64,
    /// Shortest static segment accepted, s; a shorter run is skipped and the
    /// search goes on. Default 0.1 s (the UTIL flight logs give ~0.17 s).
    /// Valid range [0, 3600].
    pub min_duration_s: f64,
    /// Lowest mean accelerometer norm of a static window, m/s^2. Default 9.3
    /// (g minus 0.5, room for accelerometer scale error). Must be < the max.
    pub accel_norm_min_mps2: f64,
    /// Highest mean accelerometer norm of a static window, m/s^2. Default 10.3.
    pub accel_norm_max_mps2: f64,
    /// Largest RMS deviation of the accelerometer vector in a static window,
    /// m/s^2. Default 0.2: MEMS noise at rest is below ~0.1, spinning
    /// Crazyflie motors give 0.4-0.8 (UTIL logs). Must be > 0.
    pub accel_dev_max_mps2: f64,
    /// Largest mean gyro norm of a static window, rad/s (bias included).
    /// Default 0.1 rad/s (5.7 deg/s). Must be > 0.
    pub gyro_norm_max_rps: f64,
    /// Time left out of the averaged segment at the start of a run and at an
    /// end closed by motion, s, where a passing window may still hold a few
    /// samples of motion. Default 0.025 s (half the window). Valid range
    /// [0, window_s].
    pub edge_trim_s: f64,
    /// Capacity of the window buffer, samples, allocated once; at a rate above
    /// `max_window_samples / window_s` the window holds only the newest
    /// samples. Default 1024 (20 kHz at 0.05 s). Valid range [3, 1_000_000].
    pub max_window_samples: usize,
}

impl Default for StaticDetectorConfig {
    fn default() -> Self {
        Self {
            window_s: 0.05,
            min_duration_s: 0.1,
            accel_norm_min_mps2: 9.3,
            accel_norm_max_mps2: 10.3,
            accel_dev_max_mps2: 0.2,
            gyro_norm_max_rps: 0.1,
            edge_trim_s: 0.025,
            max_window_samples: 1024,
        }
    }
}

/// Why a [`StaticDetectorConfig`] was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum StaticDetectorConfigError {
    /// `window_s` out of (0, 10].
    #[error("static.window_s must be in (0, 10] s, got {0}")]
    Window(f64),
    /// `min_duration_s` out of [0, 3600].
    #[error("static.min_duration_s must be in [0, 3600] s, got {0}")]
    MinDuration(f64),
    /// The accelerometer norm band is empty or not finite.
    #[error("static.accel_norm_min_mps2 ({min}) must be finite, >= 0 and below static.accel_norm_max_mps2 ({max})")]
    AccelNormBand {
        /// Configured minimum.
        min: f64,
        /// Configured maximum.
        max: f64,
    },
    /// `accel_dev_max_mps2` not finite and > 0.
    #[error("static.accel_dev_max_mps2 must be finite and > 0, got {0}")]
    AccelDev(f64),
    /// `gyro_norm_max_rps` not finite and > 0.
    #[error("static.gyro_norm_max_rps must be finite and > 0, got {0}")]
    GyroNorm(f64),
    /// `edge_trim_s` out of [0, window_s].
    #[error(
        "static.edge_trim_s must be in [0, static.window_s = {window_s}] s, got {edge_trim_s}"
    )]
    EdgeTrim {
        /// Configured trim, s.
        edge_trim_s: f64,
        /// Configured window, s.
        window_s: f64,
    },
    /// `max_window_samples` out of [3, 1_000_000].
    #[error("static.max_window_samples must be in [3, 1000000], got {0}")]
    Capacity(usize),
}

impl StaticDetectorConfig {
    /// Check every field against its documented range.
    ///
    /// # Errors
    /// The first field out of range, with its value.
    pub fn validate(&self) -> Result<(), StaticDetectorConfigError> {
        type E = StaticDetectorConfigError;
        if !(self.window_s > 0.0 && self.window_s <= 10.0) {
            return Err(E::Window(self.window_s));
        }
        if !(0.0..=3600.0).contains(&self.min_duration_s) {
            return Err(E::MinDuration(self.min_duration_s));
        }
        let (min, max) = (self.accel_norm_min_mps2, self.accel_norm_max_mps2);
        if !(min >= 0.0 && max.is_finite() && min < max) {
            return Err(E::AccelNormBand { min, max });
        }
        if !(self.accel_dev_max_mps2 > 0.0 && self.accel_dev_max_mps2.is_finite()) {
            return Err(E::AccelDev(self.accel_dev_max_mps2));
        }
        if !(self.gyro_norm_max_rps > 0.0 && self.gyro_norm_max_rps.is_finite()) {
            return Err(E::GyroNorm(self.gyro_norm_max_rps));
        }
        if !(0.0..=self.window_s).contains(&self.edge_trim_s) {
            return Err(E::EdgeTrim {
                edge_trim_s: self.edge_trim_s,
                window_s: self.window_s,
            });
        }
        if !(3..=1_000_000).contains(&self.max_window_samples) {
            return Err(E::Capacity(self.max_window_samples));
        }
        Ok(())
    }
}

/// Why [`StaticDetector::push`] refused a sample; the detector is unchanged.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum StaticDetectError {
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
    /// The sample time does not come after the previous one.
    #[error(
        "IMU sample time {t_ns} ns does not come after the previous sample time {prev_t_ns} ns"
    )]
    TimeNotIncreasing {
        /// Time of the refused sample, ns.
        t_ns: u64,
        /// Time of the previous sample, ns.
        prev_t_ns: u64,
    },
}

/// A static segment found by the [`StaticDetector`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticSegment {
    /// Time of the first sample averaged, ns (`edge_trim_s` after the first
    /// sample of the run's first static window).
    pub start_ns: u64,
    /// Time of the last sample averaged, ns: the end of the static phase
    /// (`edge_trim_s` before the last sample of the last static window when
    /// motion ended the run).
    pub end_ns: u64,
    /// Mean specific force over the segment (body), m/s^2.
    pub mean_accel_b: [f64; 3],
    /// Mean angular rate over the segment (body), rad/s.
    pub mean_gyro_b: [f64; 3],
    /// Number of samples averaged.
    pub n_samples: u64,
}

impl StaticSegment {
    /// Duration `end - start`, s.
    #[must_use]
    pub fn duration_s(&self) -> f64 {
        self.end_ns.saturating_sub(self.start_ns) as f64 * 1e-9
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    t_ns: u64,
    accel: Vector3<f64>,
    gyro: Vector3<f64>,
}

/// A static run being accumulated.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Run {
    /// First sample of the first static window, ns.
    start_ns: u64,
    /// Last sample of the last static window, ns.
    end_ns: u64,
    /// First and last sample averaged so far, ns.
    first_committed_ns: Option<u64>,
    last_committed_ns: Option<u64>,
    sum_accel: Vector3<f64>,
    sum_gyro: Vector3<f64>,
    n: u64,
}

/// Finds the first static segment of an IMU stream (see
/// [`StaticDetectorConfig`] for the test of a window).
///
/// Feed samples in time order with [`StaticDetector::push`]. A static run
/// lasts from the first sample of its first static window to the last sample
/// of its last static window; it counts when that is at least
/// `min_duration_s`, and ends at the first non-static window or at a time gap
/// longer than the window (a stream that ends while static is closed by
/// [`StaticDetector::finish`]). A window can pass with a few samples of motion
/// at its edge, so the segment reported (its times and means) leaves out
/// `edge_trim_s` at the start of the run and, when motion closed it, at its
/// end. `push` returns the segment once, at the sample that closes it.
/// The window buffer is allocated once, at construction; a push does not
/// allocate.
#[derive(Debug, Clone, PartialEq)]
pub struct StaticDetector {
    cfg: StaticDetectorConfig,
    window_ns: u64,
    min_duration_ns: u64,
    trim_ns: u64,
    buf: VecDeque<Sample>,
    /// Time of the first sample since the window (re)started.
    origin_ns: Option<u64>,
    last_t_ns: Option<u64>,
    run: Option<Run>,
    found: Option<StaticSegment>,
}

impl StaticDetector {
    /// A detector with a validated configuration.
    ///
    /// # Errors
    /// The configuration's first invalid field.
    pub fn new(cfg: StaticDetectorConfig) -> Result<Self, StaticDetectorConfigError> {
        cfg.validate()?;
        // In range by validation (<= 3600 s), so the conversions are exact to the ns.
        let window_ns = (cfg.window_s * 1e9).round() as u64;
        let min_duration_ns = (cfg.min_duration_s * 1e9).round() as u64;
        let trim_ns = (cfg.edge_trim_s * 1e9).round() as u64;
        let buf = VecDeque::with_capacity(cfg.max_window_samples);
        Ok(Self {
            cfg,
            window_ns,
            min_duration_ns,
            trim_ns,
            buf,
            origin_ns: None,
            last_t_ns: None,
            run: None,
            found: None,
        })
    }

    /// The segment found, if any.
    #[must_use]
    pub fn segment(&self) -> Option<&StaticSegment> {
        self.found.as_ref()
    }

    /// Take one raw IMU sample (specific force m/s^2, rate rad/s, body).
    /// Returns the first static segment at the sample that closes it, once;
    /// after that samples are only checked, not used.
    ///
    /// # Errors
    /// A non-finite component or a time not after the previous sample; the
    /// detector is then unchanged.
    pub fn push(
        &mut self,
        t_ns: u64,
        accel_b: [f64; 3],
        gyro_b: [f64; 3],
    ) -> Result<Option<StaticSegment>, StaticDetectError> {
        for (field, v) in [("accel_b", &accel_b), ("gyro_b", &gyro_b)] {
            for (index, &value) in v.iter().enumerate() {
                if !value.is_finite() {
                    return Err(StaticDetectError::NonFinite {
                        field,
                        index,
                        value,
                    });
                }
            }
        }
        if let Some(prev_t_ns) = self.last_t_ns {
            if t_ns <= prev_t_ns {
                return Err(StaticDetectError::TimeNotIncreasing { t_ns, prev_t_ns });
            }
        }
        self.last_t_ns = Some(t_ns);
        if self.found.is_some() {
            return Ok(None);
        }

        // A gap longer than the window ends any run (its samples up to the gap
        // are static) and restarts the window.
        let gap = self
            .buf
            .back()
            .is_some_and(|s| t_ns - s.t_ns > self.window_ns);
        let mut closed = None;
        if gap {
            if let Some(end_ns) = self.run.map(|r| r.end_ns) {
                self.commit(end_ns);
                closed = self.close_run();
            }
            self.run = None;
            self.buf.clear();
            self.origin_ns = None;
            if closed.is_some() {
                return Ok(closed);
            }
        }

        let sample = Sample {
            t_ns,
            accel: Vector3::from(accel_b),
            gyro: Vector3::from(gyro_b),
        };
        let origin_ns = *self.origin_ns.get_or_insert(t_ns);
        while self
            .buf
            .front()
            .is_some_and(|s| s.t_ns + self.window_ns < t_ns)
        {
            self.buf.pop_front();
        }
        if self.buf.len() >= self.cfg.max_window_samples {
            self.buf.pop_front();
        }
        self.buf.push_back(sample);

        if t_ns - origin_ns < self.window_ns || self.buf.len() < 3 {
            return Ok(None);
        }
        if self.window_is_static() {
            let front_ns = self.buf.front().map_or(t_ns, |s| s.t_ns);
            let run = self.run.get_or_insert(Run {
                start_ns: front_ns,
                end_ns: t_ns,
                first_committed_ns: None,
                last_committed_ns: None,
                sum_accel: Vector3::zeros(),
                sum_gyro: Vector3::zeros(),
                n: 0,
            });
            run.end_ns = t_ns;
            self.commit(t_ns.saturating_sub(self.trim_ns));
            Ok(None)
        } else {
            Ok(self.close_run())
        }
    }

    /// End of stream: close a static run still open (a stream static to its
    /// end; no trim at the end). Returns the segment found, if any.
    pub fn finish(&mut self) -> Option<StaticSegment> {
        if self.found.is_none() {
            if let Some(end_ns) = self.run.map(|r| r.end_ns) {
                self.commit(end_ns);
                self.close_run();
            }
        }
        self.found
    }

    /// Average the buffered samples of the run from `start + trim` up to `until_ns`.
    fn commit(&mut self, until_ns: u64) {
        let Some(run) = self.run.as_mut() else {
            return;
        };
        let from_ns = run.start_ns.saturating_add(self.trim_ns);
        for s in &self.buf {
            let new = run.last_committed_ns.is_none_or(|l| s.t_ns > l);
            if new && s.t_ns >= from_ns && s.t_ns <= until_ns && s.t_ns <= run.end_ns {
                run.sum_accel += s.accel;
                run.sum_gyro += s.gyro;
                run.n += 1;
                run.first_committed_ns.get_or_insert(s.t_ns);
                run.last_committed_ns = Some(s.t_ns);
            }
        }
    }

    /// End the current run: keep it as the result if long enough.
    fn close_run(&mut self) -> Option<StaticSegment> {
        let run = self.run.take()?;
        if run.end_ns - run.start_ns < self.min_duration_ns || run.n == 0 {
            return None;
        }
        let n = run.n as f64;
        let seg = StaticSegment {
            start_ns: run.first_committed_ns.unwrap_or(run.start_ns),
            end_ns: run.last_committed_ns.unwrap_or(run.end_ns),
            mean_accel_b: (run.sum_accel / n).into(),
            mean_gyro_b: (run.sum_gyro / n).into(),
            n_samples: run.n,
        };
        self.found = Some(seg);
        self.buf.clear();
        Some(seg)
    }

    fn window_is_static(&self) -> bool {
        let n = self.buf.len() as f64;
        let mut sum_a = Vector3::zeros();
        let mut sum_norm_a = 0.0;
        let mut sum_norm_g = 0.0;
        for s in &self.buf {
            sum_a += s.accel;
            sum_norm_a += s.accel.norm();
            sum_norm_g += s.gyro.norm();
        }
        let mean_a = sum_a / n;
        let var_a = self
            .buf
            .iter()
            .map(|s| (s.accel - mean_a).norm_squared())
            .sum::<f64>()
            / n;
        let mean_norm_a = sum_norm_a / n;
        let mean_norm_g = sum_norm_g / n;
        (self.cfg.accel_norm_min_mps2..=self.cfg.accel_norm_max_mps2).contains(&mean_norm_a)
            && var_a.sqrt() <= self.cfg.accel_dev_max_mps2
            && mean_norm_g <= self.cfg.gyro_norm_max_rps
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ins::{yaw_of, STANDARD_GRAVITY_MPS2 as G};
    use crate::testutil::Gauss;

    #[test]
    fn level_recovers_a_known_tilt() {
        for (roll, pitch, yaw) in [
            (0.2, -0.35, 1.0),
            (-1.0, 0.6, -2.5),
            (0.0, 0.0, 0.0),
            (2.8, 0.1, 0.3), // upside down
        ] {
            let q = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
            let f_b = q.inverse() * Vector3::new(0.0, 0.0, 9.79);
            let got = level_from_accel(f_b.into(), yaw).unwrap();
            let (r, p, y) = got.euler_angles();
            assert!((r - roll).abs() < 1e-9, "roll {r} vs {roll}");
            assert!((p - pitch).abs() < 1e-9, "pitch {p} vs {pitch}");
            assert!((y - yaw).abs() < 1e-9 && (yaw_of(&got) - yaw).abs() < 1e-9);
            assert!(got.angle_to(&q) < 1e-9);
        }
        // Hand value: f_b = [0, g sin 30, g cos 30] is a 30 deg roll.
        let q = level_from_accel([0.0, 0.5 * G, 0.75f64.sqrt() * G], 0.0).unwrap();
        assert!((q.euler_angles().0 - 30f64.to_radians()).abs() < 1e-12);
        // Body x up-tilted: f_b = [-g sin p, 0, g cos p] is a pitch of +p.
        let p = 0.25f64;
        let q = level_from_accel([-G * p.sin(), 0.0, G * p.cos()], 0.0).unwrap();
        assert!((q.euler_angles().1 - p).abs() < 1e-12);
    }

    #[test]
    fn level_refuses_bad_input() {
        let e = level_from_accel([0.1, 0.0, 0.2], 0.0).unwrap_err();
        assert!(
            matches!(e, AlignError::NoGravity { norm_mps2 } if (norm_mps2 - 0.05f64.sqrt()).abs() < 1e-15),
            "{e}"
        );
        let e = level_from_accel([0.0, 0.0, 9.8], f64::NAN).unwrap_err();
        assert!(e.to_string().contains("yaw_rad"), "{e}");
        assert!(level_from_accel([f64::INFINITY, 0.0, 9.8], 0.0).is_err());
        assert!(gyro_bias_from_static([0.0, f64::NAN, 0.0]).is_err());
        assert_eq!(
            gyro_bias_from_static([0.01, -0.02, 0.003]).unwrap(),
            Vector3::new(0.01, -0.02, 0.003)
        );
    }

    /// Synthetic IMU record: static with noise until `t_static_s`, then
    /// `motion(t)` gives (specific force, rate) without noise added.
    struct Synth {
        rate_hz: f64,
        duration_s: f64,
        t_static_s: f64,
        f_static: Vector3<f64>,
        gyro_bias: Vector3<f64>,
    }

    fn run_detector(
        cfg: StaticDetectorConfig,
        sy: &Synth,
        motion: impl Fn(f64, &mut Gauss) -> (Vector3<f64>, Vector3<f64>),
    ) -> Option<StaticSegment> {
        let mut det = StaticDetector::new(cfg).unwrap();
        let mut g = Gauss::new(42);
        let n = (sy.duration_s * sy.rate_hz) as u64;
        let mut found = None;
        for k in 0..n {
            let t = k as f64 / sy.rate_hz;
            let t_ns = (t * 1e9).round() as u64;
            let noise_a = Vector3::new(g.sample(), g.sample(), g.sample()) * 0.03;
            let noise_g = Vector3::new(g.sample(), g.sample(), g.sample()) * 0.003;
            let (f, w) = if t < sy.t_static_s {
                (sy.f_static, sy.gyro_bias)
            } else {
                let (f, w) = motion(t, &mut g);
                (f, w + sy.gyro_bias)
            };
            let r = det
                .push(t_ns, (f + noise_a).into(), (w + noise_g).into())
                .unwrap();
            if let Some(seg) = r {
                assert!(found.is_none(), "reported twice");
                found = Some(seg);
            }
        }
        found.or_else(|| det.finish())
    }

    fn tilted_static() -> Vector3<f64> {
        UnitQuaternion::from_euler_angles(0.05, -0.03, 0.0).inverse() * Vector3::new(0.0, 0.0, G)
    }

    #[test]
    fn finds_the_end_of_an_8_s_static_segment() {
        let sy = Synth {
            rate_hz: 1000.0,
            duration_s: 12.0,
            t_static_s: 8.0,
            f_static: tilted_static(),
            gyro_bias: Vector3::new(0.01, -0.005, 0.008),
        };
        // A ground robot pulling away gently: 0.5 m/s^2 forward, turning at 0.3 rad/s.
        let seg = run_detector(StaticDetectorConfig::default(), &sy, |_, _| {
            (
                sy.f_static + Vector3::new(0.5, 0.0, 0.0),
                Vector3::new(0.0, 0.0, 0.3),
            )
        })
        .unwrap();
        // Averaged from the edge trim (25 ms) to the onset of motion.
        assert_eq!(seg.start_ns, 25_000_000);
        let end_s = seg.end_ns as f64 * 1e-9;
        assert!((end_s - 8.0).abs() < 0.1, "{seg:?}");
        assert!(end_s < 8.0 && end_s > 7.97, "{seg:?}");
        // The means feed the alignment: levelling recovers the tilt within noise.
        let q = level_from_accel(seg.mean_accel_b, 0.0).unwrap();
        let (r, p, _) = q.euler_angles();
        assert!(
            (r - 0.05).abs() < 2e-3 && (p + 0.03).abs() < 2e-3,
            "{r} {p}"
        );
        let bg = gyro_bias_from_static(seg.mean_gyro_b).unwrap();
        assert!((bg - sy.gyro_bias).norm() < 2e-3, "{bg:?}");
        let st = initial_state(&seg, 0.4, [1.0, 2.0, 0.0]).unwrap();
        assert_eq!(st.t_ns, seg.end_ns);
        assert!((yaw_of(&st.att) - 0.4).abs() < 1e-12);
    }

    #[test]
    fn finds_a_short_017_s_static_start_before_motor_vibration() {
        // UTIL-like flight log: static 0.17 s, motors spin (vibration 0.3 m/s^2
        // per axis, 0.05 rad/s), lift-off at 1.2 s.
        for rate_hz in [1000.0, 100.0] {
            let sy = Synth {
                rate_hz,
                duration_s: 3.0,
                t_static_s: 0.17,
                f_static: tilted_static(),
                gyro_bias: Vector3::zeros(),
            };
            let seg = run_detector(StaticDetectorConfig::default(), &sy, |t, g| {
                let vib_a = Vector3::new(g.sample(), g.sample(), g.sample()) * 0.3;
                let vib_w = Vector3::new(g.sample(), g.sample(), g.sample()) * 0.05;
                let lift = if t > 1.2 {
                    Vector3::new(0.0, 0.0, 2.0)
                } else {
                    Vector3::zeros()
                };
                (sy.f_static + vib_a + lift, vib_w)
            })
            .unwrap();
            let end_s = seg.end_ns as f64 * 1e-9;
            let start_s = seg.start_ns as f64 * 1e-9;
            assert!((0.025..0.035).contains(&start_s), "{rate_hz} Hz: {seg:?}");
            // No vibrating sample is averaged, and the end is found within
            // 50 ms (the edge trim plus a sample or two at 100 Hz).
            assert!(end_s < 0.17 && end_s > 0.12, "{rate_hz} Hz: {seg:?}");
            assert!(seg.n_samples >= 10 && seg.duration_s() > 0.09, "{seg:?}");
        }
    }

    #[test]
    fn skips_a_static_run_shorter_than_min_duration() {
        // 0.06 s static, 0.5 s turning, then static until the end.
        let sy = Synth {
            rate_hz: 1000.0,
            duration_s: 2.0,
            t_static_s: 0.06,
            f_static: Vector3::new(0.0, 0.0, G),
            gyro_bias: Vector3::zeros(),
        };
        let seg = run_detector(StaticDetectorConfig::default(), &sy, |t, _| {
            let w = if t < 0.56 { 1.0 } else { 0.0 };
            (Vector3::new(0.0, 0.0, G), Vector3::new(0.0, 0.0, w))
        })
        .unwrap();
        // The second run's first static window still holds a few turning
        // samples (its mean rate is below 0.1 rad/s); the edge trim leaves
        // them out of the means. A stream static to its end is not trimmed.
        let start_s = seg.start_ns as f64 * 1e-9;
        assert!(start_s > 0.56 && start_s < 0.62, "{seg:?}");
        assert!((seg.end_ns as f64 * 1e-9 - 1.999).abs() < 1e-9);
        assert!(seg.mean_gyro_b[2].abs() < 5e-4, "{seg:?}");
    }

    #[test]
    fn detector_refuses_bad_samples_and_config() {
        let mut det = StaticDetector::new(StaticDetectorConfig::default()).unwrap();
        det.push(10, [0.0, 0.0, G], [0.0; 3]).unwrap();
        assert_eq!(
            det.push(10, [0.0, 0.0, G], [0.0; 3]),
            Err(StaticDetectError::TimeNotIncreasing {
                t_ns: 10,
                prev_t_ns: 10
            })
        );
        assert!(det.push(20, [0.0, 0.0, G], [0.0, f64::NAN, 0.0]).is_err());
        let e = StaticDetectorConfig {
            accel_norm_min_mps2: 11.0,
            ..StaticDetectorConfig::default()
        }
        .validate()
        .unwrap_err();
        assert!(
            e.to_string().starts_with("static.accel_norm_min_mps2 (11)"),
            "{e}"
        );
        assert!(StaticDetector::new(StaticDetectorConfig {
            window_s: 0.0,
            ..StaticDetectorConfig::default()
        })
        .is_err());
    }

    #[test]
    fn moving_stream_has_no_static_segment() {
        let sy = Synth {
            rate_hz: 200.0,
            duration_s: 2.0,
            t_static_s: 0.0,
            f_static: Vector3::new(0.0, 0.0, G),
            gyro_bias: Vector3::zeros(),
        };
        let seg = run_detector(StaticDetectorConfig::default(), &sy, |_, _| {
            (Vector3::new(0.0, 0.0, G), Vector3::new(0.5, 0.0, 0.0))
        });
        assert_eq!(seg, None);
    }
}
