//! The fusion side of the closed loop: measurement ordering, prediction
//! through the INS states, updates, corrections and fused outputs.
//!
//! Rules, which make the output independent of arrival order and scheduling:
//! - a measurement is processed as soon as the INS state covering its epoch
//!   (the first with a time at or after it) is there; measurements are taken
//!   in time order;
//! - the filter predicts through every INS interval in order;
//! - the INS position and velocity at the measurement epoch are interpolated
//!   between the two INS states around it;
//! - after an update (loose: every fix; tight: at the end of each fix epoch of
//!   TDOA measurements) the error estimate becomes an [`InsCorrection`]
//!   naming the INS sample it applies after, and the buffered INS states after
//!   that sample are dropped: the INS re-propagates and publishes them again
//!   with the new correction id;
//! - INS states that carry an older correction id than the last one sent are
//!   stale and ignored;
//! - a measurement older than the start of the INS interval processed last
//!   is late and dropped (counted); one inside it is interpolated (tight
//!   coupling: a fix arrives after the TDOA differences of its epoch moved
//!   the INS to or past it);
//! - the INS position is (re-)initialised from a UWB fix, once
//!   `reset_min_fixes` consecutive fixes agree within `reset_gate_m`;
//! - divergence: every update's NIS, of whichever filter, goes to one
//!   [`DivergenceMonitor`] ([`FusionEngineConfig::monitor`]); when it fires,
//!   the filter and the INS are re-initialised from agreeing fixes (as
//!   above), the fused states published until then lose
//!   [`FusedState::FLAG_VALID`], the reset's carries
//!   [`FusedState::FLAG_RESET`] and the first diagnostic after it
//!   [`FilterDiag::FLAG_RESET`].

use std::collections::VecDeque;

use insuwb_filter::{DivergenceMonitor, MonitorConfig, MonitorConfigError};
use insuwb_msg::{
    fixed_name, BodyVelocity, FilterDiag, FusedState, Header, Height, InsCorrection, NavState,
    UwbFix, UwbRange, UwbTdoa, LAYOUT_VERSION,
};
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::estimator::{Delta, Estimator, InsAt, UpdateInfo};

/// Fusion engine settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionEngineConfig {
    /// Frame id written into fused states.
    pub frame_id: String,
    /// Take the INS position (and velocity, when the fix has one) from the
    /// first UWB fix, instead of the configured initial state.
    pub init_from_first_fix: bool,
    /// Tight coupling: length of a correction epoch of TDOA measurements, s.
    pub tdoa_epoch_s: f64,
    /// Measurements waiting for INS data beyond this count are dropped (oldest first).
    pub max_pending: usize,
    /// INS states buffered beyond this count are dropped (oldest first).
    pub max_nav_buffer: usize,
    /// Re-initialise the filter and the INS from agreeing UWB fixes when the
    /// divergence monitor fires (or the estimator's covariance stops being
    /// finite). Default true.
    pub reset_on_divergence: bool,
    /// Initialisations and resets wait for this many consecutive UWB fixes
    /// that agree (each within `reset_gate_m` of the previous one) and take
    /// the last of them. Default 1 (the first fix). UWB near the floor can be
    /// off by metres, with fixes jumping from one epoch to the next (UTIL
    /// 0426 logs, dataset README): a few agreeing fixes skip that. At most
    /// [`MAX_RESET_FIXES`].
    pub reset_min_fixes: usize,
    /// Largest distance between two consecutive fixes that count as agreeing
    /// for `reset_min_fixes`, m (the motion over one fix period included).
    /// Default 0.3.
    pub reset_gate_m: f64,
    /// Take the velocity of an initialisation or reset from the fix's
    /// regression velocity when it has one (else zero). Default true. The
    /// regression over the last fixes is meaningless while UWB near the
    /// floor jumps by metres (UTIL: -2.2 m/s vertical from fixes at
    /// take-off); false starts from rest, with the filter's initial
    /// velocity uncertainty.
    pub reset_velocity_from_fix: bool,
    /// Predict through INS states as they arrive, keeping only the newest
    /// `eager_lag_s` of them buffered for measurements still on their way
    /// (None: predict only when a measurement needs it). The result is the
    /// same either way as long as no measurement arrives later than this
    /// behind the INS stream (one that does is dropped as late, counted);
    /// it takes the prediction off the measurement's path and lets the
    /// coasting covariance grow while UWB is silent. Default None; the
    /// fusion stage sets it in real time from its one home, robot.toml's
    /// `[fusion] eager_lag_s` (the fusion process's table): the estimator
    /// settings' `[fusion.engine] eager_lag_s` is refused, naming it.
    #[serde(skip)]
    pub eager_lag_s: Option<f64>,
    /// Refuses `[fusion.engine] eager_lag_s`, naming robot.toml's key.
    #[doc(hidden)]
    #[serde(
        default,
        rename = "eager_lag_s",
        skip_serializing,
        deserialize_with = "moved::eager_lag_s"
    )]
    pub eager_lag_s_elsewhere: (),
    /// The divergence monitor of every filter, tight or loose
    /// (`[fusion.engine.monitor]`): when at least `fraction` of the last
    /// `window` updates (fixes for the loose filters, TDOA differences for
    /// the tight one; rejected ones apart) have a NIS per measured
    /// component above `gate_per_dim`, or nothing but rejected updates came
    /// for longer than `max_reject_run_s`, the filter is deemed diverged and
    /// re-initialised from UWB (`reset_on_divergence`). Default 30 updates,
    /// 16 per component, 0.9, 1 s.
    pub monitor: MonitorConfig,
    /// Moved to `monitor.window`: reading it is an error naming the new key.
    #[doc(hidden)]
    #[serde(default, skip_serializing, deserialize_with = "moved::window")]
    pub nis_window: (),
    /// Moved to `monitor.gate_per_dim`.
    #[doc(hidden)]
    #[serde(default, skip_serializing, deserialize_with = "moved::gate_per_dim")]
    pub nis_gate_per_dim: (),
    /// Moved to `monitor.fraction`.
    #[doc(hidden)]
    #[serde(default, skip_serializing, deserialize_with = "moved::fraction")]
    pub nis_window_fraction: (),
}

/// Keys of earlier versions, refused with a message naming the key that
/// replaces them (the configuration loader adds the file and the key).
mod moved {
    use serde::de::{Deserializer, Error};

    macro_rules! moved {
        ($($name:ident => $msg:literal),* $(,)?) => {$(
            pub(super) fn $name<'de, D: Deserializer<'de>>(_: D) -> Result<(), D::Error> {
                Err(D::Error::custom($msg))
            }
        )*};
    }

    moved! {
        window => "moved to fusion.engine.monitor.window (the one divergence monitor of every filter)",
        gate_per_dim => "moved to fusion.engine.monitor.gate_per_dim (the one divergence monitor of every filter)",
        fraction => "moved to fusion.engine.monitor.fraction (the one divergence monitor of every filter)",
        eager_lag_s => "the fusion process's setting, set in robot.toml's [fusion] table (`[fusion] eager_lag_s`, see config/robot.toml), not in the estimator's settings; the lockstep runner of `insuwb eval` and replay predicts lazily",
    }
}

/// The unknown acceleration, m/s^2, by which a UWB-only pose
/// ([`FusionEngine::uwb_only_state`]) grows the last fused velocity's
/// variance when the fix carries no velocity: a robot or a small drone
/// indoors.
pub const UWB_ONLY_ACCEL_MPS2: f64 = 2.0;

