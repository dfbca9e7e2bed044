//! `insuwb launch`, `insuwb demo` and `insuwb inspect`: the process group.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use insuwb_devices::emulator::{DeviceSink, Faults, PlayReport, Player, PtyEmulator, TcpEmulator};
use insuwb_devices::Protocol;
use insuwb_group::launch::{shutdown_order, supervise, FaultInjector, LoopEnd, LoopOptions, Watch};
use insuwb_group::robot::{choose_start_epoch, RobotConfig, START_EPOCH_ENV};
use insuwb_launch::{StageSpec, Supervisor};
use insuwb_msg::{topics, FusedState, GroundTruth, Health, ImuSample, StageRole, UwbFix};
use insuwb_runtime::{cleanup, monotonic_ns, Stage, Wake};

use crate::monitor::Monitor;

/// The stage binaries ([`StageRole::program`]) live next to this executable.
fn stage_program(stage: StageRole) -> Result<PathBuf> {
    let exe = std::env::current_exe().context("locating the insuwb executable")?;
    let dir = exe
        .parent()
        .context("the insuwb executable has no folder")?;
    let p = dir.join(stage.program());
    if !p.is_file() {
        bail!(
            "stage binary {} not found (build the workspace: cargo build --release)",
            p.display()
        );
    }
    Ok(p)
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
}

/// A stage's counters from its last heartbeat (`Health`). Drivers: `extra`
/// of `uwb` is `[fixes, skipped too few pairs, skipped geometry, skipped
/// solver]` (see `insuwb_stage::driver`); of `fusion` `[_, outliers, ..]`; of
/// `logger` `[records sent, records dropped, ..]`.
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
    /// Stage-specific counters.
    pub extra: [u64; 4],
    /// Last state reported: ok, degraded, disconnected or stopping.
    pub state: &'static str,
    /// Device drivers: the device clock's offset to CLOCK_MONOTONIC, ns
    /// (`extra[2]`, decoded; absent while unknown).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clock_offset_ns: Option<i64>,
    /// Device drivers: the device clock's drift, parts per billion (`extra[3]`, decoded).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clock_drift_ppb: Option<i64>,
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
    let rt = cfg.runtime("launcher");
    // Resources left by a previous run of this group that died.
    let _ = cleanup::cleanup_dead_nodes(&rt);
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
    };

    let mut sup = Supervisor::new(cfg.launch.clone(), specs)?;
    let hook_rt = rt.clone();
    sup.set_before_restart(Box::new(
        move |stage: &str| match cleanup::cleanup_dead_nodes(&hook_rt) {
            Ok(n) if n > 0 => tracing::info!("cleaned {n} dead node(s) before restarting {stage}"),
            Ok(_) => {}
            Err(e) => tracing::warn!("cleaning dead nodes before restarting {stage}: {e}"),
        },
    ));
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
        ..
    } = watch;
    let restarts = sup.total_restarts();
    let mut report = summarise(&mut mon, restarts, elapsed);
    for (stage, src) in [
        (StageRole::Imu.name(), &cfg.sources.imu),
        (StageRole::Uwb.name(), &cfg.sources.uwb),
    ] {
        if src == "device" {
            if let Some(f) = report.stages.get_mut(stage) {
                (f.clock_offset_ns, f.clock_drift_ppb) =
                    insuwb_stage::device::clock_from_extra(&f.extra);
            }
        }
    }
    report.faults = faults.injected();
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
        self.fused.drain(|f| mon.fused(&f))?;
        self.truth.drain(|t| mon.truth(t))?;
        mon.settle();
        self.imu.drain(|s| mon.imu.count(s.header.meas_time_ns))?;
        self.fix.drain(|s| mon.fixes.count(s.header.meas_time_ns))?;
        self.health.drain(|h| {
            let name = insuwb_msg::name_str(&h.stage);
            sup.note_heartbeat_from(&name, h.pid, now);
            mon.health.insert(name, h);
        })?;
        if let Some(live) = self.live.as_mut() {
            if now.duration_since(live.last) >= Duration::from_secs(1) {
                let dt = now.duration_since(live.last).as_secs_f64();
                live.last = now;
                let (upd, p) = mon.live();
                let c = (mon.imu.n(), mon.fixes.n(), upd);
                let outliers: u64 = mon
                    .health
                    .get(StageRole::Fusion.name())
                    .map_or(0, |h| h.extra[1]);
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

fn summarise(mon: &mut Monitor, restarts: u32, elapsed: f64) -> GroupReport {
    let fig = mon.finish();
    let dropped: u64 = mon
        .health
        .values()
        .map(|h| h.dropped_invalid + h.dropped_time + h.dropped_version)
        .sum::<u64>()
        + mon
            .health
            .get(StageRole::Logger.name())
            .map_or(0, |h| h.extra[1]);
    GroupReport {
        rmse_horizontal: fig.rmse_horizontal,
        rmse_states: fig.compared,
        fused_rate_hz: fig.fused_rate_hz,
        imu_rate_hz: mon.imu.rate(),
        uwb_fix_rate_hz: mon.fixes.rate(),
        restarts,
        latency_p50_us: fig.latency_p50_us,
        latency_p99_us: fig.latency_p99_us,
        dropped,
        outliers: mon
            .health
            .get(StageRole::Fusion.name())
            .map_or(0, |h| h.extra[1]),
        degraded: fig.degraded,
        max_gap_ms: fig.max_gap_ms,
        duration_s: elapsed,
        faults: 0,
        deadlocks: fig.deadlocks,
        gave_up: Vec::new(),
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
                    extra: h.extra,
                    state: match h.state {
                        Health::STATE_OK => "ok",
                        Health::STATE_DEGRADED => "degraded",
                        Health::STATE_DISCONNECTED => "disconnected",
                        Health::STATE_STOPPING => "stopping",
                        _ => "unknown",
                    },
                    clock_offset_ns: None,
                    clock_drift_ppb: None,
                };
                (name.clone(), f)
            })
            .collect(),
    }
}

