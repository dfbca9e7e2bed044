//! The process group run that `launch`, `demo`, `chaos` and the latency
//! bench share: start the stages, supervise them, and report what the
//! group measured.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use insuwb_group::launch::{shutdown_order, supervise, FaultInjector, LoopEnd, LoopOptions, Watch};
use insuwb_group::robot::{choose_start_epoch, RobotConfig, START_EPOCH_ENV};
use insuwb_launch::{StageSpec, Supervisor};
use insuwb_msg::{
    topics, FusedState, GroundTruth, Health, ImuSample, StageCounters, StageRole, UwbFix,
};
use insuwb_runtime::{cleanup, monotonic_ns, Stage, Wake};

use crate::monitor::Monitor;
use crate::resources::{self, ProcessResources};

/// The stage binaries ([`StageRole::program`]) live next to this executable.
fn stage_program(stage: StageRole) -> Result<PathBuf> {
    crate::beside::program(stage.program())
}

/// What a group run measured.
#[derive(Debug, Default, serde::Serialize)]
pub struct GroupReport {
    /// Horizontal RMS error of the valid fused states against ground truth, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rmse_horizontal: Option<f64>,
    /// Valid fused states that ground truth was found for (the RMSE's count).
    pub rmse_states: u64,
    /// Rate of fused states from UWB updates, Hz.
    pub fused_rate_hz: f64,
    /// Rate of IMU samples, Hz.
    pub imu_rate_hz: f64,
    /// Rate of UWB fixes, Hz.
    pub uwb_fix_rate_hz: f64,
    /// Stage restarts.
    pub restarts: u32,
    /// UWB fix publish to fused publish, p50, us.
    pub latency_p50_us: f64,
    /// p99, us.
    pub latency_p99_us: f64,
    /// Samples dropped in the group (invalid, out of order, version, logger overflow).
    pub dropped: u64,
    /// Outliers flagged by the filter.
    pub outliers: u64,
    /// Fused states published while coasting (no UWB).
    pub degraded: u64,
    /// Largest gap between valid fused states from UWB updates, ms.
    pub max_gap_ms: f64,
    /// When it started, s after the group's start.
    pub max_gap_at_s: f64,
    /// The last fault injected before it started (`STAGE SIGNAL at T s`),
    /// if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_gap_after: Option<String>,
    /// Seconds run.
    pub duration_s: f64,
    /// Faults injected.
    pub faults: u32,
    /// Stretches of more than 5 s without a valid fused state after the first one.
    pub deadlocks: u32,
    /// Optional stages the launcher gave up after they exhausted their
    /// restart budget (the rest kept running).
    pub gave_up: Vec<String>,
    /// Each stage's last heartbeat figures, by stage name.
    pub stages: std::collections::BTreeMap<String, StageFigures>,
    /// The periodic looks of [`RunOptions::sample_every`], in order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub samples: Vec<ResourceSample>,
}

/// Most processes one look records (the launcher and its stages).
pub const MAX_LOOKED: usize = 16;

/// Longest process name a look keeps, bytes (longer ones are cut).
const LOOKED_NAME_LEN: usize = 24;

/// A process's name as a look keeps it: inline, no heap.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct LookedName {
    len: u8,
    bytes: [u8; LOOKED_NAME_LEN],
}

impl LookedName {
    fn new(name: &str) -> Self {
        let mut end = name.len().min(LOOKED_NAME_LEN);
        while !name.is_char_boundary(end) {
            end -= 1;
        }
        let mut bytes = [0; LOOKED_NAME_LEN];
        bytes[..end].copy_from_slice(&name.as_bytes()[..end]);
        Self {
            len: end as u8,
            bytes,
        }
    }

    fn as_str(&self) -> &str {
        std::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("?")
    }
}

/// The processes of one look: a table of fixed size, so that a look
/// allocates nothing and the looks kept for the report, reserved and
/// touched when the run starts, do not grow the launcher as they fill.
/// Serialised as a map from name to resources.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LookedProcesses {
    entries: [Option<(LookedName, ProcessResources)>; MAX_LOOKED],
}