/// Largest [`FusionEngineConfig::reset_min_fixes`].
pub const MAX_RESET_FIXES: usize = 64;

impl Default for FusionEngineConfig {
    fn default() -> Self {
        Self {
            frame_id: "map".into(),
            init_from_first_fix: false,
            tdoa_epoch_s: 0.1,
            max_pending: 8192,
            max_nav_buffer: 8192,
            reset_on_divergence: true,
            reset_min_fixes: 1,
            reset_gate_m: 0.3,
            reset_velocity_from_fix: true,
            eager_lag_s: None,
            eager_lag_s_elsewhere: (),
            monitor: MonitorConfig::default(),
            nis_window: (),
            nis_gate_per_dim: (),
            nis_window_fraction: (),
        }
    }
}

impl FusionEngineConfig {
    /// Checks the settings that can be out of range (the monitor's).
    ///
    /// # Errors
    /// [`MonitorConfigError`] naming the monitor's key.
    pub fn validate(&self) -> Result<(), MonitorConfigError> {
        self.monitor.validate()
    }
}

/// Counters of what the fusion engine did and dropped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct FusionCounters {
    /// INS states received and used.
    pub nav_used: u64,
    /// INS states ignored as stale (older correction id) or repeated.
    pub nav_stale: u64,
    /// Samples dropped for a wrong layout version.
    pub dropped_version: u64,
    /// Samples dropped for non-finite values.
    pub dropped_invalid: u64,
    /// Measurements dropped because they are older than the INS data already processed.
    pub meas_late: u64,
    /// Measurements dropped because they precede the INS's first state
    /// (taken before the alignment ended: 8.7 s of static start on
    /// UTIL's cfBolt-log00, 3799 TDOA differences); not late, unusable.
    pub meas_before_ins: u64,
    /// Measurements dropped because too many were waiting.
    pub meas_overflow: u64,
    /// Updates done.
    pub updates: u64,
    /// Updates in which a component was weighted as an outlier.
    pub outliers: u64,
    /// Measurements rejected outright.
    pub rejected: u64,
    /// Resets (first fix, divergence).
    pub resets: u64,
    /// Corrections sent.
    pub corrections: u64,
    /// INS states that followed missing IMU samples.
    pub ins_gaps: u64,
    /// Times the divergence monitor fired (once per divergence: it is
    /// not fed while a reset waits for agreeing fixes).
    pub nis_divergences: u64,
}

/// A measurement for the engine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Measurement {
    /// A multilaterated fix.
    Fix(UwbFix),
    /// One TDOA difference.
    Tdoa(UwbTdoa),
    /// One two-way range (used as a TDOA difference is: by the tight filter).
    Range(UwbRange),
    /// A body-frame velocity (odometry, flow): an aiding update of the
    /// filters that take one ([`Estimator::update_velocity`]). In tight
    /// coupling its correction goes out with its epoch's; a loose filter
    /// publishes nothing for it, its correction goes out with the next
    /// fix's. It neither initialises nor resets the filter.
    Velocity(BodyVelocity),
    /// A height (a range finder's): an aiding update as a body velocity
    /// is ([`Estimator::update_height`]), handled as one.
    Height(Height),
}

impl Measurement {
    fn time(&self) -> u64 {
        self.header().meas_time_ns
    }
    fn header(&self) -> &Header {
        match self {
            Self::Fix(f) => &f.header,
            Self::Tdoa(t) => &t.header,
            Self::Range(r) => &r.header,
            Self::Velocity(v) => &v.header,
            Self::Height(h) => &h.header,
        }
    }
    /// An aiding measurement (a body velocity, a height): it waits for the
    /// UWB stream to pass its time, neither initialises nor resets the
    /// filter, and a loose filter publishes nothing for it.
    fn is_aiding(&self) -> bool {
        matches!(self, Self::Velocity(_) | Self::Height(_))
    }
}

/// What the engine produced for one input; the caller publishes it and
/// clears it before the next call.
#[derive(Debug, Default, Clone)]
pub struct Outputs {
    /// Fused states, in order.
    pub fused: Vec<FusedState>,
    /// Filter diagnostics, one per update.
    pub diag: Vec<FilterDiag>,
    /// Corrections for the INS, in order.
    pub corrections: Vec<InsCorrection>,
}

impl Outputs {
    /// Empties every list (keeping their capacity).
    pub fn clear(&mut self) {
        self.fused.clear();
        self.diag.clear();
        self.corrections.clear();
    }
}

/// The fusion engine.
#[derive(Debug)]
pub struct FusionEngine {
    cfg: FusionEngineConfig,
    est: Box<dyn Estimator>,
    nav_buf: VecDeque<NavState>,
    prev_nav: Option<NavState>,
    last_nav: Option<NavState>,
    pending: VecDeque<Measurement>,
    correction_id: u64,
    initialised: bool,
    reset_requested: bool,
    /// Tight coupling: the epoch of the measurements folded in since the last
    /// correction, and the last of them.
    dirty: Option<(u64, Measurement, InsAt)>,
    fused_seq: u64,
    counters: FusionCounters,
    last_fused: Option<FusedState>,
    /// While waiting to (re-)initialise: the last fix position and how many
    /// consecutive fixes up to it agreed.
    reset_run: Option<([f64; 3], usize)>,
    /// The divergence monitor of whichever filter `est` is.
    monitor: DivergenceMonitor,
    /// The filter was re-initialised and has not been updated since: the
    /// next diagnostic carries [`FilterDiag::FLAG_RESET`].
    reset_unreported: bool,
    /// Where the tight coupling's correction epochs start ([`FusionEngine::align_to`]).
    epoch_phase_ns: u64,
    /// Time of the newest UWB measurement received of the stream the
    /// estimator updates from (TDOA differences tight, fixes loose), ns.
    uwb_newest_ns: Option<u64>,
    /// How long a body velocity waits for the UWB stream, ns
    /// ([`FusionEngine::with_velocity_wait`]).
    velocity_wait_ns: u64,
}

/// An empty queue with room for `n` items whose memory was written once
/// here. A queue used as a FIFO walks its whole buffer; without this each
/// page of it is faulted in on the path the first time the queue reaches it
/// (for the INS history, minutes after the start), not at start-up.
pub(crate) fn prefaulted_deque<T>(n: usize) -> VecDeque<T> {
    let mut v: Vec<T> = Vec::with_capacity(n);
    for slot in v.spare_capacity_mut() {
        *slot = core::mem::MaybeUninit::zeroed();
    }
    std::hint::black_box(&mut v);
    VecDeque::from(v)
}

impl FusionEngine {
    /// A new engine around `est`. A monitor configuration that does not
    /// validate ([`FusionEngineConfig::validate`]; `config::build_estimator`
    /// checks it) disables the monitor.
    #[must_use]
    pub fn new(cfg: FusionEngineConfig, est: Box<dyn Estimator>) -> Self {
        let initialised = !cfg.init_from_first_fix;
        let monitor = DivergenceMonitor::new(cfg.monitor.clone())
            .unwrap_or_else(|_| DivergenceMonitor::disabled());
        Self {
            nav_buf: prefaulted_deque(cfg.max_nav_buffer.min(65_536)),
            pending: prefaulted_deque(cfg.max_pending.min(65_536)),
            cfg,
            est,
            prev_nav: None,
            last_nav: None,
            correction_id: 0,
            initialised,
            reset_requested: false,
            dirty: None,
            fused_seq: 0,
            counters: FusionCounters::default(),
            last_fused: None,
            reset_run: None,
            monitor,
            reset_unreported: false,
            epoch_phase_ns: 0,
            uwb_newest_ns: None,
            velocity_wait_ns: 250_000_000,
        }
    }