/// Arguments of `insuwb launch`.
#[derive(Debug, clap::Args)]
pub struct LaunchArgs {
    /// The robot group configuration (e.g. config/robot.toml).
    pub config: PathBuf,
    /// Stop after this many seconds (default: run until SIGINT/SIGTERM).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Inject a fault: STAGE@SECONDS[:SIGNAL] (KILL, TERM, STOP or a number); repeatable.
    #[arg(long)]
    pub fault: Vec<Fault>,
    /// Print the run's report as one JSON object on standard output.
    #[arg(long)]
    pub json: bool,
}

/// Runs `insuwb launch`.
pub fn launch(a: &LaunchArgs) -> Result<()> {
    let cfg = RobotConfig::load(&a.config)?;
    let report = run_group(
        &a.config,
        &cfg,
        &RunOptions {
            duration: a.duration.map(Duration::from_secs_f64),
            live: true,
            faults: a.fault.clone(),
            chaos_seed: None,
            env: Vec::new(),
        },
    )?;
    if a.json {
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &serde_json::to_value(&report)?)?;
        writeln!(out)?;
    } else {
        eprintln!("{}", serde_json::to_string_pretty(&report)?);
    }
    Ok(())
}

/// Arguments of `insuwb demo`.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Seconds to run (the scenario lasts 60 s).
    #[arg(long, default_value_t = 20.0)]
    pub duration: f64,
    /// Filter (kf, shaf, stf, iakf, iakf_tdoa).
    #[arg(long, default_value_t = insuwb_msg::FilterKind::Iakf)]
    pub filter: insuwb_msg::FilterKind,
    /// Print one JSON object on standard output.
    #[arg(long)]
    pub json: bool,
    /// Feed the drivers through emulated devices: the IMU driver reads WitMotion frames from a pseudo-terminal, the UWB driver Eliko `$PEKIO` lines from a loopback TCP port, both played from the same scenario and seed.
    #[arg(long)]
    pub via_devices: bool,
    /// Run the Foxglove live view too (stage `foxglove`) and print its address: open it in the Foxglove app (Open connection, Foxglove WebSocket).
    #[arg(long)]
    pub foxglove: bool,
    /// The live view's address, IP:PORT (implies --foxglove).
    #[arg(long, value_name = "IP:PORT")]
    pub foxglove_bind: Option<String>,
    /// Run the Zenoh bridge too (stage `zenoh`) as robot `demo` (or --robot ID), connected to ENDPOINT (e.g. tcp/127.0.0.1:7447, where a fleet station or any Zenoh peer or router listens): it publishes insuwb/demo/pose and insuwb/demo/health (docs/ZENOH.md).
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh: Option<String>,
    /// The robot id the Zenoh bridge publishes as (with --zenoh): two demos with different ids join one station as two robots.
    #[arg(long, value_name = "ID", default_value = "demo", requires = "zenoh")]
    pub robot: String,
}