impl LookedProcesses {
    /// Records `r` under `name` (replacing an entry of that name); false
    /// when the table is full.
    pub fn insert(&mut self, name: &str, r: ProcessResources) -> bool {
        let key = LookedName::new(name);
        let slot = self
            .entries
            .iter()
            .position(|e| e.is_some_and(|(n, _)| n == key))
            .or_else(|| self.entries.iter().position(Option::is_none));
        match slot.and_then(|i| self.entries.get_mut(i)) {
            Some(e) => {
                *e = Some((key, r));
                true
            }
            None => false,
        }
    }

    /// The resources recorded under `name`.
    #[must_use]
    pub fn get(&self, name: &str) -> Option<&ProcessResources> {
        self.iter().find(|(n, _)| *n == name).map(|(_, r)| r)
    }

    /// Each process's name and resources.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &ProcessResources)> {
        self.entries.iter().flatten().map(|(n, r)| (n.as_str(), r))
    }

    /// The processes recorded.
    #[must_use]
    pub fn len(&self) -> usize {
        self.entries.iter().flatten().count()
    }

    /// Forgets every process.
    #[cfg(test)]
    pub fn clear(&mut self) {
        self.entries = [None; MAX_LOOKED];
    }
}

impl serde::Serialize for LookedProcesses {
    fn serialize<S: serde::Serializer>(&self, ser: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap as _;
        let mut m = ser.serialize_map(Some(self.len()))?;
        for (n, r) in self.iter() {
            m.serialize_entry(n, r)?;
        }
        m.end()
    }
}

/// One periodic look at a running group ([`RunOptions::sample_every`]).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ResourceSample {
    /// Seconds since the group started.
    pub elapsed_s: f64,
    /// Fused states from UWB updates since the last look, per second.
    pub fused_rate_hz: f64,
    /// Horizontal RMS error of the valid fused states compared with ground
    /// truth since the last look, m (`None`: none compared).
    pub rmse_horizontal: Option<f64>,
    /// Restarts so far.
    pub restarts: u32,
    /// The group's files in /dev/shm and under its iceoryx2 root.
    pub group_files: usize,
    /// Each live process (the stages by name, from their last heartbeat's
    /// pid, and `launcher`, this process).
    pub processes: LookedProcesses,
}

/// The sampler of [`RunOptions::sample_every`].
struct Sampler {
    every: Duration,
    last: Instant,
    /// Valid updates counted at the last look.
    updates: u64,
    /// The monitor's accuracy sums at the last look.
    accuracy: (f64, usize),
    prefix: String,
    iox_root: PathBuf,
    samples: Vec<ResourceSample>,
}

/// The looks a run keeps, reserved and touched now (the run's length of
/// looks and two, or a day of one a minute without a length): filling
/// them later does not grow the launcher's memory.
fn reserved_looks(duration: Option<Duration>, every: Duration) -> Vec<ResourceSample> {
    let n = match duration {
        Some(d) if !every.is_zero() => (d.as_secs_f64() / every.as_secs_f64()).ceil() as usize + 2,
        _ => 1440,
    }
    .min(100_000);
    let mut looks = vec![ResourceSample::default(); n];
    looks.clear();
    looks
}

impl Sampler {
    /// Takes a look if one is due at `now`.
    fn look(&mut self, mon: &Monitor, restarts: u32, now: Instant, elapsed: Duration) {
        let dt = now.duration_since(self.last);
        if dt < self.every {
            return;
        }
        self.last = now;
        let (updates, _) = mon.live();
        let rate = updates.saturating_sub(self.updates) as f64 / dt.as_secs_f64();
        self.updates = updates;
        let (se, n) = mon.accuracy_sums();
        let (se0, n0) = std::mem::replace(&mut self.accuracy, (se, n));
        let rmse = (n > n0).then(|| ((se - se0) / (n - n0) as f64).sqrt());
        let mut processes = LookedProcesses::default();
        if let Some(r) = resources::of_process(std::process::id()) {
            processes.insert("launcher", r);
        }
        for (name, h) in &mon.health {
            if let Some(r) = resources::of_process(h.pid) {
                processes.insert(name, r);
            }
        }
        let s = ResourceSample {
            elapsed_s: elapsed.as_secs_f64(),
            fused_rate_hz: rate,
            rmse_horizontal: rmse,
            restarts,
            group_files: resources::group_files(&self.prefix, &self.iox_root),
            processes,
        };
        tracing::info!(
            "[{:7.1} s] fused {:5.2} Hz, RMS {} m, restarts {}, group files {}, anonymous RSS {} KiB and {} descriptors in {} processes",
            s.elapsed_s,
            s.fused_rate_hz,
            s.rmse_horizontal
                .map_or_else(|| "-".to_owned(), |r| format!("{r:.3}")),
            s.restarts,
            s.group_files,
            s.processes.iter().map(|(_, p)| p.rss_anon_kib).sum::<u64>(),
            s.processes.iter().map(|(_, p)| p.fds).sum::<u64>(),
            s.processes.len()
        );
        self.samples.push(s);
    }
}