    /// How long a body velocity waits for the UWB stream to reach its time,
    /// s (`[fusion.aiding] wait_s`, default 0.25): it is applied once a UWB
    /// measurement at or after its time has arrived, or once the INS is
    /// this far past it. The filters then see the measurements in time
    /// order whichever process delivers first, as in `insuwb eval`.
    #[must_use]
    pub fn with_velocity_wait(mut self, wait_s: f64) -> Self {
        if wait_s.is_finite() && wait_s >= 0.0 {
            self.velocity_wait_ns = (wait_s * 1e9) as u64;
        }
        self
    }

    /// Records one update at `t_ns` in the divergence monitor: its NIS, or
    /// that it was rejected; true when the monitor says the filter
    /// diverged (it then starts afresh). Not fed while a reset waits for
    /// agreeing fixes: the filter is known to be wrong until then.
    fn nis_diverged(&mut self, info: &UpdateInfo, t_ns: u64) -> bool {
        if self.reset_pending() {
            return false;
        }
        if info.rejected {
            self.monitor.push_rejected(t_ns as f64 * 1e-9)
        } else {
            self.monitor.push(t_ns as f64 * 1e-9, info.nis, info.dim)
        }
    }

    /// The divergence monitor (its window, for diagnostics and tests).
    #[must_use]
    pub fn monitor(&self) -> &DivergenceMonitor {
        &self.monitor
    }

    /// Resumes a filter restored from a checkpoint (a restarted fusion
    /// stage whose INS kept running, corrected all along): the engine is
    /// initialised, so the first fix updates the filter instead of
    /// resetting the INS to that fix and the filter to its `P_0` and
    /// `R_0`, which would throw away the restored covariance and adaptive
    /// noise and move the INS onto one raw fix (in NLOS, off by the fix's
    /// bias).
    pub fn resume_initialised(&mut self) {
        self.initialised = true;
    }

    /// Whether the INS position and the filter are initialised (from a
    /// first fix, or resumed).
    #[must_use]
    pub fn is_initialised(&self) -> bool {
        self.initialised
    }

    /// Whether a re-initialisation from UWB is pending: the monitor fired
    /// (or the covariance stopped being finite) and the engine waits for
    /// agreeing fixes. Fused states published meanwhile are not valid.
    #[must_use]
    pub fn reset_pending(&self) -> bool {
        self.initialised
            && self.cfg.reset_on_divergence
            && (self.reset_requested || self.est.needs_reset())
    }

    /// Predicts through the buffered INS states older than the newest by
    /// more than `eager_lag_s` (see [`FusionEngineConfig::eager_lag_s`]);
    /// only while no measurement waits and no tight epoch is open, so the
    /// sequence of predictions and updates is the one of the lazy path.
    fn advance_eagerly(&mut self) {
        let Some(lag) = self.cfg.eager_lag_s else {
            return;
        };
        if !self.pending.is_empty() || self.dirty.is_some() {
            return;
        }
        let lag_ns = (lag.max(0.0) * 1e9) as u64;
        let Some(newest) = self.nav_buf.back().map(|n| n.header.meas_time_ns) else {
            return;
        };
        while let Some(front) = self.nav_buf.front().copied() {
            if front.header.meas_time_ns.saturating_add(lag_ns) > newest {
                break;
            }
            self.nav_buf.pop_front();
            self.advance_to(&front);
        }
    }

    /// Counts `fix` into the run of agreeing fixes; true when the run is long
    /// enough to (re-)initialise from it.
    fn reset_fix_ready(&mut self, fix: &UwbFix) -> bool {
        let p = fix.pos_m;
        let n = match self.reset_run {
            Some((q, n)) => {
                let d2: f64 = (0..3).map(|i| (p[i] - q[i]) * (p[i] - q[i])).sum();
                // A NaN gate accepts every fix (as the default of one fix would).
                if d2.sqrt() > self.cfg.reset_gate_m {
                    1
                } else {
                    n + 1
                }
            }
            None => 1,
        };
        self.reset_run = Some((p, n));
        n >= self.cfg.reset_min_fixes.clamp(1, MAX_RESET_FIXES)
    }

    /// Counters so far.
    #[must_use]
    pub fn counters(&self) -> FusionCounters {
        self.counters
    }

    /// The estimator.
    #[must_use]
    pub fn estimator(&self) -> &dyn Estimator {
        self.est.as_ref()
    }

    /// The estimator, mutable (checkpoint restore).
    pub fn estimator_mut(&mut self) -> &mut dyn Estimator {
        self.est.as_mut()
    }

    /// The last fused state published.
    #[must_use]
    pub fn last_fused(&self) -> Option<&FusedState> {
        self.last_fused.as_ref()
    }

    /// The newest INS state known (processed or buffered).
    #[must_use]
    pub fn latest_nav(&self) -> Option<&NavState> {
        self.nav_buf.back().or(self.last_nav.as_ref())
    }

    /// Id of the last correction sent.
    #[must_use]
    pub fn correction_id(&self) -> u64 {
        self.correction_id
    }

    /// Continue correction ids from `id` (a restarted fusion stage resuming
    /// from a checkpoint, or learning the INS's latest id).
    pub fn resume_correction_id(&mut self, id: u64) {
        self.correction_id = self.correction_id.max(id);
    }

    /// A fused state built on the newest INS state (coasting), corrected
    /// by the estimate the filter holds and has not sent yet
    /// ([`Estimator::pending_correction`]: a loose filter's body-velocity
    /// updates and vehicle constraints since the last fix; zero for the
    /// INS alone), flagged [`FusedState::FLAG_DEGRADED`]; when to publish
    /// it is [`crate::output::OutputPolicy`]'s call.
    #[must_use]
    pub fn coasting_state(&mut self) -> Option<FusedState> {
        let n = *self.latest_nav()?;
        let ins = InsAt {
            t_ns: n.header.meas_time_ns,
            pos_m: n.pos_m,
            vel_mps: n.vel_mps,
            quat: n.quat,
        };
        let pending = self.est.pending_correction();
        let delta = if pending.is_finite() {
            pending
        } else {
            Delta::default()
        };
        let mut f = self.fused_from(&ins, &delta, &n);
        f.header.flags |= FusedState::FLAG_DEGRADED;
        Some(f)
    }

