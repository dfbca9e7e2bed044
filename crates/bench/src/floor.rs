//! The floor: one role of the bare forwarding graph per process.
//!
//! Each role is the transport skeleton of the pipeline stage of the same name
//! (`insuwb_stage`), on the same runtime ports (same topics, payload types,
//! QoS, `Waiter` wake-ups, heartbeats), with the maths and the logging taken
//! out:
//! - `imu`: at `imu_rate_hz` from the start epoch, publishes an IMU sample
//!   and then a ground-truth sample, paced like the driver (one wait on the
//!   waiter's deadline timer per sample);
//! - `uwb`: at `uwb_rate_hz`, publishes `tdoa_per_epoch` TDOA measurements
//!   and, before the last of them, the fix they complete (the driver's order);
//! - `ins`: wakes on IMU samples and corrections; forwards every IMU sample as
//!   an INS state naming it (corrections are read and dropped);
//! - `fusion`: wakes on INS states, fixes (not TDOA measurements: the
//!   loosely coupled fusion stage the bench runs does not read them), a
//!   50 ms tick and, as the fusion stage, shortly before each fix is due
//!   ([`insuwb_runtime::anticipate`]; the stage warms its update there, this
//!   node has nothing to do); a fix waits until the INS state covering its epoch (the first
//!   with a time at or after it) is there, then a fused state naming both
//!   inputs, a correction and a diagnostics sample go out, in the fusion
//!   stage's order;
//! - `logger`: wakes on fused states and, 50 ms after its last drain, when
//!   none comes (as the pipeline's logger), drains every topic, copies every sample into memory
//!   (preallocated, bounded) and notes when each fused state arrived; at
//!   SIGTERM it writes them to its trace folder ([`FLOOR_LOG_FILE`],
//!   [`FUSED_TRACE_FILE`]), after the measurement.
//!
//! Every role runs until SIGINT/SIGTERM. Nothing is allocated per sample.

use core::time::Duration;
use std::path::PathBuf;

use insuwb_log::{LogWriter, Metadata, Record};
use insuwb_msg::{
    topics, FilterDiag, FusedState, GroundTruth, Header, Health, HealthState, ImuSample,
    InsCorrection, LoggerCounters, NavState, StageCounters, UwbFix, UwbTdoa,
};
use insuwb_runtime::anticipate::Anticipator;
use insuwb_runtime::drain::DrainClock;
use insuwb_runtime::{
    monotonic_ns, HealthCounters, PortError, PublishError, ReceiveError, RuntimeConfig, Stage,
    StageError, Sub, WaitError, Wake,
};
use serde::{Deserialize, Serialize};

use crate::trace::{self, RecvStamp, TraceError};

/// File the floor logger writes its records to, in the trace folder.
pub const FLOOR_LOG_FILE: &str = "floor.iulog";
/// File the floor logger writes its fused receive trace to, in the trace folder.
pub const FUSED_TRACE_FILE: &str = "fused_recv.txt";

/// A role of the floor graph: the pipeline's stage roles, one floor process each.
pub use insuwb_msg::StageRole as Role;

/// Settings of a floor process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FloorConfig {
    /// iceoryx2 service prefix of the floor graph (its own, so it never
    /// meets a pipeline). Default `insuwb_floor_`.
    pub prefix: String,
    /// iceoryx2 root folder (absolute); `None`: iceoryx2's default.
    pub root_path: Option<PathBuf>,
    /// Start epoch shared by the two drivers, CLOCK_MONOTONIC ns: sample `k`
    /// is due at `start_epoch_ns + k / rate`. 0 (default): the first start
    /// epoch at least 0.5 s ahead ([`insuwb_runtime::epoch`]), as the
    /// pipeline's drivers choose.
    pub start_epoch_ns: u64,
    /// IMU rate, Hz. Default 100 (the paper's IMU, as the pipeline's scenarios).
    pub imu_rate_hz: f64,
    /// UWB fix rate, Hz. Default 10 (the paper's UWB).
    pub uwb_rate_hz: f64,
    /// TDOA measurements per fix epoch. Default 3 (four anchors, differences
    /// to a reference anchor, as the nlos-long scenario).
    pub tdoa_per_epoch: u32,
    /// Folder the logger role writes its records and receive trace to at
    /// exit; `None`: it writes nothing.
    pub trace_dir: Option<PathBuf>,
    /// Records the logger role keeps at most (preallocated); later ones are
    /// counted and dropped. Default 65 536 (about 160 s of the graph's
    /// ~400 samples/s).
    pub max_records: usize,
    /// SCHED_FIFO priority (1-99) of the role run with this configuration,
    /// as a stage's `[realtime.*] fifo_priority` (the bench gives each role
    /// its own, [`crate::graph::fifo_ladder`]); `None` (default): the normal
    /// scheduler.
    pub fifo_priority: Option<i32>,
}