/// The emulated devices of `insuwb demo --via-devices`, playing.
struct DemoDevices {
    imu: Player<PtyEmulator>,
    uwb: Player<TcpEmulator>,
}

impl DemoDevices {
    /// Stops both players and prints what they played.
    fn finish(self) {
        for (name, report) in [
            ("IMU (witmotion, pty)", self.imu.stop_and_join()),
            ("UWB (eliko, tcp)", self.uwb.stop_and_join()),
        ] {
            match report {
                Ok(r) => eprintln!("insuwb demo: {name}: {}", crate::emulate_cmd::summary(&r)),
                Err(e) => eprintln!("insuwb demo: {name}: {e}"),
            }
        }
    }
}

/// Stops a player and gives back its report (the device is closed).
trait StopAndJoin {
    fn stop_and_join(self) -> Result<PlayReport>;
}

impl<S: DeviceSink> StopAndJoin for Player<S> {
    fn stop_and_join(self) -> Result<PlayReport> {
        self.stop();
        Ok(self.join()?.1)
    }
}

/// The `[sources]` and `[devices.*]` of the device demo, and its devices
/// started: a WitMotion IMU on a pseudo-terminal (symlink `run_dir/imu`) and
/// an Eliko server on a loopback port, both playing the demo scenario from
/// `epoch`. Returns the config text, the devices, and the scenario's truth
/// at CLOCK_MONOTONIC times.
fn start_demo_devices(
    run_dir: &Path,
    epoch: u64,
) -> Result<(String, DemoDevices, Vec<GroundTruth>)> {
    use insuwb_devices::play::{self, Encoding};
    use insuwb_group::recording;
    let rec = recording::from_scenario(DEMO_SCENARIO, DEMO_SEED)?;
    let imu_enc = Encoding::new(Protocol::WitMotion);
    let uwb_enc = Encoding {
        tag: DEMO_TAG,
        ..Encoding::new(Protocol::Eliko)
    };
    let imu_chunks = play::imu_chunks(&rec.imu, &imu_enc)?;
    let uwb_chunks = play::uwb_chunks(&rec.fixes, &uwb_enc)?;
    let link = run_dir.join("imu");
    let pty = crate::emulate_cmd::open_pty(Some(&link))?;
    let tcp = crate::emulate_cmd::start_eliko(0)?;
    let port = tcp.port();
    let text = format!(
        "[sources]\nimu = \"device\"\nuwb = \"device\"\nscenario = \"{DEMO_SCENARIO}\"\nseed = {DEMO_SEED}\n\
         [devices.imu]\nsource = \"serial:{}\"\nprotocol = \"witmotion\"\nbaud = {}\n\
         [devices.uwb]\nsource = \"tcp:127.0.0.1:{port}\"\nprotocol = \"eliko\"\ntag_id = {DEMO_TAG}\n",
        link.display(),
        imu_enc.baud,
    );
    eprintln!(
        "insuwb demo: devices: WitMotion IMU on serial:{} ({} cycles), Eliko server on tcp:127.0.0.1:{port} ({} COORD lines)",
        link.display(),
        imu_chunks.len(),
        uwb_chunks.len()
    );
    let imu = Player::start(pty, imu_chunks, epoch, monotonic_ns, Faults::none())?;
    let uwb = Player::start(tcp, uwb_chunks, epoch, monotonic_ns, Faults::none())?;
    let truth = rec
        .truth
        .iter()
        .map(|t| {
            let mut t = *t;
            t.header.meas_time_ns = t.header.meas_time_ns.saturating_add(epoch);
            t
        })
        .collect();
    Ok((text, DemoDevices { imu, uwb }, truth))
}

/// The demo's scenario and seed (the plain and the device demo alike).
const DEMO_SCENARIO: &str = "nlos-long";
const DEMO_SEED: u64 = 1;
/// The Eliko tag id of the device demo.
const DEMO_TAG: u32 = 1;