    /// A pose built on the UWB fix `fix` alone, for while the INS cannot
    /// serve (when to publish it is [`crate::output::OutputPolicy`]'s call):
    /// position and its covariance from the fix; velocity from the fix when
    /// it carries one, else the last fused velocity with its variance grown
    /// as by an unknown acceleration of [`UWB_ONLY_ACCEL_MPS2`] since then;
    /// attitude, heading and frame of the last fused state (None before
    /// the first one: no attitude is known). Flagged
    /// [`FusedState::FLAG_UWB_ONLY`] and valid.
    #[must_use]
    pub fn uwb_only_state(&mut self, fix: &UwbFix) -> Option<FusedState> {
        let last = *self.last_fused.as_ref()?;
        let mut cov = [[0.0; 6]; 6];
        for (row, src) in cov.iter_mut().zip(&fix.pos_cov_m2) {
            row[..3].copy_from_slice(src);
        }
        let vel = if fix.header.flags & UwbFix::FLAG_VEL_VALID != 0 {
            for (row, src) in cov[3..].iter_mut().zip(&fix.vel_cov) {
                row[3..].copy_from_slice(src);
            }
            fix.vel_mps
        } else {
            let dt = fix
                .header
                .meas_time_ns
                .saturating_sub(last.header.meas_time_ns) as f64
                * 1e-9;
            let grown = (UWB_ONLY_ACCEL_MPS2 * dt).powi(2);
            for (i, (row, src)) in cov[3..].iter_mut().zip(&last.cov[3..]).enumerate() {
                row[3..].copy_from_slice(&src[3..]);
                row[3 + i] += grown;
            }
            last.vel_mps
        };
        let seq = self.fused_seq;
        self.fused_seq += 1;
        Some(FusedState {
            header: Header {
                flags: FusedState::FLAG_VALID | FusedState::FLAG_UWB_ONLY,
                ..Header::new(seq, fix.header.meas_time_ns)
            },
            pos_m: fix.pos_m,
            vel_mps: vel,
            cov,
            uwb_seq: fix.header.seq,
            uwb_meas_time_ns: fix.header.meas_time_ns,
            uwb_pub_time_ns: fix.header.pub_time_ns,
            ..last
        })
    }

    /// Brings the code and data of the next update into the caches without
    /// changing the estimate ([`Estimator::warm_up`]); for a caller that
    /// knows a fix is due shortly (the fusion stage, in real time).
    pub fn warm_up(&mut self) {
        self.est.warm_up();
    }

    /// Handles one INS state.
    pub fn on_nav(&mut self, n: &NavState, out: &mut Outputs) {
        if n.header.layout_version != LAYOUT_VERSION {
            self.counters.dropped_version += 1;
            return;
        }
        let finite = n
            .pos_m
            .iter()
            .chain(&n.vel_mps)
            .chain(&n.quat)
            .chain(&n.accel_nav_mps2)
            .all(|v| v.is_finite());
        if !finite {
            self.counters.dropped_invalid += 1;
            return;
        }
        if n.correction_id < self.correction_id {
            self.counters.nav_stale += 1;
            return;
        }
        if n.correction_id > self.correction_id {
            // The INS knows a later correction than we sent: we restarted.
            self.correction_id = n.correction_id;
        }
        if let Some(last) = self.latest_nav() {
            if n.header.meas_time_ns <= last.header.meas_time_ns {
                self.counters.nav_stale += 1;
                return;
            }
        }
        if self.nav_buf.len() >= self.cfg.max_nav_buffer {
            if let Some(old) = self.nav_buf.pop_front() {
                self.advance_to(&old);
            }
        }
        self.nav_buf.push_back(*n);
        self.counters.nav_used += 1;
        self.process(out);
        self.advance_eagerly();
    }

    /// Handles one UWB measurement (a fix or a TDOA difference).
    pub fn on_measurement(&mut self, m: Measurement, out: &mut Outputs) {
        if m.header().layout_version != LAYOUT_VERSION {
            self.counters.dropped_version += 1;
            return;
        }
        let finite = match &m {
            Measurement::Fix(f) => f.pos_m.iter().chain(&f.vel_mps).all(|v| v.is_finite()),
            Measurement::Tdoa(t) => {
                t.diff_m.is_finite()
                    && t.anchor_a_pos_m
                        .iter()
                        .chain(&t.anchor_b_pos_m)
                        .all(|v| v.is_finite())
            }
            Measurement::Range(r) => insuwb_msg::check::range_values(r).is_ok(),
            Measurement::Velocity(v) => insuwb_msg::check::velocity_values(v).is_ok(),
            Measurement::Height(h) => insuwb_msg::check::height_values(h).is_ok(),
        };
        if !finite {
            self.counters.dropped_invalid += 1;
            return;
        }
        let t = m.time();
        // The UWB stream the estimator updates from: TDOA differences for
        // the tight filter (a fix is published before the differences that
        // completed it, so its time runs ahead of them), fixes for a loose one.
        let uwb = match m {
            Measurement::Tdoa(_) | Measurement::Range(_) => self.est.is_tight(),
            Measurement::Fix(_) => !self.est.is_tight(),
            Measurement::Velocity(_) | Measurement::Height(_) => false,
        };
        if uwb {
            self.uwb_newest_ns = Some(self.uwb_newest_ns.map_or(t, |u| u.max(t)));
        }
        // Keep `pending` sorted by time (stable for equal times).
        let idx = self.pending.partition_point(|p| p.time() <= t);
        self.pending.insert(idx, m);
        if self.pending.len() > self.cfg.max_pending {
            self.pending.pop_front();
            self.counters.meas_overflow += 1;
        }
        self.process(out);
    }

    fn advance_to(&mut self, n: &NavState) {
        if let Some(last) = self.last_nav {
            let dt = (n
                .header
                .meas_time_ns
                .saturating_sub(last.header.meas_time_ns)) as f64
                * 1e-9;
            self.est.predict(dt, n);
        }
        if n.header.flags & NavState::FLAG_GAP != 0 {
            self.counters.ins_gaps += 1;
        }
        self.prev_nav = self.last_nav;
        self.last_nav = Some(*n);
    }

    fn epoch_period_ns(&self) -> u64 {
        (self.cfg.tdoa_epoch_s * 1e9).max(1.0) as u64
    }

    fn epoch_of(&self, t_ns: u64) -> u64 {
        t_ns.saturating_sub(self.epoch_phase_ns)
            .div_ceil(self.epoch_period_ns())
    }

    /// Aligns the tight coupling's correction epochs to a recording replayed
    /// from `epoch_ns` (measurement times `epoch_ns + t`), as
    /// `insuwb_uwb::fix::FixBuilder::align_to` does the fix epochs: the same
    /// measurements share an epoch as for the recording's own times.
    pub fn align_to(&mut self, epoch_ns: u64) {
        self.epoch_phase_ns = epoch_ns % self.epoch_period_ns();
    }