impl Default for FloorConfig {
    fn default() -> Self {
        Self {
            prefix: "insuwb_floor_".into(),
            root_path: None,
            start_epoch_ns: 0,
            imu_rate_hz: 100.0,
            uwb_rate_hz: 10.0,
            tdoa_per_epoch: 3,
            trace_dir: None,
            max_records: 65_536,
            fifo_priority: None,
        }
    }
}

/// Largest [`FloorConfig::max_records`].
pub const MAX_RECORDS: usize = 1 << 20;

/// A [`FloorConfig`] value that is not acceptable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FloorConfigError {
    /// A rate outside its range.
    #[error("floor.{key} must be in [{min}, {max}] Hz, got {value}")]
    Rate {
        /// The key.
        key: &'static str,
        /// The value.
        value: f64,
        /// Smallest accepted.
        min: f64,
        /// Largest accepted.
        max: f64,
    },
    /// `tdoa_per_epoch` outside 1..=16.
    #[error("floor.tdoa_per_epoch must be in [1, 16], got {0}")]
    TdoaPerEpoch(u32),
    /// `max_records` outside 1..=[`MAX_RECORDS`].
    #[error("floor.max_records must be in [1, {MAX_RECORDS}], got {0}")]
    MaxRecords(usize),
}

impl FloorConfig {
    /// Checks every value (the runtime checks the prefix and root path).
    pub fn validate(&self) -> Result<(), FloorConfigError> {
        for (key, value, min, max) in [
            ("imu_rate_hz", self.imu_rate_hz, 1.0, 10_000.0),
            ("uwb_rate_hz", self.uwb_rate_hz, 0.1, 1_000.0),
        ] {
            if !(value.is_finite() && (min..=max).contains(&value)) {
                return Err(FloorConfigError::Rate {
                    key,
                    value,
                    min,
                    max,
                });
            }
        }
        if !(1..=16).contains(&self.tdoa_per_epoch) {
            return Err(FloorConfigError::TdoaPerEpoch(self.tdoa_per_epoch));
        }
        if !(1..=MAX_RECORDS).contains(&self.max_records) {
            return Err(FloorConfigError::MaxRecords(self.max_records));
        }
        Ok(())
    }

    /// The runtime configuration of `role`.
    #[must_use]
    pub fn runtime(&self, role: Role) -> RuntimeConfig {
        RuntimeConfig {
            prefix: self.prefix.clone(),
            root_path: self.root_path.clone(),
            stage_name: role.name().to_owned(),
            realtime: insuwb_runtime::realtime::RealtimeConfig {
                fifo_priority: self.fifo_priority,
                ..Default::default()
            },
            ..RuntimeConfig::default()
        }
    }
}

