//! The INS side of the closed loop: mechanisation of raw IMU samples, static
//! alignment at start, and the correction protocol.
//!
//! A correction names the IMU sample after which it applies
//! (`apply_at_seq`). The engine keeps a ring of its recent states; when a
//! correction arrives it restores the state at that sample, applies the
//! correction and re-propagates the samples that came after it, and returns
//! the re-propagated navigation states (tagged with the correction id) for
//! publication. The result is therefore the same whether the correction
//! arrives at once (in process, `insuwb eval`) or a few samples late (the
//! process pipeline): one code path, the same floating-point operations.

use std::collections::VecDeque;

use insuwb_msg::{Header, ImuSample, InsCorrection, NavState, LAYOUT_VERSION};
use insuwb_nav::align::level_from_accel;
use insuwb_nav::ins::{Ins, InsConfig, InsState, NavOutput};
use insuwb_nav::vehicle::{HorizontalSignal, Mechanisation};
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// The INS's sensor bias estimates (alignment and corrections), body frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct InsBiases {
    /// Accelerometer bias, m/s^2.
    pub accel_mps2: [f64; 3],
    /// Gyro bias, rad/s.
    pub gyro_rps: [f64; 3],
}

/// How the INS attitude is initialised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AttitudeInit {
    /// Level (roll = pitch = 0), yaw from `init.yaw_rad`: a ground robot on a
    /// level floor, which may already be moving at start.
    Level,
    /// Roll and pitch from the mean specific force over the alignment
    /// window (the vehicle must be static then), yaw from `init.yaw_rad`.
    Accel,
}

/// Initial state of the INS.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InsInit {
    /// Initial position, ENU, m (a fusion engine with `init_from_first_fix`
    /// replaces it by the first UWB fix).
    pub pos_m: [f64; 3],
    /// Initial velocity, ENU, m/s.
    pub vel_mps: [f64; 3],
    /// Initial yaw, rad, counter-clockwise from east (from config or a
    /// magnetometer; with no magnetometer a filter with a large initial yaw
    /// variance makes it observable).
    pub yaw_rad: f64,
    /// How roll and pitch are found.
    pub attitude: AttitudeInit,
    /// Alignment window, s: samples in it are averaged for roll, pitch and the
    /// gyro bias (with `attitude = "accel"`); integration starts after it. 0
    /// starts at the first sample.
    pub align_window_s: f64,
    /// Estimate the gyro bias as the mean rate over the alignment window.
    pub gyro_bias_from_static: bool,
    /// End the alignment window early when the specific-force norm departs
    /// from its running mean by more than this (m/s^2): motion started.
    pub motion_threshold_mps2: f64,
    /// Length of the blocks whose mean specific-force norm is compared with
    /// the running mean for `motion_threshold_mps2`, s; 0 (default) tests
    /// every sample. Spinning motors shake a quadrotor's IMU by 0.3-2 m/s^2
    /// RMS on the floor (UTIL), which a per-sample test reads as motion
    /// within a few samples; block means keep the window open until
    /// lift-off, when the thrust moves the mean.
    pub motion_block_s: f64,
    /// Take the gyro bias from the window (`gyro_bias_from_static`) only
    /// when the rates' standard deviation over it (largest axis) is below
    /// this, rad/s; otherwise the bias starts at zero. Default infinity
    /// (always). With the motors spinning, the mean rate holds the
    /// vehicle's real rotation as it slides on the floor (UTIL: -3 to +5
    /// deg/s of yaw before lift-off) and is no bias; the IMU at rest shakes
    /// by about 0.003 rad/s, with the motors on by 0.1-0.3 rad/s.
    pub gyro_bias_max_sd_rps: f64,
}

impl Default for InsInit {
    fn default() -> Self {
        Self {
            pos_m: [0.0; 3],
            vel_mps: [0.0; 3],
            yaw_rad: 0.0,
            attitude: AttitudeInit::Level,
            align_window_s: 0.0,
            gyro_bias_from_static: false,
            motion_threshold_mps2: 1.0,
            motion_block_s: 0.0,
            gyro_bias_max_sd_rps: f64::INFINITY,
        }
    }
}