    fn process(&mut self, out: &mut Outputs) {
        while let Some(m) = self.pending.front().copied() {
            let t_m = m.time();
            // An aiding measurement waits for the UWB stream to pass its time.
            if m.is_aiding()
                && self.uwb_newest_ns.is_none_or(|u| u < t_m)
                && !self.latest_nav().is_some_and(|n| {
                    n.header.meas_time_ns >= t_m.saturating_add(self.velocity_wait_ns)
                })
            {
                return;
            }
            // Tight coupling: close the previous epoch before touching the next one.
            if let Some((epoch, _, _)) = self.dirty {
                if self.epoch_of(t_m) != epoch {
                    self.emit_epoch(out);
                    continue;
                }
            }
            // The oldest INS time a measurement can still be processed at:
            // the start of the interval processed last (a measurement inside
            // it is interpolated; tight coupling delivers a fix after the
            // TDOA differences of its epoch moved the INS to or past it),
            // else the first INS state known.
            let Some(first_t) = self
                .prev_nav
                .as_ref()
                .or(self.last_nav.as_ref())
                .or(self.nav_buf.front())
                .map(|n| n.header.meas_time_ns)
            else {
                return; // no INS yet
            };
            let last_t = self.last_nav.map_or(0, |n| n.header.meas_time_ns);
            if t_m < first_t {
                self.pending.pop_front();
                if self.last_nav.is_none() && self.prev_nav.is_none() {
                    self.counters.meas_before_ins += 1;
                } else {
                    self.counters.meas_late += 1;
                }
                continue;
            }
            if self.last_nav.is_none() || t_m > last_t {
                // Predict through the INS states up to the one covering t_m.
                let Some(cover) = self
                    .nav_buf
                    .iter()
                    .position(|n| n.header.meas_time_ns >= t_m)
                else {
                    // Wait for INS data. Eagerly, predict now through the
                    // states before t_m: the lazy path predicts through
                    // every one of them first when the covering state comes
                    // (the same predictions in the same order), and only
                    // the last prediction and the update are left for then.
                    if self.cfg.eager_lag_s.is_some() {
                        while let Some(n) = self.nav_buf.pop_front() {
                            self.advance_to(&n);
                        }
                    }
                    return;
                };
                for _ in 0..=cover {
                    if let Some(n) = self.nav_buf.pop_front() {
                        self.advance_to(&n);
                    }
                }
            }
            self.pending.pop_front();
            let Some(ins) = self.ins_at(t_m) else {
                self.counters.meas_late += 1;
                continue;
            };
            self.handle(m, ins, out);
        }
    }

    fn ins_at(&self, t: u64) -> Option<InsAt> {
        let b = self.last_nav?;
        let tb = b.header.meas_time_ns;
        let a = match self.prev_nav {
            Some(a) if a.header.meas_time_ns == t => {
                return Some(InsAt {
                    t_ns: t,
                    pos_m: a.pos_m,
                    vel_mps: a.vel_mps,
                    quat: a.quat,
                })
            }
            Some(a) if a.header.meas_time_ns < t && t < tb => a,
            _ => {
                return Some(InsAt {
                    t_ns: t,
                    pos_m: b.pos_m,
                    vel_mps: b.vel_mps,
                    quat: b.quat,
                })
            }
        };
        let ta = a.header.meas_time_ns;
        let w = (t - ta) as f64 / (tb - ta) as f64;
        let l = |x: [f64; 3], y: [f64; 3]| {
            [
                x[0] + w * (y[0] - x[0]),
                x[1] + w * (y[1] - x[1]),
                x[2] + w * (y[2] - x[2]),
            ]
        };
        let qa = to_uq(a.quat);
        let qb = to_uq(b.quat);
        let q = qa.try_slerp(&qb, w, 1e-12).unwrap_or(qb);
        Some(InsAt {
            t_ns: t,
            pos_m: l(a.pos_m, b.pos_m),
            vel_mps: l(a.vel_mps, b.vel_mps),
            quat: [q.w, q.i, q.j, q.k],
        })
    }

    fn handle(&mut self, m: Measurement, ins: InsAt, out: &mut Outputs) {
        let Some(last) = self.last_nav else {
            return;
        };
        // Position initialisation and divergence resets come from fixes.
        if let Measurement::Fix(fix) = m {
            if !self.initialised || self.reset_pending() {
                if self.reset_fix_ready(&fix) {
                    self.reset_run = None;
                    self.reset_from_fix(&fix, &ins, &last, out);
                }
                return;
            }
        }
        if !self.initialised {
            return;
        }
        self.est.flush_predict();
        let info = match m {
            Measurement::Fix(f) => self.est.update_fix(&ins, &f),
            Measurement::Tdoa(t) => self.est.update_tdoa(&ins, &t),
            Measurement::Range(r) => self.est.update_range(&ins, &r),
            Measurement::Velocity(v) => self.est.update_velocity(&ins, &v),
            Measurement::Height(h) => self.est.update_height(&ins, &h),
        };
        let Some(info) = info else {
            return; // not a measurement this estimator uses
        };
        self.counters.updates += 1;
        if info.outlier {
            self.counters.outliers += 1;
        }
        if info.rejected {
            self.counters.rejected += 1;
        }
        if info.divergence && self.est.needs_reset() {
            self.reset_requested = true;
        }
        let mut diag = self.diag_from(&info, &m);
        if std::mem::take(&mut self.reset_unreported) {
            diag.header.flags |= FilterDiag::FLAG_RESET;
        }
        if self.nis_diverged(&info, m.time()) {
            self.counters.nis_divergences += 1;
            diag.header.flags |= FilterDiag::FLAG_DIVERGENCE;
            if self.cfg.reset_on_divergence {
                self.reset_requested = true;
            }
        }
        out.diag.push(diag);
        if self.est.is_tight() {
            let epoch = self.epoch_of(m.time());
            // An epoch's fused state is stamped with its last UWB
            // measurement; with a velocity only when it has none.
            if !(m.is_aiding() && self.dirty.is_some()) {
                self.dirty = Some((epoch, m, ins));
            }
            if m.header().flags & UwbTdoa::FLAG_EPOCH_END != 0 {
                self.emit_epoch(out);
            }
        } else if !m.is_aiding() {
            self.emit(&m, &ins, out);
        }
        // A loose filter's body-velocity update publishes nothing: the
        // estimate it leaves is propagated by the filter, goes out with the
        // next fix's correction and shows in the coasting state meanwhile
        // (`Estimator::pending_correction`).
    }

    fn emit_epoch(&mut self, out: &mut Outputs) {
        if let Some((_, m, ins)) = self.dirty.take() {
            self.emit(&m, &ins, out);
        }
    }

    /// Takes the correction, sends it, publishes the fused state at the measurement epoch.
    fn emit(&mut self, m: &Measurement, ins: &InsAt, out: &mut Outputs) {
        let Some(last) = self.last_nav else {
            return;
        };
        let delta = self.est.take_correction();
        if !delta.is_finite() {
            self.counters.dropped_invalid += 1;
            self.est.reset();
            self.reset_requested = true;
            return;
        }
        let mut fused = self.fused_from(ins, &delta, &last);
        let h = m.header();
        fused.uwb_seq = h.seq;
        fused.uwb_meas_time_ns = h.meas_time_ns;
        fused.uwb_pub_time_ns = h.pub_time_ns;
        if !delta.is_zero() {
            self.send_correction(&delta, None, &last, out);
        }
        self.last_fused = Some(fused);
        out.fused.push(fused);
    }

    fn reset_from_fix(&mut self, fix: &UwbFix, ins: &InsAt, last: &NavState, out: &mut Outputs) {
        self.counters.resets += 1;
        self.est.reset();
        // Updates of the diverged filter do not count against the new one.
        self.monitor.clear();
        self.dirty = None;
        let vel =
            if self.cfg.reset_velocity_from_fix && fix.header.flags & UwbFix::FLAG_VEL_VALID != 0 {
                fix.vel_mps
            } else {
                [0.0; 3]
            };
        // Position at the fix epoch, moved to the INS sample the reset applies at.
        let dt = (last.header.meas_time_ns.saturating_sub(ins.t_ns)) as f64 * 1e-9;
        let mut pos = fix.pos_m;
        for i in 0..3 {
            pos[i] += vel[i] * dt;
        }
        if fix.header.flags & UwbFix::FLAG_2D != 0 {
            pos[2] = last.pos_m[2];
        }
        let reset = (pos, vel, last.quat);
        let flag = if self.initialised {
            FusedState::FLAG_RESET
        } else {
            0
        };
        self.reset_unreported = self.initialised;
        self.initialised = true;
        self.reset_requested = false;
        self.send_correction(&Delta::default(), Some(reset), last, out);
        let ins_new = InsAt {
            t_ns: ins.t_ns,
            pos_m: fix.pos_m,
            vel_mps: vel,
            quat: last.quat,
        };
        let mut fused = self.fused_from(&ins_new, &Delta::default(), last);
        fused.header.flags |= flag;
        fused.uwb_seq = fix.header.seq;
        fused.uwb_meas_time_ns = fix.header.meas_time_ns;
        fused.uwb_pub_time_ns = fix.header.pub_time_ns;
        self.last_fused = Some(fused);
        out.fused.push(fused);
    }