/// Why a floor role failed.
#[derive(Debug, thiserror::Error)]
pub enum FloorError {
    /// The settings are invalid.
    #[error(transparent)]
    Config(#[from] FloorConfigError),
    /// The stage (iceoryx2 node) could not start.
    #[error(transparent)]
    Stage(#[from] StageError),
    /// A port could not be created.
    #[error(transparent)]
    Port(#[from] PortError),
    /// The wait loop failed.
    #[error(transparent)]
    Wait(#[from] WaitError),
    /// A sample could not be published.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// A sample could not be received.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// The receive trace could not be written.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// The role has no floor stage (the ROS 2 bridge, the Foxglove live
    /// view and the Zenoh bridge are their own binaries,
    /// `insuwb-stage-ros2`, `insuwb-stage-foxglove` and
    /// `insuwb-stage-zenoh`, off the fix path).
    #[error("the floor has no {0} stage: it is its own binary insuwb-stage-{0}, off the fix path")]
    NoFloorStage(Role),
    /// The floor log could not be created or written.
    #[error("floor log {path}: {reason}")]
    Log {
        /// The file.
        path: String,
        /// What failed.
        reason: String,
    },
}

/// Runs `role` until SIGINT/SIGTERM (a shutdown while starting is a clean exit).
pub fn run_role(role: Role, cfg: &FloorConfig) -> Result<(), FloorError> {
    cfg.validate()?;
    let r = match role {
        Role::Imu => run_imu(cfg),
        Role::Uwb => run_uwb(cfg),
        Role::Ins => run_ins(cfg),
        Role::Fusion => run_fusion(cfg),
        Role::Logger => run_logger(cfg),
        Role::Ros2 | Role::Foxglove | Role::Zenoh => Err(FloorError::NoFloorStage(role)),
    };
    match r {
        Err(FloorError::Stage(StageError::ShutdownRequested(_))) => Ok(()),
        r => r,
    }
}

/// The start epoch of `cfg`, or the first epoch at least 0.5 s ahead, as
/// the pipeline's ([`insuwb_runtime::epoch`]).
fn epoch_of(cfg: &FloorConfig) -> u64 {
    if cfg.start_epoch_ns > 0 {
        return cfg.start_epoch_ns;
    }
    insuwb_runtime::epoch::epoch_at_or_after(monotonic_ns() + 500_000_000)
}

fn period_ns(rate_hz: f64) -> u64 {
    (1e9 / rate_hz).round() as u64
}

/// How long a driver waits at most before it looks at the clock again, ns.
const MAX_WAIT_NS: u64 = 200_000_000;

/// The deadline a driver waits for, as the pipeline's drivers: the next
/// sample's due time (the waiter's timer ends the wait there in one
/// wake-up), at most [`MAX_WAIT_NS`] ahead.
fn wait_for(due_ns: u64) -> u64 {
    due_ns.min(monotonic_ns().saturating_add(MAX_WAIT_NS))
}

fn run_imu(cfg: &FloorConfig) -> Result<(), FloorError> {
    let stage = Stage::new(cfg.runtime(Role::Imu))?;
    let epoch = epoch_of(cfg);
    let period = period_ns(cfg.imu_rate_hz);
    let mut imu_pub = stage.publisher::<ImuSample>(topics::IMU)?;
    let mut truth_pub = stage.publisher::<GroundTruth>(topics::TRUTH)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let hb = waiter.attach_interval(health.period())?;
    let mut counters = HealthCounters::default();
    // Resume at the sample the clock has reached (as a restarted driver).
    let mut k = monotonic_ns().saturating_sub(epoch).div_ceil(period);
    loop {
        let now = monotonic_ns();
        while epoch + k * period <= now {
            let t = epoch + k * period;
            // The sensor sample first, then the truth (as the pipeline's driver).
            imu_pub.publish(ImuSample {
                header: Header::new(k, t),
                accel_mps2: [0.0, 0.0, 9.81],
                gyro_rps: [0.0; 3],
            })?;
            truth_pub.publish(GroundTruth {
                header: Header::new(k, t),
                quat: [1.0, 0.0, 0.0, 0.0],
                ..GroundTruth::default()
            })?;
            counters.published += 1;
            k += 1;
        }
        match waiter.wait_deadline(wait_for(epoch + k * period))? {
            Wake::Shutdown => break,
            Wake::Fired(f) if f.contains(&hb) => {
                health.report(&counters, HealthState::Ok)?;
                imu_pub.update_connections()?;
            }
            _ => {}
        }
    }
    health.report(&counters, HealthState::Stopping)?;
    Ok(())
}

fn run_uwb(cfg: &FloorConfig) -> Result<(), FloorError> {
    let stage = Stage::new(cfg.runtime(Role::Uwb))?;
    let epoch = epoch_of(cfg);
    let period = period_ns(cfg.uwb_rate_hz);
    let mut tdoa_pub = stage.publisher::<UwbTdoa>(topics::UWB_TDOA)?;
    let mut fix_pub = stage.publisher::<UwbFix>(topics::UWB_FIX)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let hb = waiter.attach_interval(health.period())?;
    let mut counters = HealthCounters::default();
    let n = cfg.tdoa_per_epoch;
    let mut k = monotonic_ns().saturating_sub(epoch).div_ceil(period);
    loop {
        let now = monotonic_ns();
        if epoch + k * period <= now {
            // Gives way to an IMU driver woken with it, as the UWB driver.
            std::thread::yield_now();
        }
        while epoch + k * period <= now {
            let t = epoch + k * period;
            for i in 0..n {
                let last = i + 1 == n;
                if last {
                    // The fix the epoch completes goes out before its last TDOA.
                    fix_pub.publish(UwbFix {
                        header: Header {
                            flags: UwbFix::FLAG_2D,
                            ..Header::new(0, t)
                        },
                        n_meas: n,
                        ..UwbFix::default()
                    })?;
                }
                tdoa_pub.publish(UwbTdoa {
                    header: Header {
                        flags: if last { UwbTdoa::FLAG_EPOCH_END } else { 0 },
                        ..Header::new(0, t)
                    },
                    anchor_a: 0,
                    anchor_b: i + 1,
                    ..UwbTdoa::default()
                })?;
                counters.published += 1;
            }
            k += 1;
        }
        match waiter.wait_deadline(wait_for(epoch + k * period))? {
            Wake::Shutdown => break,
            Wake::Fired(f) if f.contains(&hb) => {
                health.report(&counters, HealthState::Ok)?;
                tdoa_pub.update_connections()?;
            }
            _ => {}
        }
    }
    health.report(&counters, HealthState::Stopping)?;
    Ok(())
}

fn run_ins(cfg: &FloorConfig) -> Result<(), FloorError> {
    let stage = Stage::new(cfg.runtime(Role::Ins))?;
    let imu_sub = stage.subscriber::<ImuSample>(topics::IMU)?;
    let corr_sub = stage.subscriber::<InsCorrection>(topics::CORRECTION)?;
    let mut nav_pub = stage.publisher::<NavState>(topics::NAV)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let imu_a = waiter.attach(&imu_sub)?;
    let corr_a = waiter.attach(&corr_sub)?;
    let hb = waiter.attach_interval(health.period())?;
    let mut counters = HealthCounters::default();
    loop {
        match waiter.wait_timeout(Duration::from_millis(500))? {
            Wake::Shutdown => break,
            Wake::Timeout => {}
            Wake::Fired(f) => {
                if f.contains(&imu_a) || f.contains(&corr_a) {
                    corr_sub.drain(|_| {})?;
                    let mut err = None;
                    imu_sub.drain(|s| {
                        let n = NavState {
                            header: Header {
                                flags: NavState::FLAG_ALIGNED,
                                ..Header::new(0, s.header.meas_time_ns)
                            },
                            imu_seq: s.header.seq,
                            imu_generation: s.header.generation,
                            quat: [1.0, 0.0, 0.0, 0.0],
                            ..NavState::default()
                        };
                        if let Err(e) = nav_pub.publish(n) {
                            err = Some(e);
                        }
                    })?;
                    if let Some(e) = err {
                        return Err(e.into());
                    }
                }
                if f.contains(&hb) {
                    counters.add_sub(&imu_sub.stats());
                    counters.published = nav_pub.published();
                    health.report(&counters, HealthState::Ok)?;
                    counters = HealthCounters::default();
                    nav_pub.update_connections()?;
                }
            }
        }
    }
    health.report(&counters, HealthState::Stopping)?;
    Ok(())
}

/// Fixes waiting for their INS state, and recent INS states (fixed capacity).
const FUSION_RING: usize = 64;

/// A bounded FIFO in a fixed array (no allocation).
#[derive(Debug)]
struct Ring<T: Copy + Default> {
    items: [T; FUSION_RING],
    head: usize,
    len: usize,
}

impl<T: Copy + Default> Ring<T> {
    fn new() -> Self {
        Self {
            items: [T::default(); FUSION_RING],
            head: 0,
            len: 0,
        }
    }

    /// Appends `v`, dropping the oldest item when full.
    fn push(&mut self, v: T) {
        if self.len == FUSION_RING {
            self.pop();
        }
        let i = (self.head + self.len) % FUSION_RING;
        if let Some(slot) = self.items.get_mut(i) {
            *slot = v;
        }
        self.len += 1;
    }

    fn front(&self) -> Option<&T> {
        (self.len > 0).then(|| self.items.get(self.head)).flatten()
    }

    fn pop(&mut self) -> Option<T> {
        let v = *self.front()?;
        self.head = (self.head + 1) % FUSION_RING;
        self.len -= 1;
        Some(v)
    }

    fn clear(&mut self) {
        self.len = 0;
    }

    fn iter(&self) -> impl Iterator<Item = &T> {
        (0..self.len).filter_map(move |i| self.items.get((self.head + i) % FUSION_RING))
    }
}

/// The fusion role's waiting rule: fixes wait for the first INS state at or
/// after their epoch; each pair is emitted once, in time order.
#[derive(Debug)]
struct Matcher {
    fixes: Ring<UwbFix>,
    navs: Ring<NavState>,
    out: Ring<(UwbFix, NavState)>,
}

impl Matcher {
    fn new() -> Self {
        Self {
            fixes: Ring::new(),
            navs: Ring::new(),
            out: Ring::new(),
        }
    }

    fn on_fix(&mut self, f: UwbFix) {
        self.fixes.push(f);
        self.process();
    }

    fn on_nav(&mut self, n: NavState) {
        self.navs.push(n);
        self.process();
    }

    fn process(&mut self) {
        while let Some(f) = self.fixes.front().copied() {
            let t = f.header.meas_time_ns;
            let Some(n) = self
                .navs
                .iter()
                .find(|n| n.header.meas_time_ns >= t)
                .copied()
            else {
                return;
            };
            self.fixes.pop();
            self.out.push((f, n));
        }
    }
}

fn run_fusion(cfg: &FloorConfig) -> Result<(), FloorError> {
    let stage = Stage::new(cfg.runtime(Role::Fusion))?;
    let nav_sub = stage.subscriber::<NavState>(topics::NAV)?;
    let fix_sub = stage.subscriber::<UwbFix>(topics::UWB_FIX)?;
    let mut fused_pub = stage.publisher::<FusedState>(topics::FUSED)?;
    let mut diag_pub = stage.publisher::<FilterDiag>(topics::DIAG)?;
    let mut corr_pub = stage.publisher::<InsCorrection>(topics::CORRECTION)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let nav_a = waiter.attach(&nav_sub)?;
    let fix_a = waiter.attach(&fix_sub)?;
    // The fusion stage's coasting/staleness tick (0.5 / coast rate, at most 50 ms).
    let _tick = waiter.attach_interval(Duration::from_millis(50))?;
    let hb = waiter.attach_interval(health.period())?;
    let mut m = Matcher::new();
    let mut correction_id = 0u64;
    let mut counters = HealthCounters::default();
    // The fusion stage's wake-up shortly before each fix is due (it warms
    // its update there; this node has nothing to warm).
    let mut next_fix = Anticipator::new();
    loop {
        let wake = waiter.wait_deadline(next_fix.deadline_within(monotonic_ns(), 500_000_000))?;
        let Wake::Fired(f) = wake else {
            if matches!(wake, Wake::Shutdown) {
                break;
            }
            next_fix.take_due(monotonic_ns());
            continue;
        };
        if f.contains(&nav_a) || f.contains(&fix_a) {
            fix_sub.drain(|x| {
                next_fix.observe(x.header.meas_time_ns, x.header.pub_time_ns);
                m.on_fix(x);
            })?;
            nav_sub.drain(|n| m.on_nav(n))?;
            // Fused states, corrections, diagnostics: the fusion stage's order.
            for (x, n) in m.out.iter() {
                fused_pub.publish(FusedState {
                    header: Header {
                        flags: FusedState::FLAG_VALID,
                        ..Header::new(0, x.header.meas_time_ns)
                    },
                    quat: [1.0, 0.0, 0.0, 0.0],
                    uwb_seq: x.header.seq,
                    uwb_meas_time_ns: x.header.meas_time_ns,
                    uwb_pub_time_ns: x.header.pub_time_ns,
                    ins_seq: n.header.seq,
                    ins_meas_time_ns: n.header.meas_time_ns,
                    ins_pub_time_ns: n.header.pub_time_ns,
                    ..FusedState::default()
                })?;
            }
            for (x, n) in m.out.iter() {
                correction_id += 1;
                corr_pub.publish(InsCorrection {
                    header: Header::new(0, x.header.meas_time_ns),
                    correction_id,
                    apply_at_seq: n.imu_seq,
                    imu_generation: n.imu_generation,
                    reset_quat: [1.0, 0.0, 0.0, 0.0],
                    ..InsCorrection::default()
                })?;
            }
            for (x, _) in m.out.iter() {
                diag_pub.publish(FilterDiag {
                    header: Header::new(0, x.header.meas_time_ns),
                    dim: 2,
                    ..FilterDiag::default()
                })?;
            }
            m.out.clear();
        }
        if f.contains(&hb) {
            counters.add_sub(&nav_sub.stats());
            counters.add_sub(&fix_sub.stats());
            counters.published = fused_pub.published();
            health.report(&counters, HealthState::Ok)?;
            counters = HealthCounters::default();
            fused_pub.update_connections()?;
        }
        next_fix.take_due(monotonic_ns());
    }
    health.report(&counters, HealthState::Stopping)?;
    Ok(())
}

/// Records of the floor logger, preallocated and bounded.
#[derive(Debug)]
struct Keep {
    records: Vec<Record>,
    recv: Vec<RecvStamp>,
    dropped: u64,
}

impl Keep {
    fn push(&mut self, r: Record) {
        if self.records.len() < self.records.capacity() {
            self.records.push(r);
        } else {
            self.dropped += 1;
        }
    }

    fn fused(&mut self, s: FusedState, sub: &Sub<FusedState>) {
        if self.recv.len() < self.recv.capacity() {
            self.recv.push(RecvStamp {
                seq: s.header.seq,
                pub_time_ns: s.header.pub_time_ns,
                receive_ns: sub.last_receive_ns().unwrap_or_else(monotonic_ns),
            });
        }
        self.push(Record::Fused(s));
    }
}

fn run_logger(cfg: &FloorConfig) -> Result<(), FloorError> {
    let stage = Stage::new(cfg.runtime(Role::Logger))?;
    let mut keep = Keep {
        records: Vec::with_capacity(cfg.max_records),
        recv: Vec::with_capacity(cfg.max_records / 8 + 1),
        dropped: 0,
    };
    let imu = stage.subscriber::<ImuSample>(topics::IMU)?;
    let tdoa = stage.subscriber::<UwbTdoa>(topics::UWB_TDOA)?;
    let fix = stage.subscriber::<UwbFix>(topics::UWB_FIX)?;
    let nav = stage.subscriber::<NavState>(topics::NAV)?;
    let corr = stage.subscriber::<InsCorrection>(topics::CORRECTION)?;
    let fused = stage.subscriber::<FusedState>(topics::FUSED)?;
    let diag = stage.subscriber::<FilterDiag>(topics::DIAG)?;
    let truth = stage.subscriber::<GroundTruth>(topics::TRUTH)?;
    let hsub = stage.subscriber::<Health>(topics::HEALTH)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    // As the pipeline's logger: fused states wake it, the other topics are
    // drained then, or 50 ms after the last drain when no fused state came.
    let fused_a = waiter.attach(&fused)?;
    let mut bulk = DrainClock::new(50_000_000, monotonic_ns());
    let hb = waiter.attach_interval(health.period())?;
    let mut counters = HealthCounters::default();
    loop {
        let wake = waiter.wait_deadline(bulk.deadline())?;
        let Some(next) = bulk.after(&wake, &fused_a, &hb, monotonic_ns()) else {
            break;
        };
        if next.drain {
            fused.drain(|s| keep.fused(s, &fused))?;
            imu.drain(|s| keep.push(Record::Imu(s)))?;
            tdoa.drain(|s| keep.push(Record::Tdoa(s)))?;
            fix.drain(|s| keep.push(Record::Fix(s)))?;
            nav.drain(|s| keep.push(Record::Nav(s)))?;
            corr.drain(|s| keep.push(Record::Correction(s)))?;
            diag.drain(|s| keep.push(Record::Diag(s)))?;
            truth.drain(|s| keep.push(Record::Truth(s)))?;
            hsub.drain(|s| keep.push(Record::Health(s)))?;
            bulk.drained(monotonic_ns());
        }
        if next.beat {
            counters = HealthCounters::default();
            for st in [imu.stats(), tdoa.stats(), fused.stats(), nav.stats()] {
                counters.add_sub(&st);
            }
            counters.stage = StageCounters::Logger(LoggerCounters {
                sent: keep.records.len() as u64,
                dropped: keep.dropped,
            });
            health.report(&counters, HealthState::Ok)?;
        }
    }
    let _ = health.report(&counters, HealthState::Stopping);
    if keep.dropped > 0 {
        tracing::warn!(
            "floor logger: {} records beyond max_records = {} were not kept",
            keep.dropped,
            cfg.max_records
        );
    }
    if let Some(dir) = &cfg.trace_dir {
        write_records(&dir.join(FLOOR_LOG_FILE), &keep.records)?;
        trace::write(&dir.join(FUSED_TRACE_FILE), &keep.recv)?;
    }
    Ok(())
}

fn write_records(path: &std::path::Path, records: &[Record]) -> Result<(), FloorError> {
    let err = |reason: String| FloorError::Log {
        path: path.display().to_string(),
        reason,
    };
    let mut w = LogWriter::create(path, &Metadata::new("insuwb floor logger"), monotonic_ns())
        .map_err(|e| err(e.to_string()))?;
    for r in records {
        w.append(r).map_err(|e| err(e.to_string()))?;
    }
    w.finish().map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fix(seq: u64, t: u64) -> UwbFix {
        UwbFix {
            header: Header::new(seq, t),
            ..UwbFix::default()
        }
    }

    fn nav(seq: u64, t: u64) -> NavState {
        NavState {
            header: Header::new(seq, t),
            imu_seq: seq,
            ..NavState::default()
        }
    }

    fn drain(m: &mut Matcher) -> Vec<(u64, u64)> {
        let mut v = Vec::new();
        while let Some((f, n)) = m.out.pop() {
            v.push((f.header.seq, n.header.seq));
        }
        v
    }

    #[test]
    fn a_fix_waits_for_the_ins_state_covering_its_epoch() {
        let mut m = Matcher::new();
        m.on_nav(nav(0, 90));
        m.on_fix(fix(7, 100));
        assert!(drain(&mut m).is_empty(), "INS at 90 does not cover 100");
        m.on_nav(nav(1, 100));
        assert_eq!(drain(&mut m), vec![(7, 1)]);
    }

    #[test]
    fn a_late_fix_takes_the_first_ins_state_at_or_after_it() {
        let mut m = Matcher::new();
        for k in 0..5 {
            m.on_nav(nav(k, 100 + 10 * k));
        }
        // Epoch 115: the state at 120 (seq 2) covers it, not the newest.
        m.on_fix(fix(3, 115));
        m.on_fix(fix(4, 140));
        assert_eq!(drain(&mut m), vec![(3, 2), (4, 4)]);
        // Fixes keep their order: a later one never overtakes a waiting one.
        m.on_fix(fix(5, 200));
        m.on_fix(fix(6, 150));
        m.on_nav(nav(9, 210));
        assert_eq!(drain(&mut m), vec![(5, 9), (6, 9)]);
    }

    #[test]
    fn rings_are_bounded_and_keep_order() {
        let mut r = Ring::<u64>::new();
        for i in 0..(FUSION_RING as u64 + 10) {
            r.push(i);
        }
        assert_eq!(r.iter().count(), FUSION_RING);
        assert_eq!(r.front(), Some(&10));
        assert_eq!(r.iter().last(), Some(&(FUSION_RING as u64 + 9)));
        let mut n = 0;
        while r.pop().is_some() {
            n += 1;
        }
        assert_eq!(n, FUSION_RING);
        assert_eq!(r.pop(), None);
    }

    #[test]
    fn roles_parse_by_name_and_config_validates() {
        for r in Role::ALL {
            assert_eq!(r.name().parse::<Role>(), Ok(r));
        }
        assert!("gps"
            .parse::<Role>()
            .unwrap_err()
            .to_string()
            .contains("gps"));
        assert!(FloorConfig::default().validate().is_ok());
        let e = FloorConfig {
            imu_rate_hz: 0.0,
            ..FloorConfig::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("floor.imu_rate_hz"), "{e}");
        let e = FloorConfig {
            tdoa_per_epoch: 0,
            ..FloorConfig::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("floor.tdoa_per_epoch"), "{e}");
        let e = FloorConfig {
            max_records: 0,
            ..FloorConfig::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("floor.max_records"), "{e}");
        let c: FloorConfig = toml::from_str("imu_rate_hz = 200.0").unwrap();
        assert_eq!(c.imu_rate_hz, 200.0);
        assert!(toml::from_str::<FloorConfig>("imu_rate = 200.0").is_err());
    }
}