/// A stage's counters from its last heartbeat (`Health`): those every stage
/// keeps, and those of its kind by name (`counters`, see
/// `insuwb_msg::StageCounters`: e.g. `fixes` of the UWB driver, `outliers`
/// of fusion, `dropped` of the logger, `clock_offset_ns` of a device
/// driver).
#[derive(Debug, Default, serde::Serialize)]
pub struct StageFigures {
    /// Samples published.
    pub published: u64,
    /// Samples received.
    pub received: u64,
    /// Dropped for a NaN, infinite or out-of-range value.
    pub dropped_invalid: u64,
    /// Dropped for a timestamp going backwards or repeated.
    pub dropped_time: u64,
    /// Dropped for another layout version.
    pub dropped_version: u64,
    /// Samples missing on inputs.
    pub seq_gaps: u64,
    /// The counters of the stage's kind, by name (empty for a kind this
    /// version does not know).
    pub counters: StageCounters,
    /// Last state reported, in the words of every report
    /// (`insuwb_report::health::StageCondition::name`): ok, degraded,
    /// disconnected, stopping or unknown.
    pub state: &'static str,
}

/// Options of a group run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Stop after this long (None: until SIGINT/SIGTERM).
    pub duration: Option<Duration>,
    /// Print a live line each second on standard error.
    pub live: bool,
    /// Faults to inject: signal a stage at a time after start.
    pub faults: Vec<Fault>,
    /// Chaos: every 1-5 s a random stage gets SIGKILL, or SIGSTOP for 2 s
    /// then SIGCONT, drawn from this seed.
    pub chaos_seed: Option<u64>,
    /// Every this long, a look at each process's resident memory and open
    /// files, the group's shared-memory files and the fused rate since the
    /// last look ([`ResourceSample`], in the report's `samples`).
    pub sample_every: Option<Duration>,
    /// Extra environment variables of every stage process (e.g. the logger's
    /// fused receive trace for `insuwb bench latency`).
    pub env: Vec<(String, String)>,
}

pub use insuwb_group::launch::Fault;

/// What a group run may be given besides its [`RunOptions`] (the device
/// demo, whose emulators are paced to the epoch and whose drivers publish
/// no ground truth).
#[derive(Debug, Default)]
pub struct GroupExtras {
    /// The start epoch (CLOCK_MONOTONIC ns) instead of one chosen at start.
    pub start_epoch_ns: Option<u64>,
    /// Ground truth known beforehand, CLOCK_MONOTONIC times, taken with the
    /// truth topic's for the accuracy figures.
    pub truth: Vec<GroundTruth>,
}

/// Starts the group of `cfg` (from the file `cfg_path`), supervises it and
/// returns what it measured once it stops.
pub fn run_group(cfg_path: &Path, cfg: &RobotConfig, opts: &RunOptions) -> Result<GroupReport> {
    run_group_with(cfg_path, cfg, opts, GroupExtras::default())
}