/// INS stage configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct InsEngineConfig {
    /// Mechanisation settings.
    pub ins: InsConfig,
    /// Initial state and alignment.
    pub init: InsInit,
    /// Constrain the INS to the horizontal plane (a ground robot): vertical
    /// velocity zero and height held at `init.pos_m[2]`.
    pub planar: bool,
    /// Samples kept for re-propagation after a late correction.
    pub history_len: usize,
    /// The multirotor's hand-over to the free model at run time; set from
    /// the fusion settings' `[fusion.multirotor]`, not from this table.
    #[serde(skip)]
    pub free_handover: Option<FreeHandover>,
}

/// When a multirotor INS hands over to the free model
/// (`[fusion.multirotor] free_above_signal_ratio`): after `window_s` of
/// integration, if the accelerometer's horizontal channels carried more
/// than `ratio` times their vibration in slow variation
/// ([`insuwb_nav::vehicle::HorizontalSignal`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FreeHandover {
    /// The ratio above which every axis is integrated.
    pub ratio: f64,
    /// Seconds of integration it is judged over.
    pub window_s: f64,
}

/// Where the hand-over stands.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Handover {
    /// Not configured, or judged: the configured model stays.
    Kept,
    /// Judging.
    Judging(HorizontalSignal),
    /// Handed over: every axis integrated.
    Free,
}

/// Why the INS engine could not be built.
#[derive(Debug, thiserror::Error)]
pub enum InsEngineError {
    /// The mechanisation config or initial state was refused.
    #[error("ins: {0}")]
    Ins(insuwb_nav::ins::InsNewError),
    /// A value out of range.
    #[error("ins engine: {key} {message}")]
    Invalid {
        /// The key.
        key: &'static str,
        /// What is wrong.
        message: String,
    },
}

impl From<insuwb_nav::ins::InsNewError> for InsEngineError {
    fn from(e: insuwb_nav::ins::InsNewError) -> Self {
        Self::Ins(e)
    }
}

/// Counters of what the INS engine dropped or did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct InsCounters {
    /// Samples integrated.
    pub integrated: u64,
    /// Samples dropped: wrong layout version.
    pub dropped_version: u64,
    /// Samples dropped: NaN, infinity or out of range
    /// ([`insuwb_msg::check::imu_values`]).
    pub dropped_invalid: u64,
    /// Samples dropped: timestamp not after the previous one.
    pub dropped_time: u64,
    /// Corrections applied.
    pub corrections: u64,
    /// Corrections ignored because their id was already applied.
    pub corrections_duplicate: u64,
    /// Corrections older than the history, applied to the current state.
    pub corrections_too_old: u64,
    /// Samples re-propagated after late corrections.
    pub repropagated: u64,
    /// Restarts of the IMU source seen (new generation).
    pub imu_restarts: u64,
}

#[derive(Debug, Clone)]
struct RingEntry {
    imu: ImuSample,
    ins_after: Ins,
    nav: NavState,
}

/// The INS engine.
#[derive(Debug, Clone)]
pub struct InsEngine {
    cfg: InsEngineConfig,
    ins: Option<Ins>,
    align: AlignAcc,
    ring: VecDeque<RingEntry>,
    correction_id: u64,
    imu_generation: Option<u32>,
    last_imu_t: Option<u64>,
    counters: InsCounters,
    out_seq: u64,
    reinit_flag: bool,
    handover: Handover,
}

#[derive(Debug, Clone, Default)]
struct AlignAcc {
    n: u64,
    t0: Option<u64>,
    acc_sum: [f64; 3],
    gyro_sum: [f64; 3],
    gyro_sq_sum: [f64; 3],
    norm_mean: f64,
    /// Samples folded into `norm_mean`.
    norm_n: u64,
    /// The open block of `motion_block_s`: start time, norm sum, samples.
    block_t0: Option<u64>,
    block_sum: f64,
    block_n: u64,
}