    fn send_correction(
        &mut self,
        d: &Delta,
        reset: Option<([f64; 3], [f64; 3], [f64; 4])>,
        last: &NavState,
        out: &mut Outputs,
    ) {
        self.correction_id += 1;
        self.counters.corrections += 1;
        let mut c = InsCorrection {
            header: Header::new(self.correction_id, last.header.meas_time_ns),
            correction_id: self.correction_id,
            apply_at_seq: last.imu_seq,
            imu_generation: last.imu_generation,
            d_pos_m: d.d_pos_m,
            d_vel_mps: d.d_vel_mps,
            d_att_rad: d.d_att_rad,
            d_accel_bias_mps2: d.d_accel_bias_mps2,
            d_gyro_bias_rps: d.d_gyro_bias_rps,
            ..InsCorrection::default()
        };
        // The buffered INS states after `last` do not hold this correction:
        // the INS re-propagates and sends them again.
        self.nav_buf.clear();
        let mut l = *last;
        if let Some((p, v, q)) = reset {
            c.header.flags |= InsCorrection::FLAG_RESET;
            c.reset_pos_m = p;
            c.reset_vel_mps = v;
            c.reset_quat = q;
            l.pos_m = p;
            l.vel_mps = v;
            self.prev_nav = None;
        } else {
            apply_delta(&mut l, d);
            if let Some(p) = self.prev_nav.as_mut() {
                apply_delta(p, d);
                p.correction_id = self.correction_id;
            }
        }
        l.correction_id = self.correction_id;
        self.last_nav = Some(l);
        out.corrections.push(c);
    }

    fn fused_from(&mut self, ins: &InsAt, d: &Delta, nav: &NavState) -> FusedState {
        let mut pos = ins.pos_m;
        let mut vel = ins.vel_mps;
        for i in 0..3 {
            pos[i] -= d.d_pos_m[i];
            vel[i] -= d.d_vel_mps[i];
        }
        let q = corrected_quat(ins.quat, d.d_att_rad);
        let uq = to_uq(q);
        let yaw = {
            let x = uq * Vector3::x();
            x.y.atan2(x.x)
        };
        let seq = self.fused_seq;
        self.fused_seq += 1;
        // A filter the monitor found diverged is not valid until re-initialised.
        let flags = if self.reset_pending() {
            0
        } else {
            FusedState::FLAG_VALID
        };
        FusedState {
            header: Header {
                flags,
                ..Header::new(seq, ins.t_ns)
            },
            pos_m: pos,
            vel_mps: vel,
            quat: q,
            yaw_rad: yaw,
            cov: self.est.pos_vel_cov(),
            frame_id: fixed_name(&self.cfg.frame_id),
            ins_seq: nav.header.seq,
            ins_meas_time_ns: nav.header.meas_time_ns,
            ins_pub_time_ns: nav.header.pub_time_ns,
            filter_kind: self.est.kind() as u32,
            ..FusedState::default()
        }
    }

    fn diag_from(&self, info: &UpdateInfo, m: &Measurement) -> FilterDiag {
        let mut flags = 0;
        if info.divergence {
            flags |= FilterDiag::FLAG_DIVERGENCE;
        }
        if info.outlier || info.rejected {
            flags |= FilterDiag::FLAG_OUTLIER;
        }
        FilterDiag {
            header: Header {
                flags,
                ..Header::new(self.counters.updates, m.time())
            },
            innovation: info.innovation,
            innovation_var: info.innovation_var,
            lambda: info.lambda,
            r_diag: info.r_diag,
            nis: info.nis,
            fading: info.fading,
            dim: info.dim,
            filter_kind: self.est.kind() as u32,
        }
    }
}