/// [`run_group`] with [`GroupExtras`].
pub fn run_group_with(
    cfg_path: &Path,
    cfg: &RobotConfig,
    opts: &RunOptions,
    extras: GroupExtras,
) -> Result<GroupReport> {
    // Owner-only files (0600/0700) for the launcher and, inherited, every stage.
    insuwb_runtime::perm::restrict_umask();
    // One group per prefix and run directory: a second launch refuses here,
    // before it cleans, removes or creates anything (insuwb_stage::lock).
    let _group_lock = insuwb_stage::lock::GroupLock::acquire(&cfg.group)?;
    if insuwb_runtime::perm::is_shared(&cfg.group.run_dir) {
        tracing::warn!(
            "the run directory {} has group or other permission bits",
            cfg.group.run_dir.display()
        );
    }
    std::fs::create_dir_all(&cfg.group.run_dir).with_context(|| {
        format!(
            "{}: cannot create the run directory",
            cfg.group.run_dir.display()
        )
    })?;
    // Resources left by a previous run of this group that died are removed
    // by the first stage that starts (`Stage::new` cleans its deployment's
    // dead nodes), the launcher's own monitor node included.
    let rt = cfg.runtime("launcher");
    let epoch = extras
        .start_epoch_ns
        .unwrap_or_else(|| choose_start_epoch(monotonic_ns() + 500_000_000));
    let cfg_arg = cfg_path.display().to_string();
    let mut specs = Vec::new();
    for s in &cfg.stages {
        let mut spec = StageSpec::new(s.name(), stage_program(*s)?, &["--config", &cfg_arg]);
        spec.env
            .push((START_EPOCH_ENV.to_owned(), epoch.to_string()));
        spec.env.extend(opts.env.iter().cloned());
        specs.push(spec);
    }
    let monitor_stage = Stage::new(rt.clone())?;
    let waiter = monitor_stage.waiter()?;
    let tick = waiter.attach_interval(Duration::from_millis(50))?;
    let mut watch = GroupWatch {
        fused: monitor_stage.subscriber::<FusedState>(topics::FUSED)?,
        truth: monitor_stage.subscriber::<GroundTruth>(topics::TRUTH)?,
        imu: monitor_stage.subscriber::<ImuSample>(topics::IMU)?,
        fix: monitor_stage.subscriber::<UwbFix>(topics::UWB_FIX)?,
        health: monitor_stage.subscriber::<Health>(topics::HEALTH)?,
        waiter: &waiter,
        mon: Monitor::new(extras.truth),
        live: opts.live.then(|| LiveLine {
            last: Instant::now(),
            counts: (0, 0, 0),
        }),
        sampler: opts.sample_every.map(|every| Sampler {
            every,
            last: Instant::now(),
            updates: 0,
            accuracy: (0.0, 0),
            prefix: cfg.group.prefix.clone(),
            iox_root: cfg.iox_root(),
            samples: reserved_looks(opts.duration, every),
        }),
    };

    // No before-restart hook: a restarted stage removes the dead nodes of its
    // deployment itself when it starts (`Stage::new`), before it creates its
    // own. Listing iceoryx2's nodes here made some 40 000 short-lived
    // allocations per restart in the launcher, which fragmented its heap
    // over hours (docs/RELIABILITY.md).
    let mut sup = Supervisor::new(cfg.launch.clone(), specs)?;
    let mut faults = FaultInjector::new(
        opts.faults.clone(),
        opts.chaos_seed,
        cfg.stages.iter().map(|s| s.name().to_owned()).collect(),
        opts.duration,
    );
    let loop_opts = LoopOptions {
        duration: opts.duration,
        max_wait: Duration::from_millis(100),
        // Sources first, the bridges after fusion, the logger last.
        shutdown_order: shutdown_order(&cfg.stages),
    };
    let t0 = Instant::now();
    let t0_ns = monotonic_ns();
    let end = supervise(&mut sup, t0, &loop_opts, &mut watch, Some(&mut faults))?;
    let elapsed = t0.elapsed().as_secs_f64();
    let failed = match end {
        LoopEnd::NotStarted(e) => return Err(e.into()),
        LoopEnd::Failed(stage) => Some(stage),
        LoopEnd::Duration | LoopEnd::Shutdown => None,
    };
    let GroupWatch {
        fused,
        truth,
        imu,
        fix,
        health,
        mut mon,
        sampler,
        ..
    } = watch;
    let restarts = sup.total_restarts();
    let (mut report, mon_gap_start_ns) = summarise(&mut mon, restarts, elapsed);
    report.samples = sampler.map(|s| s.samples).unwrap_or_default();
    report.faults = faults.injected();
    if report.max_gap_ms > 0.0 {
        let start = Duration::from_nanos(mon_gap_start_ns.saturating_sub(t0_ns));
        report.max_gap_at_s = start.as_secs_f64();
        report.max_gap_after = faults.last_before(start).map(|f| {
            let name = match f.signal {
                9 => "SIGKILL".to_owned(),
                19 => "SIGSTOP".to_owned(),
                n => format!("signal {n}"),
            };
            format!("{} {name} at {:.1} s", f.stage, f.at.as_secs_f64())
        });
    }
    report.gave_up = sup.given_up();
    drop(tick);
    drop(waiter);
    drop((fused, truth, imu, fix, health));
    drop(monitor_stage);
    let removed = cleanup::remove_prefix_files(&cfg.group.prefix, Some(&cfg.iox_root()));
    if let Err(e) = removed {
        tracing::warn!("removing the group's shared-memory files: {e}");
    }
    if let Some(stage) = failed {
        bail!("stage {stage} exhausted its restart budget");
    }
    Ok(report)
}