impl InsEngine {
    /// A new engine (not yet aligned).
    ///
    /// # Errors
    /// An invalid configuration.
    pub fn new(cfg: InsEngineConfig) -> Result<Self, InsEngineError> {
        cfg.ins.validate().map_err(|e| InsEngineError::Invalid {
            key: "ins",
            message: e.to_string(),
        })?;
        let i = &cfg.init;
        if !(i.align_window_s.is_finite() && (0.0..=60.0).contains(&i.align_window_s)) {
            return Err(InsEngineError::Invalid {
                key: "init.align_window_s",
                message: format!("must be in [0, 60] s, got {}", i.align_window_s),
            });
        }
        if !(i.motion_block_s.is_finite() && (0.0..=10.0).contains(&i.motion_block_s)) {
            return Err(InsEngineError::Invalid {
                key: "init.motion_block_s",
                message: format!("must be in [0, 10] s, got {}", i.motion_block_s),
            });
        }
        if i.gyro_bias_max_sd_rps.is_nan() || i.gyro_bias_max_sd_rps <= 0.0 {
            return Err(InsEngineError::Invalid {
                key: "init.gyro_bias_max_sd_rps",
                message: format!("must be > 0 rad/s, got {}", i.gyro_bias_max_sd_rps),
            });
        }
        if !i.pos_m.iter().chain(&i.vel_mps).all(|v| v.is_finite()) || !i.yaw_rad.is_finite() {
            return Err(InsEngineError::Invalid {
                key: "init",
                message: "pos_m, vel_mps and yaw_rad must be finite".into(),
            });
        }
        let history_len = if cfg.history_len == 0 {
            2048
        } else {
            cfg.history_len
        };
        Ok(Self {
            ring: crate::engine::prefaulted_deque(history_len),
            cfg: InsEngineConfig { history_len, ..cfg },
            ins: None,
            align: AlignAcc::default(),
            correction_id: 0,
            imu_generation: None,
            last_imu_t: None,
            counters: InsCounters::default(),
            out_seq: 0,
            reinit_flag: false,
            handover: Handover::Kept,
        })
    }

    /// Whether the INS handed over from the multirotor model to the free
    /// one ([`FreeHandover`]); its states then carry [`NavState::FLAG_FREE`].
    #[must_use]
    pub fn handed_over(&self) -> bool {
        self.handover == Handover::Free
    }

    /// The hand-over's state for an INS that starts now with the
    /// configured mechanisation.
    fn fresh_handover(&self) -> Handover {
        match (self.cfg.free_handover, self.cfg.ins.mechanisation) {
            (Some(h), Mechanisation::ThrustDrag { .. }) if h.ratio > 0.0 => {
                Handover::Judging(HorizontalSignal::default())
            }
            _ => Handover::Kept,
        }
    }

    /// Folds an integrated sample into the hand-over's judgement; hands
    /// over (the INS and its history) once judged above the ratio.
    fn judge_handover(&mut self, s: &ImuSample) {
        let Handover::Judging(mut sig) = self.handover else {
            return;
        };
        let Some(h) = self.cfg.free_handover else {
            self.handover = Handover::Kept;
            return;
        };
        sig.push(s.header.meas_time_ns, s.accel_mps2);
        if sig.span_s() < h.window_s {
            self.handover = Handover::Judging(sig);
            return;
        }
        if !sig.ratio().is_some_and(|r| r > h.ratio) {
            self.handover = Handover::Kept;
            return;
        }
        let Some(ins) = self.ins.as_mut() else {
            return;
        };
        if ins.set_mechanisation(Mechanisation::Free).is_err() {
            self.handover = Handover::Kept;
            return;
        }
        for e in &mut self.ring {
            let _ = e.ins_after.set_mechanisation(Mechanisation::Free);
        }
        self.handover = Handover::Free;
    }

    /// Counters so far.
    #[must_use]
    pub fn counters(&self) -> InsCounters {
        self.counters
    }

    /// Id of the last correction applied.
    #[must_use]
    pub fn correction_id(&self) -> u64 {
        self.correction_id
    }

    /// Whether alignment is done and the INS integrates.
    #[must_use]
    pub fn is_aligned(&self) -> bool {
        self.ins.is_some()
    }

    /// The current sensor bias estimates, if aligned (what a restarted INS
    /// needs to go on where this one stopped: a fused state carries none).
    #[must_use]
    pub fn biases(&self) -> Option<InsBiases> {
        let n = self.latest()?;
        Some(InsBiases {
            accel_mps2: n.accel_bias_mps2,
            gyro_rps: n.gyro_bias_rps,
        })
    }