/// Runs `insuwb demo`: the whole group on simulated sensors in real time.
pub fn demo(a: &DemoArgs) -> Result<()> {
    if !(a.duration.is_finite() && a.duration > 0.0 && a.duration <= 60.0) {
        bail!(
            "--duration must be in (0, 60] s (the demo scenario lasts 60 s), got {}",
            a.duration
        );
    }
    if let Some(e) = &a.zenoh {
        insuwb_zenoh::config::check_endpoint("connect", e)
            .map_err(|e| anyhow::anyhow!("--zenoh: {}", e.reason))?;
        insuwb_fleet::keys::check_robot_id(&a.robot)
            .map_err(|e| anyhow::anyhow!("--robot: {e}"))?;
    }
    if a.via_devices && a.filter == insuwb_msg::FilterKind::IakfTdoa {
        bail!("--via-devices needs a loosely coupled filter (kf, shaf, stf, iakf): the devices report positions, not TDOA");
    }
    let id = format!("{}_{}", std::process::id(), monotonic_ns() % 1_000_000);
    let run_dir = std::env::temp_dir().join(format!("insuwb-demo-{id}"));
    // Owner-only, as run_group makes everything else.
    insuwb_runtime::perm::restrict_umask();
    std::fs::create_dir_all(&run_dir)?;
    let result = demo_group(a, &id, &run_dir);
    let _ = std::fs::remove_dir_all(&run_dir);
    let r = result?;
    if a.json {
        let v = serde_json::to_value(&r)?;
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &v)?;
        writeln!(out)?;
    } else {
        println!(
            "accuracy: horizontal RMS {} m against ground truth\nrates: fused {:.2} Hz, IMU {:.1} Hz, UWB fixes {:.1} Hz\nrestarts: {}\nlatency UWB fix -> fused: p50 {:.0} us, p99 {:.0} us\ndropped: {}, outliers flagged: {}, degraded outputs: {}",
            r.rmse_horizontal.map_or("n/a".into(), |v| format!("{v:.3}")),
            r.fused_rate_hz,
            r.imu_rate_hz,
            r.uwb_fix_rate_hz,
            r.restarts,
            r.latency_p50_us,
            r.latency_p99_us,
            r.dropped,
            r.outliers,
            r.degraded
        );
    }
    Ok(())
}

/// Writes the demo's config into `run_dir`, starts the devices if asked,
/// and runs the group.
fn demo_group(a: &DemoArgs, id: &str, run_dir: &Path) -> Result<GroupReport> {
    let mut extras = GroupExtras::default();
    let (sources, devices) = if a.via_devices {
        let epoch = choose_start_epoch(monotonic_ns() + 500_000_000);
        let (text, devices, truth) = start_demo_devices(run_dir, epoch)?;
        extras.start_epoch_ns = Some(epoch);
        extras.truth = truth;
        (text, Some(devices))
    } else {
        (
            format!(
                "[sources]\nimu = \"sim\"\nuwb = \"sim\"\nscenario = \"{DEMO_SCENARIO}\"\nseed = {DEMO_SEED}\nspeed = 1.0\n"
            ),
            None,
        )
    };
    // The optional stages asked for; `stages` is a top-level key: before
    // the first table.
    let extra = [
        (StageRole::Foxglove, a.foxglove || a.foxglove_bind.is_some()),
        (StageRole::Zenoh, a.zenoh.is_some()),
    ];
    let stages = if extra.iter().any(|(_, on)| *on) {
        format!(
            "stages = [{}]\n",
            StageRole::ALL
                .iter()
                .filter(|r| StageRole::DEFAULT.contains(r) || extra.contains(&(**r, true)))
                .map(|r| format!("\"{}\"", r.name()))
                .collect::<Vec<_>>()
                .join(", ")
        )
    } else {
        String::new()
    };
    let foxglove = a
        .foxglove_bind
        .as_ref()
        .map(|b| format!("[foxglove]\nbind = {}\n", toml::Value::String(b.clone())))
        .unwrap_or_default();
    let zenoh = a
        .zenoh
        .as_ref()
        .map(|e| {
            format!(
                "[zenoh]\nrobot = {}\nconnect = [{}]\n",
                toml::Value::String(a.robot.clone()),
                toml::Value::String(e.clone())
            )
        })
        .unwrap_or_default();
    let text = format!(
        "{stages}[group]\nname = \"demo\"\nprefix = \"insuwb_demo{id}_\"\nrun_dir = \"{}\"\n\
         {sources}[fusion]\nfilter = \"{}\"\n{foxglove}{zenoh}",
        run_dir.display(),
        a.filter
    );
    let cfg_path = run_dir.join("demo.toml");
    let result = std::fs::write(&cfg_path, &text)
        .map_err(anyhow::Error::from)
        .and_then(|()| Ok(RobotConfig::load(&cfg_path)?))
        .and_then(|cfg| {
            eprintln!(
                "insuwb demo: {} stages on the simulated scenario {DEMO_SCENARIO}{} for {} s (run directory {})",
                cfg.stages.len(),
                if a.via_devices { " through emulated devices" } else { "" },
                a.duration,
                run_dir.display()
            );
            if cfg.stages.contains(&StageRole::Foxglove) {
                eprintln!(
                    "insuwb demo: Foxglove live view on {} (Foxglove app: Open connection, Foxglove WebSocket; layout deploy/foxglove/insuwb-live.json)",
                    cfg.foxglove.url()?
                );
            }
            if cfg.stages.contains(&StageRole::Zenoh) {
                eprintln!(
                    "insuwb demo: Zenoh bridge as robot {robot}, connecting to {} (keys insuwb/{robot}/pose and insuwb/{robot}/health, docs/ZENOH.md)",
                    cfg.zenoh.connect.join(", "),
                    robot = cfg.zenoh.robot
                );
            }
            run_group_with(
                &cfg_path,
                &cfg,
                &RunOptions {
                    duration: Some(Duration::from_secs_f64(a.duration)),
                    live: true,
                    faults: Vec::new(),
                    chaos_seed: None,
                    env: Vec::new(),
                },
                extras,
            )
        });
    if let Some(d) = devices {
        d.finish();
    }
    result
}