/// The launcher's view of its group in the launch loop: the topics it
/// measures, the heartbeats it forwards to the supervisor, and the live
/// line (`--live`).
struct GroupWatch<'w> {
    fused: insuwb_runtime::Sub<FusedState>,
    truth: insuwb_runtime::Sub<GroundTruth>,
    imu: insuwb_runtime::Sub<ImuSample>,
    fix: insuwb_runtime::Sub<UwbFix>,
    health: insuwb_runtime::Sub<Health>,
    waiter: &'w insuwb_runtime::Waiter,
    mon: Monitor,
    live: Option<LiveLine>,
    sampler: Option<Sampler>,
}

/// The last live line's time and counts (IMU samples, fixes, updates).
struct LiveLine {
    last: Instant,
    counts: (u64, u64, u64),
}

impl Watch for GroupWatch<'_> {
    type Error = anyhow::Error;

    fn wait(&mut self, max: Duration) -> Result<bool> {
        Ok(matches!(self.waiter.wait_timeout(max)?, Wake::Shutdown))
    }

    fn on_wake(&mut self, sup: &mut Supervisor, now: Instant, elapsed: Duration) -> Result<()> {
        let mon = &mut self.mon;
        // Fixes before the fused states: a coasting state closes a gap only
        // if no fix was published in it.
        self.fix.drain(|s| mon.fix(&s))?;
        self.fused.drain(|f| mon.fused(&f))?;
        self.truth.drain(|t| mon.truth(t))?;
        mon.settle();
        self.imu.drain(|s| mon.imu.count(s.header.meas_time_ns))?;
        self.health.drain(|h| {
            let name = insuwb_msg::name_str(&h.stage);
            sup.note_heartbeat_from(&name, h.pid, now);
            mon.health.insert(name, h);
        })?;
        if let Some(s) = self.sampler.as_mut() {
            s.look(mon, sup.total_restarts(), now, elapsed);
        }
        if let Some(live) = self.live.as_mut() {
            if now.duration_since(live.last) >= Duration::from_secs(1) {
                let dt = now.duration_since(live.last).as_secs_f64();
                live.last = now;
                let (upd, p) = mon.live();
                let c = (mon.imu.n(), mon.fixes.n(), upd);
                let outliers = fusion_outliers(&mon.health);
                eprintln!(
                    "[{:5.1} s] imu {:6.1} Hz  uwb {:5.1} Hz  fused {:5.1} Hz  pos ({:6.2}, {:6.2})  outliers {outliers}  restarts {}",
                    elapsed.as_secs_f64(),
                    (c.0 - live.counts.0) as f64 / dt,
                    (c.1 - live.counts.1) as f64 / dt,
                    (c.2 - live.counts.2) as f64 / dt,
                    p[0],
                    p[1],
                    sup.total_restarts()
                );
                live.counts = c;
            }
        }
        Ok(())
    }
}