    /// The latest navigation state, if aligned.
    #[must_use]
    pub fn latest(&self) -> Option<&NavState> {
        self.ring.back().map(|e| &e.nav)
    }

    /// Re-initialise from a fused state (a restarted INS): position,
    /// velocity and attitude are taken from `fused`, the sensor biases from
    /// `biases` (the previous generation's estimates; zero when unknown or
    /// not finite), the next IMU sample starts integration.
    pub fn reinit_from(
        &mut self,
        pos_m: [f64; 3],
        vel_mps: [f64; 3],
        quat: [f64; 4],
        biases: Option<InsBiases>,
        correction_id: u64,
    ) {
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            quat[0], quat[1], quat[2], quat[3],
        ));
        let b = biases
            .filter(|b| {
                b.accel_mps2
                    .iter()
                    .chain(&b.gyro_rps)
                    .all(|v| v.is_finite())
            })
            .unwrap_or_default();
        let st = InsState {
            pos_m: Vector3::from(pos_m),
            vel_mps: Vector3::from(vel_mps),
            att: q,
            accel_bias_mps2: Vector3::from(b.accel_mps2),
            gyro_bias_rps: Vector3::from(b.gyro_rps),
            ..InsState::default()
        };
        if let Ok(ins) = Ins::new(self.cfg.ins.clone(), st) {
            self.ins = Some(ins);
            self.handover = self.fresh_handover();
            self.ring.clear();
            self.correction_id = self.correction_id.max(correction_id);
            self.reinit_flag = true;
        }
    }

    /// Integrates one IMU sample. Returns the navigation state to publish,
    /// or `None` while aligning or when the sample was dropped (counted).
    pub fn on_imu(&mut self, s: &ImuSample) -> Option<NavState> {
        if s.header.layout_version != LAYOUT_VERSION {
            self.counters.dropped_version += 1;
            return None;
        }
        // The drivers' value check (their gate refuses such a sample
        // before it is published): a defensive check of other callers.
        if insuwb_msg::check::imu_values(s).is_err() {
            self.counters.dropped_invalid += 1;
            return None;
        }
        let t = s.header.meas_time_ns;
        if self.imu_generation != Some(s.header.generation) {
            if self.imu_generation.is_some() {
                self.counters.imu_restarts += 1;
                // A restarted driver restarts its sequence numbers: the ring
                // refers to the old generation, corrections for it are moot.
                self.ring.clear();
            }
            self.imu_generation = Some(s.header.generation);
        } else if let Some(last) = self.last_imu_t {
            if t <= last {
                self.counters.dropped_time += 1;
                return None;
            }
        }
        self.last_imu_t = Some(t);
        if self.ins.is_none() && !self.align_step(s) {
            return None;
        }
        let ins = self.ins.as_mut()?;
        let out = match ins.step(t, s.accel_mps2, s.gyro_rps) {
            Ok(o) => o,
            Err(_) => {
                self.counters.dropped_time += 1;
                return None;
            }
        };
        if self.cfg.planar {
            Self::constrain_planar(ins, self.cfg.init.pos_m[2]);
        }
        self.counters.integrated += 1;
        self.judge_handover(s);
        let nav = self.make_nav(s, &out);
        let ins_after = self.ins.clone()?;
        if self.ring.len() == self.cfg.history_len {
            self.ring.pop_front();
        }
        self.ring.push_back(RingEntry {
            imu: *s,
            ins_after,
            nav,
        });
        Some(nav)
    }

    fn constrain_planar(ins: &mut Ins, height: f64) {
        let mut st = *ins.state();
        st.vel_mps.z = 0.0;
        st.pos_m.z = height;
        let _ = ins.reset(st);
    }

    fn make_nav(&mut self, s: &ImuSample, out: &NavOutput) -> NavState {
        let mut flags = NavState::FLAG_ALIGNED;
        if self.reinit_flag {
            flags |= NavState::FLAG_REINIT;
        }
        if out.gap_clamped {
            flags |= NavState::FLAG_GAP;
        }
        if self.handover == Handover::Free {
            flags |= NavState::FLAG_FREE;
        }
        let nav_seq = self.out_seq;
        self.out_seq += 1;
        NavState {
            header: Header {
                layout_version: LAYOUT_VERSION,
                flags,
                seq: nav_seq,
                meas_time_ns: s.header.meas_time_ns,
                ..Header::default()
            },
            correction_id: self.correction_id,
            imu_seq: s.header.seq,
            imu_generation: s.header.generation,
            reserved: 0,
            pos_m: out.pos_m,
            vel_mps: out.vel_mps,
            quat: out.quat,
            accel_nav_mps2: out.accel_nav_mps2,
            omega_nav_rps: out.omega_nav_rps,
            accel_bias_mps2: out.accel_bias_mps2,
            gyro_bias_rps: out.gyro_bias_rps,
        }
    }

    /// Accumulates the alignment window; returns true once the INS exists
    /// (this sample then starts integration).
    fn align_step(&mut self, s: &ImuSample) -> bool {
        let init = &self.cfg.init;
        let t = s.header.meas_time_ns;
        let a = &mut self.align;
        let t0 = *a.t0.get_or_insert(t);
        let norm = s.accel_mps2.iter().map(|v| v * v).sum::<f64>().sqrt();
        if init.align_window_s > 0.0 {
            let block_ns = (init.motion_block_s.max(0.0) * 1e9) as u64;
            let moving = if block_ns == 0 {
                a.n > 10 && (norm - a.norm_mean).abs() > init.motion_threshold_mps2
            } else {
                let b0 = *a.block_t0.get_or_insert(t);
                a.block_sum += norm;
                a.block_n += 1;
                let mut moving = false;
                if t.saturating_sub(b0) >= block_ns {
                    let mean = a.block_sum / a.block_n as f64;
                    moving =
                        a.norm_n > 0 && (mean - a.norm_mean).abs() > init.motion_threshold_mps2;
                    a.norm_n += a.block_n;
                    a.norm_mean += (mean - a.norm_mean) * a.block_n as f64 / a.norm_n as f64;
                    a.block_t0 = None;
                    a.block_sum = 0.0;
                    a.block_n = 0;
                }
                moving
            };
            let elapsed_s = (t - t0) as f64 * 1e-9;
            let done = a.n > 0 && (elapsed_s >= init.align_window_s || moving);
            if !done {
                a.n += 1;
                for i in 0..3 {
                    a.acc_sum[i] += s.accel_mps2[i];
                    a.gyro_sum[i] += s.gyro_rps[i];
                    a.gyro_sq_sum[i] += s.gyro_rps[i] * s.gyro_rps[i];
                }
                if block_ns == 0 {
                    a.norm_mean += (norm - a.norm_mean) / a.n as f64;
                }
                return false;
            }
        } else if a.n == 0 {
            a.n = 1;
            a.acc_sum = s.accel_mps2;
            a.gyro_sum = s.gyro_rps;
            a.gyro_sq_sum = s.gyro_rps.map(|g| g * g);
        }
        let n = a.n.max(1) as f64;
        let mean_acc = [a.acc_sum[0] / n, a.acc_sum[1] / n, a.acc_sum[2] / n];
        let mean_gyro = [a.gyro_sum[0] / n, a.gyro_sum[1] / n, a.gyro_sum[2] / n];
        let att = match init.attitude {
            AttitudeInit::Level => UnitQuaternion::from_euler_angles(0.0, 0.0, init.yaw_rad),
            AttitudeInit::Accel => level_from_accel(mean_acc, init.yaw_rad)
                .unwrap_or_else(|_| UnitQuaternion::from_euler_angles(0.0, 0.0, init.yaw_rad)),
        };
        let gyro_sd = (0..3)
            .map(|i| {
                (a.gyro_sq_sum[i] / n - mean_gyro[i] * mean_gyro[i])
                    .max(0.0)
                    .sqrt()
            })
            .fold(0.0, f64::max);
        let gyro_bias = if init.gyro_bias_from_static && gyro_sd <= init.gyro_bias_max_sd_rps {
            Vector3::from(mean_gyro)
        } else {
            Vector3::zeros()
        };
        let st = InsState {
            pos_m: Vector3::from(init.pos_m),
            vel_mps: Vector3::from(init.vel_mps),
            att,
            gyro_bias_rps: gyro_bias,
            accel_bias_mps2: Vector3::zeros(),
            t_ns: t,
        };
        match Ins::new(self.cfg.ins.clone(), st) {
            Ok(ins) => {
                self.ins = Some(ins);
                self.handover = self.fresh_handover();
                true
            }
            Err(_) => false,
        }
    }

    /// Applies a correction. Returns the navigation states re-propagated
    /// after the sample it names (to be published; empty when the
    /// correction applies to the latest sample), or nothing for a duplicate.
    pub fn on_correction(&mut self, c: &InsCorrection, out: &mut Vec<NavState>) {
        out.clear();
        if c.header.layout_version != LAYOUT_VERSION {
            self.counters.dropped_version += 1;
            return;
        }
        if c.correction_id <= self.correction_id {
            self.counters.corrections_duplicate += 1;
            return;
        }
        let Some(ins) = self.ins.as_mut() else {
            return;
        };
        let pos = self.ring.iter().position(|e| {
            e.imu.header.seq == c.apply_at_seq && e.imu.header.generation == c.imu_generation
        });
        let Some(pos) = pos else {
            // Older than the history (or of a previous IMU generation): apply now.
            self.counters.corrections_too_old += 1;
            let _ = Self::apply(ins, c);
            self.correction_id = c.correction_id;
            return;
        };
        self.correction_id = c.correction_id;
        self.counters.corrections += 1;
        let mut ins_k = self.ring[pos].ins_after.clone();
        if Self::apply(&mut ins_k, c).is_err() {
            self.counters.dropped_invalid += 1;
            return;
        }
        if self.cfg.planar {
            Self::constrain_planar(&mut ins_k, self.cfg.init.pos_m[2]);
        }
        self.ring[pos].ins_after = ins_k.clone();
        self.ring[pos].nav.correction_id = c.correction_id;
        for i in pos + 1..self.ring.len() {
            let imu = self.ring[i].imu;
            if let Ok(o) = ins_k.step(imu.header.meas_time_ns, imu.accel_mps2, imu.gyro_rps) {
                if self.cfg.planar {
                    Self::constrain_planar(&mut ins_k, self.cfg.init.pos_m[2]);
                }
                let nav = self.make_nav(&imu, &o);
                self.ring[i].nav = nav;
                self.ring[i].ins_after = ins_k.clone();
                out.push(nav);
                self.counters.repropagated += 1;
            }
        }
        self.ins = Some(ins_k);
    }

    fn apply(ins: &mut Ins, c: &InsCorrection) -> Result<(), ()> {
        if c.header.flags & InsCorrection::FLAG_RESET != 0 {
            let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                c.reset_quat[0],
                c.reset_quat[1],
                c.reset_quat[2],
                c.reset_quat[3],
            ));
            let st = InsState {
                pos_m: Vector3::from(c.reset_pos_m),
                vel_mps: Vector3::from(c.reset_vel_mps),
                att: q,
                ..*ins.state()
            };
            return ins.reset(st).map_err(|_| ());
        }
        ins.apply_correction(
            c.d_pos_m,
            c.d_vel_mps,
            c.d_att_rad,
            c.d_accel_bias_mps2,
            c.d_gyro_bias_rps,
        )
        .map_err(|_| ())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;

    const G: f64 = 9.80665;

    /// A vehicle on the floor with its motors on for 2 s (1 kHz): the
    /// specific force shakes by +-1.5 m/s^2 sample to sample and the rates
    /// by +-0.2 rad/s around a real yaw rotation of 0.05 rad/s, then the
    /// thrust rises by 3 m/s^2 (lift-off). Returns the time (s) of the first
    /// navigation state, i.e. where the alignment ended, and its state.
    fn align_on_shaking_floor(init: InsInit) -> (f64, NavState) {
        let mut e = InsEngine::new(InsEngineConfig {
            init,
            ..InsEngineConfig::default()
        })
        .unwrap();
        for k in 0..3000u64 {
            let t = k as f64 * 1e-3;
            let shake = if k % 2 == 0 { 1.5 } else { -1.5 };
            let lift = if t >= 2.0 { 3.0 } else { 0.0 };
            let s = ImuSample {
                header: Header::new(k, k * 1_000_000),
                accel_mps2: [0.0, 0.0, G + shake + lift],
                gyro_rps: [shake * 0.13, -shake * 0.13, 0.05],
            };
            if let Some(n) = e.on_imu(&s) {
                return (t, n);
            }
        }
        panic!("never aligned");
    }

    #[test]
    fn block_means_keep_the_alignment_open_until_lift_off() {
        let init = InsInit {
            attitude: AttitudeInit::Accel,
            align_window_s: 10.0,
            gyro_bias_from_static: true,
            motion_threshold_mps2: 0.5,
            ..InsInit::default()
        };
        // Per sample, the shaking ends the window at once.
        let (t, _) = align_on_shaking_floor(init.clone());
        assert!(t < 0.05, "{t}");
        // 50 ms blocks: open until lift-off at 2 s.
        let (t, nav) = align_on_shaking_floor(InsInit {
            motion_block_s: 0.05,
            ..init.clone()
        });
        assert!((2.0..2.1).contains(&t), "{t}");
        // The window's mean rate holds the real yaw rotation: taken as a
        // bias unless the rates' spread says the IMU was not still.
        assert!((nav.gyro_bias_rps[2] - 0.05).abs() < 1e-6, "{nav:?}");
        let (_, nav) = align_on_shaking_floor(InsInit {
            motion_block_s: 0.05,
            gyro_bias_max_sd_rps: 0.02,
            ..init
        });
        assert_eq!(nav.gyro_bias_rps, [0.0; 3]);
    }

    /// A multirotor INS judged over 3 s: channels that follow a slow
    /// motion hand over to the free model (every later state flagged, the
    /// INS integrating every axis); channels of vibration do not.
    #[test]
    fn quiet_channels_that_follow_the_motion_hand_over_to_the_free_model() {
        let run = |follows: bool| {
            let mut cfg = InsEngineConfig {
                init: InsInit {
                    align_window_s: 0.0,
                    ..InsInit::default()
                },
                free_handover: Some(FreeHandover {
                    ratio: 1.4,
                    window_s: 3.0,
                }),
                ..InsEngineConfig::default()
            };
            cfg.ins.mechanisation = Mechanisation::ThrustDrag { drag_per_s: 0.3 };
            let mut e = InsEngine::new(cfg).unwrap();
            let mut flags = Vec::new();
            for k in 0..5000u64 {
                let t = k as f64 * 1e-3;
                let shake = if k % 2 == 0 { 1.0 } else { -1.0 };
                let (ax, ay) = if follows {
                    (
                        0.8 * (2.0 * t).sin() + 0.1 * shake,
                        0.6 * (1.3 * t).cos() - 0.1 * shake,
                    )
                } else {
                    (0.05 * (2.0 * t).sin() + 1.5 * shake, -1.5 * shake)
                };
                let s = ImuSample {
                    header: Header::new(k, k * 1_000_000),
                    accel_mps2: [ax, ay, G],
                    gyro_rps: [0.0; 3],
                };
                if let Some(n) = e.on_imu(&s) {
                    flags.push((t, n.header.flags & NavState::FLAG_FREE != 0));
                }
            }
            (e, flags)
        };
        let (e, flags) = run(true);
        assert!(e.handed_over());
        assert_eq!(
            e.ins.as_ref().map(|i| i.config().mechanisation),
            Some(Mechanisation::Free)
        );
        let first = flags.iter().find(|f| f.1).map(|f| f.0).unwrap();
        assert!((2.9..3.1).contains(&first), "{first}");
        assert!(flags.iter().skip_while(|f| !f.1).all(|f| f.1));
        let (e, flags) = run(false);
        assert!(!e.handed_over());
        assert!(flags.iter().all(|f| !f.1));
    }

    #[test]
    fn alignment_settings_are_checked() {
        for (init, key) in [
            (
                InsInit {
                    motion_block_s: -1.0,
                    ..InsInit::default()
                },
                "init.motion_block_s",
            ),
            (
                InsInit {
                    gyro_bias_max_sd_rps: 0.0,
                    ..InsInit::default()
                },
                "init.gyro_bias_max_sd_rps",
            ),
        ] {
            let e = InsEngine::new(InsEngineConfig {
                init,
                ..InsEngineConfig::default()
            })
            .unwrap_err();
            assert!(e.to_string().contains(key), "{e}");
        }
    }
}