/// Arguments of `insuwb inspect`.
#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// The robot group configuration (for its prefix and run directory).
    pub config: PathBuf,
    /// Seconds to measure topic rates over.
    #[arg(long, default_value_t = 2.0)]
    pub duration: f64,
}

/// Runs `insuwb inspect`: per-topic rate, last-sample age, publishers and subscribers.
pub fn inspect(a: &InspectArgs) -> Result<()> {
    let cfg = RobotConfig::load(&a.config)?;
    let rt = cfg.runtime("inspect");
    let nodes = cleanup::list_nodes(&rt)?;
    println!("nodes:");
    for n in &nodes {
        println!(
            "  {:<12} pid {:>7} {:?}",
            n.name,
            n.pid.map_or("-".into(), |p| p.to_string()),
            n.state
        );
    }
    let services = cleanup::list_services(&rt)?;
    let stage = Stage::new(rt)?;
    let subs: Vec<Probe> = vec![
        probe::<ImuSample>(&stage, topics::IMU)?,
        probe::<insuwb_msg::UwbTdoa>(&stage, topics::UWB_TDOA)?,
        probe::<UwbFix>(&stage, topics::UWB_FIX)?,
        probe::<insuwb_msg::NavState>(&stage, topics::NAV)?,
        probe::<FusedState>(&stage, topics::FUSED)?,
        probe::<insuwb_msg::FilterDiag>(&stage, topics::DIAG)?,
        probe::<insuwb_msg::InsCorrection>(&stage, topics::CORRECTION)?,
        probe::<Health>(&stage, topics::HEALTH)?,
        probe::<GroundTruth>(&stage, topics::TRUTH)?,
    ];
    // The first samples are the publishers' history: let it arrive, then count.
    for _ in 0..3 {
        subs.iter().for_each(|(_, f)| {
            f();
        });
        let _ = stage.sleep(Duration::from_millis(150));
    }
    let start: Vec<u64> = subs.iter().map(|(_, f)| f().0).collect();
    let _ = stage.sleep(Duration::from_secs_f64(a.duration.clamp(0.1, 60.0)));
    let now = monotonic_ns();
    println!(
        "{:<12} {:>9} {:>12} {:>5} {:>5}",
        "topic", "rate Hz", "age ms", "pubs", "subs"
    );
    for (i, (topic, f)) in subs.iter().enumerate() {
        let (n, last) = f();
        let svc = services.iter().find(|s| s.name.ends_with(topic.as_str()));
        println!(
            "{:<12} {:>9.1} {:>12} {:>5} {:>5}",
            topic,
            (n - start[i]) as f64 / a.duration,
            last.map_or("-".into(), |t| format!(
                "{:.1}",
                now.saturating_sub(t) as f64 * 1e-6
            )),
            svc.and_then(|s| s.publishers)
                .map_or("-".into(), |v| v.to_string()),
            svc.and_then(|s| s.subscribers)
                .map_or("-".into(), |v| v.to_string())
        );
    }
    Ok(())
}