fn to_uq(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// `q_true = Exp(-d_att) * q_ins` (the correction convention).
#[must_use]
pub fn corrected_quat(q: [f64; 4], d_att: [f64; 3]) -> [f64; 4] {
    if d_att == [0.0; 3] {
        return q;
    }
    let r = UnitQuaternion::from_scaled_axis(-Vector3::from(d_att));
    let c = r * to_uq(q);
    [c.w, c.i, c.j, c.k]
}

fn apply_delta(n: &mut NavState, d: &Delta) {
    for i in 0..3 {
        n.pos_m[i] -= d.d_pos_m[i];
        n.vel_mps[i] -= d.d_vel_mps[i];
    }
    n.quat = corrected_quat(n.quat, d.d_att_rad);
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::panic)]

    use super::*;
    use crate::config::{build_estimator, FusionConfig};
    use insuwb_msg::FilterKind;

    fn nav(k: u64) -> NavState {
        NavState {
            header: Header::new(k, k * 1_000_000),
            imu_seq: k,
            quat: [1.0, 0.0, 0.0, 0.0],
            ..NavState::default()
        }
    }

    fn fix(t_ns: u64, pos_m: [f64; 3]) -> UwbFix {
        UwbFix {
            header: Header::new(0, t_ns),
            pos_m,
            ..UwbFix::default()
        }
    }

    /// A KF engine that initialises from the first fix, and its outputs.
    fn kf_from_first_fix() -> (FusionEngine, Outputs) {
        let cfg = FusionEngineConfig {
            init_from_first_fix: true,
            ..FusionEngineConfig::default()
        };
        let est = build_estimator(FilterKind::Kf, &FusionConfig::default()).unwrap();
        (FusionEngine::new(cfg, est), Outputs::default())
    }

    /// Fixes jumping by 100 m, a KF at rest: the monitor fires on the third
    /// update (window 3, all above the gate); the output of that update is
    /// not valid, the next fix resets the filter and the INS (flagged,
    /// valid), the window starts empty and the next diagnostic says reset.
    #[test]
    fn the_monitor_resets_from_uwb_and_flags_the_outputs() {
        let cfg = FusionEngineConfig {
            init_from_first_fix: true,
            monitor: MonitorConfig {
                window: 3,
                gate_per_dim: 9.0,
                fraction: 1.0,
                max_reject_run_s: 1.0,
                ..MonitorConfig::default()
            },
            ..FusionEngineConfig::default()
        };
        let est = build_estimator(FilterKind::Kf, &FusionConfig::default()).unwrap();
        let mut e = FusionEngine::new(cfg, est);
        let mut out = Outputs::default();
        let mut all = Outputs::default();
        let mut k = 0;
        let (east, west) = ([50.0, 0.0, 0.0], [-50.0, 0.0, 0.0]);
        let fixes = [
            [0.0; 3],
            east,
            west,
            east,
            [10.0, 0.0, 0.0],
            [10.1, 0.0, 0.0],
        ];
        for (i, p) in fixes.iter().enumerate() {
            let t = (i as u64 + 1) * 100;
            while k <= t {
                let n = NavState {
                    correction_id: e.correction_id(),
                    ..nav(k)
                };
                e.on_nav(&n, &mut out);
                k += 1;
            }
            e.on_measurement(Measurement::Fix(fix(t * 1_000_000, *p)), &mut out);
            all.fused.extend_from_slice(&out.fused);
            all.diag.extend_from_slice(&out.diag);
            out.clear();
            assert_eq!(e.reset_pending(), i == 3, "after fix {i}");
        }
        let c = e.counters();
        assert_eq!((c.nis_divergences, c.resets, c.updates), (1, 2, 4), "{c:?}");
        let flags: Vec<u32> = all.fused.iter().map(|f| f.header.flags).collect();
        let (v, r) = (FusedState::FLAG_VALID, FusedState::FLAG_RESET);
        // First fix (initialisation), three updates (the last fires), the
        // reset from the fifth fix, one update.
        assert_eq!(flags, [v, v, v, 0, v | r, v], "{flags:?}");
        let diag: Vec<u32> = all.diag.iter().map(|d| d.header.flags).collect();
        assert_eq!(
            diag[2] & FilterDiag::FLAG_DIVERGENCE,
            FilterDiag::FLAG_DIVERGENCE
        );
        assert_eq!(diag[3] & FilterDiag::FLAG_RESET, FilterDiag::FLAG_RESET);
        assert!(diag[..3].iter().all(|d| d & FilterDiag::FLAG_RESET == 0));
        assert!(!e.reset_pending());
        assert_eq!(e.monitor().len(), 1, "only the update after the reset");
    }

    /// The monitor's keys live in `[fusion.engine.monitor]`; the former keys
    /// of `[fusion.engine]` are refused with a message naming the new one,
    /// and are never written; likewise `eager_lag_s`, robot.toml's.
    #[test]
    fn the_monitor_keys_and_their_former_names() {
        let c: FusionEngineConfig =
            toml::from_str("[monitor]\nwindow = 10\nfraction = 0.7\ngate_per_dim = 9.0").unwrap();
        assert_eq!(
            (c.monitor.window, c.monitor.fraction, c.monitor.gate_per_dim),
            (10, 0.7, 9.0)
        );
        assert_eq!(c.monitor.max_reject_run_s, 1.0);
        c.validate().unwrap();
        for (old, new) in [
            ("nis_window = 10", "fusion.engine.monitor.window"),
            (
                "nis_gate_per_dim = 9.0",
                "fusion.engine.monitor.gate_per_dim",
            ),
            (
                "nis_window_fraction = 0.7",
                "fusion.engine.monitor.fraction",
            ),
        ] {
            let e = toml::from_str::<FusionEngineConfig>(old)
                .unwrap_err()
                .to_string();
            assert!(e.contains(new), "{old}: {e}");
        }
        let text = toml::to_string(&FusionEngineConfig::default()).unwrap();
        assert!(!text.contains("nis_"), "{text}");
        // The eager prediction's lag: robot.toml's, never written here.
        let e = toml::from_str::<FusionEngineConfig>("eager_lag_s = 0.01")
            .unwrap_err()
            .to_string();
        assert!(e.contains("robot.toml's [fusion]"), "{e}");
        let eager = FusionEngineConfig {
            eager_lag_s: Some(0.01),
            ..FusionEngineConfig::default()
        };
        let text = toml::to_string(&eager).unwrap();
        assert!(!text.contains("eager"), "{text}");
        let bad = FusionEngineConfig {
            monitor: MonitorConfig {
                fraction: 1.5,
                ..MonitorConfig::default()
            },
            ..FusionEngineConfig::default()
        };
        assert_eq!(
            bad.validate().unwrap_err().to_string(),
            "monitor.fraction must be in (0, 1], got 1.5"
        );
        let mut cfg = FusionConfig {
            engine: bad,
            ..FusionConfig::default()
        };
        let e = build_estimator(FilterKind::Kf, &cfg)
            .unwrap_err()
            .to_string();
        assert_eq!(e, "engine.monitor.fraction must be in (0, 1], got 1.5");
        cfg.engine.monitor.fraction = 0.5;
        assert!(build_estimator(FilterKind::IakfTdoa, &cfg).is_ok());
    }

    /// Aligned to a replay's epoch, the correction epochs hold the same
    /// measurement times as the recording's own times; the epoch length
    /// is `tdoa_epoch_s` (0.1 s by default).
    #[test]
    fn correction_epochs_follow_the_replay_epoch() {
        let (mut e, _) = kf_from_first_fix();
        let p = e.epoch_period_ns();
        assert_eq!(p, 100_000_000);
        let epoch = 31_360_002_500_000; // a start epoch (`insuwb_runtime::epoch`)
        let ts = [
            1,
            97_500_000,
            99_999_999,
            100_000_000,
            100_000_001,
            250_000_000,
        ];
        let plain: Vec<u64> = ts.iter().map(|&t| e.epoch_of(t)).collect();
        assert_eq!(plain, [1, 1, 1, 1, 2, 3]);
        // Unaligned, the windows end 2.5 ms early: 97.5 ms and 99.999999 ms
        // fall apart.
        let late: Vec<u64> = ts.iter().map(|&t| e.epoch_of(epoch + t)).collect();
        assert_eq!(late[2] - late[1], 1);
        e.align_to(epoch);
        let aligned: Vec<u64> = ts.iter().map(|&t| e.epoch_of(epoch + t)).collect();
        let base = aligned[0] - plain[0];
        let rel: Vec<u64> = aligned.iter().map(|k| k - base).collect();
        assert_eq!(rel, plain);
    }

    /// Initialisation waits for three consecutive fixes within 0.3 m of each
    /// other and takes the last one; a jump restarts the count.
    #[test]
    fn initialisation_waits_for_agreeing_fixes() {
        let cfg = FusionEngineConfig {
            init_from_first_fix: true,
            reset_min_fixes: 3,
            reset_gate_m: 0.3,
            ..FusionEngineConfig::default()
        };
        let est = build_estimator(FilterKind::Kf, &FusionConfig::default()).unwrap();
        let mut e = FusionEngine::new(cfg, est);
        let mut out = Outputs::default();
        let fixes = [
            [0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [2.1, 0.0, 0.0],
            [5.0, 0.0, 0.0],
            [5.1, 0.1, 0.0],
            [5.2, 0.2, 0.0],
        ];
        let mut k = 0;
        for (i, p) in fixes.iter().enumerate() {
            let t = (i as u64 + 1) * 100;
            while k <= t {
                e.on_nav(&nav(k), &mut out);
                k += 1;
            }
            e.on_measurement(Measurement::Fix(fix(t * 1_000_000, *p)), &mut out);
            let resets = e.counters().resets;
            assert_eq!(resets, u64::from(i == fixes.len() - 1), "after fix {i}");
        }
        let c = out.corrections.last().unwrap();
        assert!(c.header.flags & InsCorrection::FLAG_RESET != 0);
        assert_eq!(c.reset_pos_m, [5.2, 0.2, 0.0]);
        assert_eq!(out.fused.len(), 1);
    }

    /// The initialisation takes the fix's regression velocity only with
    /// `reset_velocity_from_fix`; otherwise it starts from rest.
    #[test]
    fn initial_velocity_from_the_fix_only_when_configured() {
        for from_fix in [true, false] {
            let cfg = FusionEngineConfig {
                init_from_first_fix: true,
                reset_velocity_from_fix: from_fix,
                ..FusionEngineConfig::default()
            };
            let est = build_estimator(FilterKind::Kf, &FusionConfig::default()).unwrap();
            let mut e = FusionEngine::new(cfg, est);
            let mut out = Outputs::default();
            for k in 0..=100 {
                e.on_nav(&nav(k), &mut out);
            }
            let mut f = fix(100_000_000, [1.0, 2.0, 0.5]);
            f.vel_mps = [0.0, 0.0, -2.2];
            f.header.flags |= UwbFix::FLAG_VEL_VALID;
            e.on_measurement(Measurement::Fix(f), &mut out);
            let c = out.corrections.last().unwrap();
            assert!(c.header.flags & InsCorrection::FLAG_RESET != 0);
            let want = if from_fix { [0.0, 0.0, -2.2] } else { [0.0; 3] };
            assert_eq!(c.reset_vel_mps, want);
        }
    }

    /// A fix stamped inside the INS interval processed last is not late (the
    /// TDOA differences of its epoch moved the INS past it).
    #[test]
    fn a_fix_inside_the_last_interval_is_used() {
        let (mut e, mut out) = kf_from_first_fix();
        for k in 0..=10 {
            e.on_nav(&nav(k), &mut out);
        }
        // A measurement at 9.5 ms moves the engine to the state at 10 ms.
        e.on_measurement(Measurement::Fix(fix(9_500_000, [9.0, 9.0, 0.0])), &mut out);
        assert_eq!(e.counters().resets, 1);
        out.clear();
        for k in 11..=20 {
            // As the INS re-publishes them after the reset.
            let n = NavState {
                correction_id: e.correction_id(),
                ..nav(k)
            };
            e.on_nav(&n, &mut out);
        }
        // The fix at 15 ms is processed at the state of 15 ms (interval 14-15 ms).
        e.on_measurement(Measurement::Fix(fix(15_000_000, [1.0, 2.0, 0.0])), &mut out);
        assert_eq!(e.counters().updates, 1, "{:?}", e.counters());
        // One at 14.9 ms lies inside that interval: interpolated, not late.
        e.on_measurement(Measurement::Fix(fix(14_900_000, [1.0, 2.0, 0.0])), &mut out);
        assert_eq!(e.counters().updates, 2, "{:?}", e.counters());
        assert_eq!(e.counters().meas_late, 0, "{:?}", e.counters());
        // Older than the interval processed last: late.
        e.on_measurement(Measurement::Fix(fix(5_000_000, [1.0, 2.0, 0.0])), &mut out);
        assert_eq!(e.counters().meas_late, 1);
        assert_eq!(e.counters().meas_before_ins, 0);
    }

    /// A loose filter's body-velocity update publishes neither a fused
    /// state nor a correction: its estimate waits in the filter, shows in
    /// the coasting state, and goes out with the next fix's correction.
    #[test]
    fn a_loose_velocity_update_goes_out_with_the_next_fix() {
        let (mut e, mut out) = kf_from_first_fix();
        for k in 0..=10 {
            e.on_nav(&nav(k), &mut out);
        }
        e.on_measurement(Measurement::Fix(fix(10_000_000, [0.0; 3])), &mut out);
        assert_eq!(e.counters().resets, 1);
        let id = e.correction_id();
        out.clear();
        // The INS stands still facing east; the wheels read 0.5 m/s forward.
        let v = BodyVelocity {
            header: Header::new(0, 15_000_000),
            vel_mps: [0.5, 0.0, 0.0],
            sigma_mps: [0.01, 0.0, 0.0],
            source: BodyVelocity::SOURCE_ODOMETRY,
            range_mm: 0,
        };
        e.on_measurement(Measurement::Velocity(v), &mut out);
        // The INS goes on (far enough past the velocity for it to be used
        // without a UWB measurement after it).
        for k in 11..=400 {
            let n = NavState {
                correction_id: id,
                ..nav(k)
            };
            e.on_nav(&n, &mut out);
        }
        assert_eq!(e.counters().updates, 1, "{:?}", e.counters());
        assert!(
            out.fused.is_empty() && out.corrections.is_empty(),
            "{out:?}"
        );
        assert_eq!(out.diag.len(), 1);
        assert_eq!(e.correction_id(), id);
        // INS minus truth: about -0.5 m/s east, held by the filter.
        let pending = e.estimator().pending_correction();
        assert!((pending.d_vel_mps[0] + 0.5).abs() < 0.01, "{pending:?}");
        let coast = e.coasting_state().unwrap();
        assert!((coast.vel_mps[0] - 0.5).abs() < 0.01, "{coast:?}");
        // The next fix sends it with its own.
        out.clear();
        e.on_measurement(
            Measurement::Fix(fix(400_000_000, [0.2, 0.0, 0.0])),
            &mut out,
        );
        assert_eq!(e.counters().updates, 2, "{:?}", e.counters());
        assert_eq!(out.fused.len(), 1);
        let c = out.corrections.first().unwrap();
        assert!(c.d_vel_mps[0] < -0.3, "{c:?}");
        assert!(out.fused[0].vel_mps[0] > 0.3, "{:?}", out.fused[0]);
        assert!(e.estimator().pending_correction().is_zero());
    }

    /// A measurement from before the INS's first state (the alignment
    /// window) is counted apart from late ones.
    #[test]
    fn measurements_before_the_first_ins_state_are_not_late() {
        let (mut e, mut out) = kf_from_first_fix();
        for k in 100..=110 {
            e.on_nav(&nav(k), &mut out);
        }
        e.on_measurement(Measurement::Fix(fix(50_000_000, [1.0, 2.0, 0.0])), &mut out);
        let c = e.counters();
        assert_eq!((c.meas_before_ins, c.meas_late), (1, 0), "{c:?}");
    }

    /// A fused state names the INS state it was built on by that state's own
    /// sequence number and times (not the IMU sample's), and the fix by its.
    #[test]
    fn a_fused_state_names_the_ins_state_and_the_fix_it_used() {
        let (mut e, mut out) = kf_from_first_fix();
        // INS states numbered apart from the IMU samples they integrated (as
        // after re-propagations), published 40 us after their time.
        let ins = |k: u64, correction_id: u64| NavState {
            header: Header {
                pub_time_ns: k * 1_000_000 + 40_000,
                ..Header::new(500 + k, k * 1_000_000)
            },
            correction_id,
            ..nav(k)
        };
        for k in 0..=10 {
            e.on_nav(&ins(k, e.correction_id()), &mut out);
        }
        let f = UwbFix {
            header: Header {
                pub_time_ns: 10_000_000 + 90_000,
                ..Header::new(77, 10_000_000)
            },
            ..fix(10_000_000, [1.0, 2.0, 0.0])
        };
        e.on_measurement(Measurement::Fix(f), &mut out);
        let s = out.fused.last().unwrap();
        assert_eq!(
            (s.uwb_seq, s.uwb_meas_time_ns, s.uwb_pub_time_ns),
            (77, 10_000_000, 10_090_000)
        );
        assert_eq!(
            (s.ins_seq, s.ins_meas_time_ns, s.ins_pub_time_ns),
            (510, 10_000_000, 10_040_000)
        );
    }
}