/// Measurement components the fusion stage weighted as outliers, from its
/// last heartbeat (0 without one).
fn fusion_outliers(health: &std::collections::BTreeMap<String, Health>) -> u64 {
    match health.get(StageRole::Fusion.name()).map(Health::counters) {
        Some(Ok(StageCounters::Fusion(c))) => c.outliers,
        _ => 0,
    }
}

/// Records the logger dropped, from its last heartbeat (0 without one).
fn logger_dropped(health: &std::collections::BTreeMap<String, Health>) -> u64 {
    match health.get(StageRole::Logger.name()).map(Health::counters) {
        Some(Ok(StageCounters::Logger(c))) => c.dropped,
        _ => 0,
    }
}

/// The report of a run, and when its largest gap started (CLOCK_MONOTONIC ns).
fn summarise(mon: &mut Monitor, restarts: u32, elapsed: f64) -> (GroupReport, u64) {
    let fig = mon.finish();
    let gap_start_ns = fig.max_gap_start_ns;
    let dropped: u64 = mon
        .health
        .values()
        .map(|h| h.dropped_invalid + h.dropped_time + h.dropped_version)
        .sum::<u64>()
        + logger_dropped(&mon.health);
    let report = GroupReport {
        rmse_horizontal: fig.rmse_horizontal,
        rmse_states: fig.compared,
        fused_rate_hz: fig.fused_rate_hz,
        imu_rate_hz: mon.imu.rate(),
        uwb_fix_rate_hz: mon.fixes.rate(),
        restarts,
        latency_p50_us: fig.latency_p50_us,
        latency_p99_us: fig.latency_p99_us,
        dropped,
        outliers: fusion_outliers(&mon.health),
        degraded: fig.degraded,
        max_gap_ms: fig.max_gap_ms,
        max_gap_at_s: 0.0,
        max_gap_after: None,
        duration_s: elapsed,
        faults: 0,
        deadlocks: fig.deadlocks,
        gave_up: Vec::new(),
        samples: Vec::new(),
        stages: mon
            .health
            .iter()
            .map(|(name, h)| {
                let f = StageFigures {
                    published: h.published,
                    received: h.received,
                    dropped_invalid: h.dropped_invalid,
                    dropped_time: h.dropped_time,
                    dropped_version: h.dropped_version,
                    seq_gaps: h.seq_gaps,
                    counters: h.counters().unwrap_or_default(),
                    state: insuwb_report::health::StageCondition::of_state(h.state).name(),
                };
                (name.clone(), f)
            })
            .collect(),
    };
    (report, gap_start_ns)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    fn res(pid: u32) -> ProcessResources {
        ProcessResources {
            pid,
            rss_kib: 2000,
            rss_anon_kib: 1000,
            fds: 7,
        }
    }

    /// A look's table holds each name once, refuses a seventeenth process,
    /// and serialises as a map; the reserved looks are empty, with room
    /// for the run.
    #[test]
    fn a_look_records_its_processes_in_place() {
        let mut t = LookedProcesses::default();
        assert!(t.insert("launcher", res(1)));
        assert!(t.insert("fusion", res(2)));
        assert!(t.insert("fusion", res(3)));
        assert_eq!(t.len(), 2);
        assert_eq!(t.get("fusion").map(|r| r.pid), Some(3));
        assert_eq!(t.get("imu"), None);
        let json = serde_json::to_value(t).unwrap();
        assert_eq!(json["launcher"]["pid"], 1);
        assert_eq!(json.as_object().map(|o| o.len()), Some(2));
        for i in 2..MAX_LOOKED {
            assert!(t.insert(&format!("stage{i}"), res(10)));
        }
        assert!(!t.insert("one-too-many", res(11)));
        // A long name is cut at a character boundary.
        let mut u = LookedProcesses::default();
        assert!(u.insert("ééééééééééééééééééééé", res(12)));
        assert_eq!(u.iter().next().map(|(n, _)| n.len()), Some(24));
        u.clear();
        assert_eq!(u.len(), 0);
        let looks = reserved_looks(Some(Duration::from_secs(3600)), Duration::from_secs(60));
        assert!(looks.is_empty() && looks.capacity() >= 62);
        assert!(reserved_looks(None, Duration::from_secs(60)).capacity() >= 1440);
    }
}