type Probe = (String, Box<dyn Fn() -> (u64, Option<u64>)>);

fn probe<T>(stage: &Stage, topic: &str) -> Result<Probe>
where
    T: insuwb_msg::HasHeader + Copy + std::fmt::Debug + iceoryx2::prelude::ZeroCopySend + 'static,
{
    let sub = stage.subscriber::<T>(topic)?;
    let state = std::cell::Cell::new((0u64, None::<u64>));
    Ok((
        topic.to_owned(),
        Box::new(move || {
            let (mut n, mut last) = state.get();
            let _ = sub.drain(|s| {
                n += 1;
                last = Some(s.header().pub_time_ns);
            });
            state.set((n, last));
            (n, last)
        }),
    ))
}

/// Arguments of `insuwb chaos`.
#[derive(Debug, clap::Args)]
pub struct ChaosArgs {
    /// Seconds to run.
    #[arg(long, default_value_t = 60.0)]
    pub duration: f64,
    /// Seed of the fault schedule.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print one JSON object on standard output.
    #[arg(long)]
    pub json: bool,
    /// Keep both groups' run directories (configuration and recording) and
    /// print where they are.
    #[arg(long)]
    pub keep: bool,
}

/// What `insuwb chaos` checks.
#[derive(Debug, serde::Serialize)]
struct ChaosReport {
    faults: u32,
    restarts: u32,
    max_gap_ms: f64,
    records_lost: u64,
    leftover_files: usize,
    deadlocks: u32,
    rmse_horizontal: Option<f64>,
    /// The same scenario, seed and length without faults, run beside.
    rmse_undisturbed: Option<f64>,
    /// `rmse_horizontal / rmse_undisturbed`.
    rmse_ratio: Option<f64>,
    fused_rate_hz: f64,
}

/// Runs `insuwb chaos`: the group on simulated sensors under random SIGKILL
/// and SIGSTOP faults, then checks recovery, the recording and the cleanup.
pub fn chaos(a: &ChaosArgs) -> Result<()> {
    if !(a.duration.is_finite() && a.duration >= 5.0 && a.duration <= 3600.0) {
        bail!("--duration must be in [5, 3600] s, got {}", a.duration);
    }
    let id = format!("{}_{}", std::process::id(), monotonic_ns() % 1_000_000);
    let chaos_group = ChaosGroup::write(&format!("chaos{id}"), a.duration)?;
    let control = ChaosGroup::write(&format!("calm{id}"), a.duration)?;
    let duration = Some(Duration::from_secs_f64(a.duration));
    // The undisturbed run: the same scenario, seed and length, beside the
    // chaos group on the same machine at the same time.
    let calm = std::thread::spawn({
        let (path, cfg) = (control.cfg_path.clone(), control.cfg.clone());
        move || {
            run_group(
                &path,
                &cfg,
                &RunOptions {
                    duration,
                    live: false,
                    faults: Vec::new(),
                    chaos_seed: None,
                    env: Vec::new(),
                },
            )
        }
    });
    let result = run_group(
        &chaos_group.cfg_path,
        &chaos_group.cfg,
        &RunOptions {
            duration,
            live: !a.json,
            faults: Vec::new(),
            chaos_seed: Some(a.seed),
            env: Vec::new(),
        },
    );
    let calm = calm
        .join()
        .map_err(|_| anyhow::anyhow!("the undisturbed group's thread panicked"));
    let leftover = chaos_group.leftover_files();
    let lost = imu_records_lost(&chaos_group.run_dir.join("log"));
    if a.keep {
        eprintln!(
            "insuwb chaos: kept {} (faults) and {} (undisturbed)",
            chaos_group.run_dir.display(),
            control.run_dir.display()
        );
    } else {
        let _ = std::fs::remove_dir_all(&chaos_group.run_dir);
        let _ = std::fs::remove_dir_all(&control.run_dir);
    }
    let r = result?;
    let calm = calm?.context("the undisturbed group")?;
    let rmse_ratio = match (r.rmse_horizontal, calm.rmse_horizontal) {
        (Some(a), Some(b)) if b > 0.0 => Some(a / b),
        _ => None,
    };
    let report = ChaosReport {
        faults: r.faults,
        restarts: r.restarts,
        max_gap_ms: r.max_gap_ms,
        records_lost: lost?,
        leftover_files: leftover,
        deadlocks: r.deadlocks,
        rmse_horizontal: r.rmse_horizontal,
        rmse_undisturbed: calm.rmse_horizontal,
        rmse_ratio,
        fused_rate_hz: r.fused_rate_hz,
    };
    if a.json {
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &serde_json::to_value(&report)?)?;
        writeln!(out)?;
    } else {
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    Ok(())
}

/// One group of `insuwb chaos`: its run directory and configuration.
struct ChaosGroup {
    run_dir: PathBuf,
    prefix: String,
    cfg_path: PathBuf,
    cfg: RobotConfig,
}

impl ChaosGroup {
    /// Writes the configuration of group `name`: the long NLOS scenario,
    /// stretched to outlast the run (its loops and random NLOS continue),
    /// and a restart budget sized so the fault rate (at most one fault per
    /// second across the group) can never exhaust it.
    fn write(name: &str, duration_s: f64) -> Result<Self> {
        let run_dir = std::env::temp_dir().join(format!("insuwb-{name}"));
        std::fs::create_dir_all(&run_dir)?;
        let prefix = format!("insuwb_{name}_");
        let scenario = insuwb_config::builtin("scenario", "nlos-long")?
            .text
            .replacen(
                "duration_s = 60.0",
                &format!("duration_s = {:.1}", duration_s + 15.0),
                1,
            );
        let scenario_path = run_dir.join("chaos-scenario.toml");
        std::fs::write(&scenario_path, scenario)?;
        let text = format!(
            "[group]\nname = \"{name}\"\nprefix = \"{prefix}\"\nrun_dir = \"{}\"\n\
             [sources]\nimu = \"sim\"\nuwb = \"sim\"\nscenario = \"{}\"\nseed = 1\n\
             [fusion]\nfilter = \"iakf\"\n[logger.segments.flush]\nevery_ms = 200\n\
             [launch]\nbudget_restarts = 60\nbudget_window_s = 60.0\n",
            run_dir.display(),
            scenario_path.display()
        );
        let cfg_path = run_dir.join("chaos.toml");
        std::fs::write(&cfg_path, &text)?;
        let cfg = RobotConfig::load(&cfg_path)?;
        Ok(Self {
            run_dir,
            prefix,
            cfg_path,
            cfg,
        })
    }

    fn leftover_files(&self) -> usize {
        leftover_files(&self.prefix, &self.cfg.iox_root())
    }
}

/// Files of the group left in /dev/shm and under its iceoryx2 root.
fn leftover_files(prefix: &str, iox_root: &Path) -> usize {
    let shm = std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(std::result::Result::ok)
                .filter(|e| e.file_name().to_string_lossy().starts_with(prefix))
                .count()
        })
        .unwrap_or(0);
    fn count(p: &Path) -> usize {
        std::fs::read_dir(p).map_or(0, |d| {
            d.filter_map(std::result::Result::ok)
                .map(|e| {
                    if e.path().is_dir() {
                        count(&e.path())
                    } else {
                        1
                    }
                })
                .sum()
        })
    }
    shm + count(iox_root)
}

/// IMU samples missing from the recording while the IMU driver was up: gaps
/// in the sequence within one driver generation (a gap across a generation
/// change is the driver's own downtime, not a lost record).
fn imu_records_lost(log_dir: &Path) -> Result<u64> {
    let read = insuwb_log::read_segments(log_dir)
        .with_context(|| format!("{}: cannot read the recording", log_dir.display()))?;
    let mut imu: Vec<(u64, u32)> = read
        .records
        .iter()
        .filter_map(|r| match r {
            insuwb_log::Record::Imu(s) => Some((s.header.seq, s.header.generation)),
            _ => None,
        })
        .collect();
    imu.sort_unstable();
    imu.dedup();
    Ok(imu
        .windows(2)
        .filter(|w| w[0].1 == w[1].1)
        .map(|w| w[1].0.saturating_sub(w[0].0 + 1))
        .sum())
}
