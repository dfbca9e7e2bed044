//! `insuwb bench latency`: the latency of the 10 Hz loop against bare iceoryx2.
//!
//! In one run: the floor (`insuwb-bench-floor`, the same process graph with bare
//! forwarding processes: same payloads, rates, wake-ups and waiting rule at
//! the fusion node, no maths, no logging) and the real group on simulated
//! sensors (scenario nlos-long, real time), alternating in `--rounds`
//! rounds (by default ten of 3 s for `--duration 30`), the floor first in
//! every other round, so that both meet the same spells of machine noise;
//! then the per-hop analysis of every recording
//! (`insuwb_bench::analysis`), pooled per graph over the rounds, the CPU
//! time of every process over the steady windows, and the ratios of the
//! group's end-to-end percentiles over the floor's. With `--json` standard
//! output holds only the report object; the per-hop tables of both graphs
//! go to standard error.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use insuwb_bench::analysis::{
    samples, AnalysisConfig, Cycle, Hops, LatencySamples, Percentiles, RunLatency,
};
use insuwb_bench::graph::{cpu_percent, cpu_snapshot, run_floor_graph, FloorGraphOptions};
use insuwb_group::robot::RobotConfig;
use insuwb_msg::StageRole;
use insuwb_runtime::monotonic_ns;

use crate::group_run::{run_group, RunOptions};

/// `insuwb bench` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum BenchCmd {
    /// Latency of the 10 Hz loop: the floor (bare iceoryx2 graph), then the
    /// group on simulated sensors; per-hop percentiles, period jitter,
    /// missed cycles, CPU per stage, ratios to the floor.
    Latency(LatencyArgs),
    /// The fleet's station under N simulated robots at 10 Hz over loopback
    /// (10, 100, 500 by default): its CPU share, the delay of the poses
    /// from publish to the station, what was dropped. Runs
    /// `insuwb-station bench` (`insuwb bench fleet --help` for its options).
    #[command(disable_help_flag = true)]
    Fleet {
        /// The load generator's arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
}

/// Arguments of `insuwb bench latency`.
#[derive(Debug, clap::Args)]
pub struct LatencyArgs {
    /// Seconds of steady state measured per graph, over all rounds; each
    /// round of a graph runs `duration / rounds` seconds plus a start-up
    /// allowance of 3 s (process start, first fused state, 1 s warm-up).
    #[arg(long, default_value_t = 30.0)]
    pub duration: f64,
    /// Rounds: both graphs run this many times, in turn (the floor first in
    /// odd rounds, the group first in even ones), and their samples are
    /// pooled (1: the floor once, then the group once). `duration / rounds`
    /// must be in [3, 50] s (the simulated scenario lasts 60 s). Default: as
    /// many 3 s rounds as `duration` holds, at most 10 (a round's median
    /// depends on how the stages happen to share the CPUs from the start:
    /// many short rounds average that out in both graphs).
    #[arg(long)]
    pub rounds: Option<u32>,
    /// Print the report as one JSON object on standard output.
    #[arg(long)]
    pub json: bool,
    /// Also write every steady-state cycle of every round (the stamps along
    /// the path of each fix) as `floor<round>.csv` and `group<round>.csv`
    /// in this folder, for looking at single cycles.
    #[arg(long, value_name = "DIR")]
    pub samples: Option<PathBuf>,
    /// Run the stages of both graphs in the SCHED_FIFO class (the stages'
    /// `[realtime.*] fifo_priority`, needs CAP_SYS_NICE): fusion at this
    /// priority, the INS one below, the drivers two below, the logger in the
    /// normal scheduler. Default: the normal scheduler for every stage, as
    /// a robot's default configuration.
    #[arg(long, value_name = "PRIORITY", value_parser = clap::value_parser!(i32).range(1..=99))]
    pub fifo_priority: Option<i32>,
    /// Also run this optional stage in the group's rounds (repeatable; e.g.
    /// `ros2`, with its `[ros2]` defaults): a bridge subscribes beside the
    /// logger, so the ratio shows what it costs the fix path, and the CPU
    /// table its own share. The ROS 2 bridge discovers peers by multicast:
    /// run it inside a private network namespace (BENCHMARKS.md). The
    /// Zenoh bridge (`zenoh`) connects to a subscriber in this process
    /// listening on a free loopback port, as robot `bench`.
    #[arg(long = "with", value_name = "STAGE")]
    pub with: Vec<insuwb_msg::StageRole>,
}

/// CPU time of each stage over the steady window, percent of one core.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct CpuPercent {
    /// IMU driver.
    pub imu: f64,
    /// UWB driver.
    pub uwb: f64,
    /// INS.
    pub ins: f64,
    /// Fusion.
    pub fusion: f64,
    /// Logger.
    pub logger: f64,
    /// The ROS 2 bridge, when the group ran it (`--with ros2`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ros2: Option<f64>,
    /// The Foxglove live view, when the group ran it (`--with foxglove`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub foxglove: Option<f64>,
    /// The Zenoh bridge, when the group ran it (`--with zenoh`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zenoh: Option<f64>,
}

impl CpuPercent {
    fn from_named(v: &[(String, f64)]) -> Self {
        let find = |r: StageRole| v.iter().find(|(m, _)| m == r.name()).map(|(_, p)| *p);
        let get = |r: StageRole| find(r).unwrap_or(0.0);
        Self {
            imu: get(StageRole::Imu),
            uwb: get(StageRole::Uwb),
            ins: get(StageRole::Ins),
            fusion: get(StageRole::Fusion),
            logger: get(StageRole::Logger),
            ros2: find(StageRole::Ros2),
            foxglove: find(StageRole::Foxglove),
            zenoh: find(StageRole::Zenoh),
        }
    }
}

/// The report of `insuwb bench latency` (the keys, in its order).
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct LatencyReport {
    /// Floor: UWB fix publish -> the floor fusion node's output, p50, us.
    pub floor_p50_us: f64,
    /// Floor: same, p99, us.
    pub floor_p99_us: f64,
    /// Group: UWB fix publish -> fused publish, p50, us.
    pub e2e_uwb_fused_p50_us: f64,
    /// Group: same, p99, us.
    pub e2e_uwb_fused_p99_us: f64,
    /// Group: same, p99.9, us.
    pub e2e_uwb_fused_p999_us: f64,
    /// Group: p99 of the deviation of the fused output period from 100 ms, us.
    pub loop_jitter_p99_us: f64,
    /// Floor: same, us.
    pub floor_jitter_p99_us: f64,
    /// Group: steady-state UWB fixes with no fused state.
    pub missed_cycles: u64,
    /// Group: per hop.
    pub hops: Hops,
    /// Group: CPU time per stage, percent of one core.
    pub cpu_percent: CpuPercent,
    /// `e2e_uwb_fused_p50_us / floor_p50_us`.
    pub ratio_p50: f64,
    /// `e2e_uwb_fused_p99_us / floor_p99_us`.
    pub ratio_p99: f64,
    /// Rounds the figures pool (each graph ran this many times, in turn).
    pub rounds: u32,
    /// With `--with ros2`: UWB fix publish -> the bridge's odometry received
    /// by a DDS reader in this process, p50 / p99, us (the same fixes'
    /// fix-to-fused beside it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dds: Option<DdsLatency>,
    /// With `--with zenoh`: UWB fix publish -> the bridge's pose received
    /// by a Zenoh subscriber in this process (a station's), p50 / p99, us.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zenoh: Option<ZenohLatency>,
}

/// Fix-to-Zenoh-subscriber delivery against fix-to-fused, over the same fixes.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct ZenohLatency {
    /// Fixes whose pose the subscriber received.
    pub count: usize,
    /// UWB fix publish -> pose received, p50, us.
    pub fix_to_zenoh_p50_us: f64,
    /// Same, p99, us.
    pub fix_to_zenoh_p99_us: f64,
    /// UWB fix publish -> fused publish for those fixes, p50, us.
    pub fix_to_fused_p50_us: f64,
    /// Same, p99, us.
    pub fix_to_fused_p99_us: f64,
}

/// Fix-to-DDS delivery against fix-to-fused, over the same fixes.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct DdsLatency {
    /// Fixes whose odometry the reader received.
    pub count: usize,
    /// UWB fix publish -> odometry received, p50, us.
    pub fix_to_dds_p50_us: f64,
    /// Same, p99, us.
    pub fix_to_dds_p99_us: f64,
    /// UWB fix publish -> fused publish for those fixes, p50, us.
    pub fix_to_fused_p50_us: f64,
    /// Same, p99, us.
    pub fix_to_fused_p99_us: f64,
}

/// Start of the CPU window after a graph starts (past process start-up and
/// the INS alignment at rest).
const CPU_FROM: Duration = Duration::from_secs(3);

/// What a round of a graph runs beyond its share of `--duration`: the start
/// epoch (up to 2 s ahead), the first fused state and the analysis warm-up.
const START_ALLOWANCE: Duration = Duration::from_secs(3);

/// Runs an `insuwb bench` subcommand.
pub fn run(cmd: &BenchCmd) -> Result<()> {
    match cmd {
        BenchCmd::Latency(a) => latency(a),
        BenchCmd::Fleet { args } => {
            let mut all = vec![std::ffi::OsString::from("bench")];
            all.extend(args.iter().cloned());
            crate::beside::exec("insuwb-station", &all)
        }
    }
}

/// Shortest and longest share of `--duration` one round of a graph runs, s.
const ROUND_S: (f64, f64) = (3.0, 50.0);
/// Most rounds.
const MAX_ROUNDS: u32 = 10;

/// The rounds of a run: `--rounds`, else as many rounds of the shortest
/// length as `duration_s` holds, between 1 and [`MAX_ROUNDS`].
fn rounds_for(rounds: Option<u32>, duration_s: f64) -> u32 {
    rounds.unwrap_or_else(|| {
        let fit = (duration_s / ROUND_S.0).floor();
        if fit.is_finite() && fit >= 1.0 {
            (fit as u32).min(MAX_ROUNDS)
        } else {
            1
        }
    })
}

fn latency(a: &LatencyArgs) -> Result<()> {
    let rounds = rounds_for(a.rounds, a.duration);
    if !(1..=MAX_ROUNDS).contains(&rounds) {
        bail!("--rounds must be in [1, {MAX_ROUNDS}], got {rounds}");
    }
    let per_round = a.duration / f64::from(rounds);
    if !(a.duration.is_finite() && (ROUND_S.0..=ROUND_S.1).contains(&per_round)) {
        bail!(
            "--duration / --rounds must be in [{}, {}] s, got {} / {rounds} = {per_round} s",
            ROUND_S.0,
            ROUND_S.1,
            a.duration,
        );
    }
    let duration = Duration::from_secs_f64(per_round) + START_ALLOWANCE;
    let id = format!("{}_{}", std::process::id(), monotonic_ns() % 1_000_000);
    let base = std::env::temp_dir().join(format!("insuwb-bench-{id}"));
    private_dir(&base)?;
    let result = measure(a, rounds, duration, &id, &base);
    let _ = std::fs::remove_dir_all(&base);
    let report = result?;
    if a.json {
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &serde_json::to_value(report)?)?;
        writeln!(out)?;
    } else {
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    Ok(())
}

fn measure(
    a: &LatencyArgs,
    rounds: u32,
    duration: Duration,
    id: &str,
    base: &Path,
) -> Result<LatencyReport> {
    let acfg = AnalysisConfig::default();
    eprintln!(
        "insuwb bench latency: {rounds} round(s) of the floor graph and the group in turn, {:.1} s each",
        duration.as_secs_f64()
    );
    let (mut fl, mut gr) = (LatencySamples::default(), LatencySamples::default());
    let (mut fl_cpu, mut gr_cpu) = (Vec::new(), Vec::new());
    let (mut to_dds, mut to_fused) = (Vec::new(), Vec::new());
    let (mut to_zenoh, mut to_fused_z) = (Vec::new(), Vec::new());
    if let Some(dir) = &a.samples {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create the samples folder", dir.display()))?;
    }
    for round in 0..rounds {
        // The floor first in rounds 1, 3, ..., the group first in 2, 4, ...:
        // a drift of the machine over the run then meets both graphs alike.
        let floor_first = round % 2 == 0;
        for floor_turn in [floor_first, !floor_first] {
            if floor_turn {
                // The floor: bare forwarding processes.
                let floor = run_floor_graph(&FloorGraphOptions {
                    program: crate::beside::program("insuwb-bench-floor")?,
                    run_dir: base.join(format!("floor{round}")),
                    prefix: format!("insuwb_bfl{id}r{round}_"),
                    duration,
                    cpu_from: CPU_FROM,
                    fifo_priority: a.fifo_priority,
                })?;
                let s = samples(&floor.records, &floor.recv, &acfg)
                    .with_context(|| format!("the floor run of round {}", round + 1))?;
                write_cycles(a.samples.as_deref(), &format!("floor{round}.csv"), &s)?;
                fl.extend(&s);
                fl_cpu.push(floor.cpu_percent);
            } else {
                // The group on simulated sensors, its logger noting fused receive times.
                let (s, cpu, dds, zenoh) = group_round(round, duration, id, base, &acfg, a)?;
                to_dds.extend(dds.iter().map(|d| d.0));
                to_fused.extend(dds.iter().map(|d| d.1));
                to_zenoh.extend(zenoh.iter().map(|d| d.0));
                to_fused_z.extend(zenoh.iter().map(|d| d.1));
                write_cycles(a.samples.as_deref(), &format!("group{round}.csv"), &s)?;
                gr.extend(&s);
                gr_cpu.push(cpu);
            }
        }
    }
    let (fl_cpu, gr_cpu) = (mean_cpu(&fl_cpu), mean_cpu(&gr_cpu));
    let (fl, gr) = (fl.summary(), gr.summary());
    print_table("floor", &fl, &fl_cpu);
    print_table("group", &gr, &gr_cpu);

    let ratio = |g: f64, f: f64| if f > 0.0 { g / f } else { f64::INFINITY };
    let dds = (!to_dds.is_empty()).then(|| {
        let (d, f) = (Percentiles::of(to_dds.iter().copied()), Percentiles::of(to_fused.iter().copied()));
        eprintln!(
            "  fix -> DDS reader       p50 {:>8.1}  p99 {:>8.1} us  (fix -> fused p50 {:.1}, p99 {:.1} us; n = {})",
            d.p50_us, d.p99_us, f.p50_us, f.p99_us, to_dds.len()
        );
        DdsLatency {
            count: to_dds.len(),
            fix_to_dds_p50_us: d.p50_us,
            fix_to_dds_p99_us: d.p99_us,
            fix_to_fused_p50_us: f.p50_us,
            fix_to_fused_p99_us: f.p99_us,
        }
    });
    let zenoh = (!to_zenoh.is_empty()).then(|| {
        let (z, f) = (
            Percentiles::of(to_zenoh.iter().copied()),
            Percentiles::of(to_fused_z.iter().copied()),
        );
        eprintln!(
            "  fix -> Zenoh subscriber p50 {:>8.1}  p99 {:>8.1} us  (fix -> fused p50 {:.1}, p99 {:.1} us; n = {})",
            z.p50_us, z.p99_us, f.p50_us, f.p99_us, to_zenoh.len()
        );
        ZenohLatency {
            count: to_zenoh.len(),
            fix_to_zenoh_p50_us: z.p50_us,
            fix_to_zenoh_p99_us: z.p99_us,
            fix_to_fused_p50_us: f.p50_us,
            fix_to_fused_p99_us: f.p99_us,
        }
    });
    Ok(LatencyReport {
        floor_p50_us: fl.e2e_uwb_fused.p50_us,
        floor_p99_us: fl.e2e_uwb_fused.p99_us,
        e2e_uwb_fused_p50_us: gr.e2e_uwb_fused.p50_us,
        e2e_uwb_fused_p99_us: gr.e2e_uwb_fused.p99_us,
        e2e_uwb_fused_p999_us: gr.e2e_uwb_fused.p999_us,
        loop_jitter_p99_us: gr.jitter.p99_us,
        floor_jitter_p99_us: fl.jitter.p99_us,
        missed_cycles: gr.missed_cycles,
        hops: gr.hops,
        cpu_percent: CpuPercent::from_named(&gr_cpu),
        ratio_p50: ratio(gr.e2e_uwb_fused.p50_us, fl.e2e_uwb_fused.p50_us),
        ratio_p99: ratio(gr.e2e_uwb_fused.p99_us, fl.e2e_uwb_fused.p99_us),
        rounds,
        dds,
        zenoh,
    })
}

/// A group round's samples, each stage's CPU share, with `--with ros2`
/// each odometry's `(fix -> DDS, fix -> fused)` and with `--with zenoh`
/// each pose's `(fix -> Zenoh subscriber, fix -> fused)`, ns.
type GroupRound = (
    LatencySamples,
    Vec<(String, f64)>,
    Vec<(u64, u64)>,
    Vec<(u64, u64)>,
);

/// One run of the group (round `round`): its samples and the CPU time of
/// each stage over the steady window.
fn group_round(
    round: u32,
    duration: Duration,
    id: &str,
    base: &Path,
    acfg: &AnalysisConfig,
    a: &LatencyArgs,
) -> Result<GroupRound> {
    let run_dir = base.join(format!("group{round}"));
    private_dir(&run_dir)?;
    let stages: Vec<String> = StageRole::ALL
        .into_iter()
        .filter(|r| StageRole::DEFAULT.contains(r) || a.with.contains(r))
        .map(|r| format!("\"{r}\""))
        .collect();
    let mut text = format!(
        "stages = [{}]\n[group]\nname = \"bench\"\nprefix = \"insuwb_bgr{id}r{round}_\"\nrun_dir = \"{}\"\n\
         [sources]\nimu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 1\nspeed = 1.0\n\
         [fusion]\nfilter = \"iakf\"\n",
        stages.join(", "),
        run_dir.display()
    );
    let with_ros2 = a.with.contains(&StageRole::Ros2);
    if with_ros2 {
        // Stamps in CLOCK_MONOTONIC: the odometry's stamp is then the fused
        // state's measurement time, which finds its fix in the recording.
        text.push_str("[ros2]\nstamp_clock = \"monotonic\"\n");
    }
    let zenoh_endpoint = if a.with.contains(&StageRole::Zenoh) {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .context("finding a free port for the Zenoh subscriber")?
            .port();
        let e = format!("tcp/127.0.0.1:{port}");
        // Monotonic stamps, as for ROS 2 above.
        text.push_str(&format!(
            "[zenoh]\nrobot = \"{ZENOH_ROBOT}\"\nconnect = [\"{e}\"]\nstamp_clock = \"monotonic\"\n"
        ));
        Some(e)
    } else {
        None
    };
    if let Some(p) = a.fifo_priority {
        // The floor's roles are the stages, by the same names.
        for stage in insuwb_bench::floor::Role::ALL.map(|r| r.name()) {
            if let Some(q) = insuwb_bench::graph::fifo_ladder(stage, p) {
                text.push_str(&format!("[realtime.{stage}]\nfifo_priority = {q}\n"));
            }
        }
    }
    let cfg_path = run_dir.join("bench.toml");
    std::fs::write(&cfg_path, &text)?;
    let cfg = RobotConfig::load(&cfg_path)?;
    let trace_path = run_dir.join("fused_recv.txt");
    let probe = with_ros2
        .then(|| PoseProbe::dds(&cfg_path, duration + Duration::from_secs(10)))
        .transpose()?;
    let zprobe = zenoh_endpoint
        .map(|e| PoseProbe::zenoh(e, duration + Duration::from_secs(10)))
        .transpose()?;
    let sampler = spawn_cpu_sampler(
        CPU_FROM,
        duration.saturating_sub(Duration::from_millis(200)),
    );
    let group = run_group(
        &cfg_path,
        &cfg,
        &RunOptions {
            duration: Some(duration),
            live: false,
            faults: Vec::new(),
            chaos_seed: None,
            sample_every: None,
            env: vec![(
                insuwb_stage::logger::FUSED_TRACE_ENV.to_owned(),
                trace_path.display().to_string(),
            )],
        },
    )?;
    let cpu = sampler.join().unwrap_or_default();
    let odom = match probe {
        Some(p) => p.finish()?,
        None => Vec::new(),
    };
    let poses = match zprobe {
        Some(p) => p.finish()?,
        None => Vec::new(),
    };
    if group.restarts > 0 {
        eprintln!(
            "warning: {} stage restart(s) during the group run of round {}",
            group.restarts,
            round + 1
        );
    }
    let records = insuwb_log::read_segments(run_dir.join("log"))
        .context("reading the group's recording")?
        .records;
    let recv = insuwb_bench::trace::read(&trace_path)?;
    let s = samples(&records, &recv, acfg)
        .with_context(|| format!("the group run of round {}", round + 1))?;
    Ok((
        s,
        cpu,
        fix_to_dds(&records, &odom, acfg.warmup_s),
        fix_to_dds(&records, &poses, acfg.warmup_s),
    ))
}

/// Writes the cycles of one run as CSV to `dir/name` (nothing without `dir`).
fn write_cycles(dir: Option<&Path>, name: &str, s: &LatencySamples) -> Result<()> {
    let Some(dir) = dir else {
        return Ok(());
    };
    let path = dir.join(name);
    let mut text = String::with_capacity(64 * (s.cycles.len() + 1));
    text.push_str(Cycle::CSV_HEADER);
    text.push('\n');
    for c in &s.cycles {
        text.push_str(&c.csv_row());
        text.push('\n');
    }
    std::fs::write(&path, text).with_context(|| format!("{}: cannot write", path.display()))
}

/// Creates `dir` (and its parents) readable by the owner only, as the
/// launcher wants a run directory.
fn private_dir(dir: &Path) -> Result<()> {
    insuwb_runtime::perm::create_private_dir(dir)
        .with_context(|| format!("{}: cannot create", dir.display()))
}

/// Mean CPU percent per name over rounds (a name missing from a round counts 0 there).
fn mean_cpu(rounds: &[Vec<(String, f64)>]) -> Vec<(String, f64)> {
    let mut names: Vec<String> = Vec::new();
    for r in rounds {
        for (n, _) in r {
            if !names.contains(n) {
                names.push(n.clone());
            }
        }
    }
    let k = rounds.len().max(1) as f64;
    names
        .into_iter()
        .map(|n| {
            let sum: f64 = rounds
                .iter()
                .filter_map(|r| r.iter().find(|(m, _)| *m == n).map(|(_, p)| *p))
                .sum();
            (n, sum / k)
        })
        .collect()
}

/// Samples the CPU time of this process's stage children (by their process
/// names, [`insuwb_msg::StageRole::process_name`]) at
/// `from` and `to` after now; returns percent of one core per stage name.
fn spawn_cpu_sampler(from: Duration, to: Duration) -> std::thread::JoinHandle<Vec<(String, f64)>> {
    std::thread::spawn(move || {
        let t0 = std::time::Instant::now();
        let stages = || -> Vec<(String, u32)> {
            insuwb_bench::cpu::children(std::process::id())
                .into_iter()
                .filter_map(|(pid, comm)| {
                    let role = insuwb_msg::StageRole::from_process_name(&comm)?;
                    Some((role.name().to_owned(), pid))
                })
                .collect()
        };
        std::thread::sleep(from);
        let a_at = std::time::Instant::now();
        let before = cpu_snapshot(&stages());
        std::thread::sleep(to.saturating_sub(t0.elapsed()));
        let wall = u64::try_from(a_at.elapsed().as_nanos()).unwrap_or(u64::MAX);
        cpu_percent(&before, &cpu_snapshot(&stages()), wall)
    })
}

fn print_table(what: &str, r: &RunLatency, cpu: &[(String, f64)]) {
    let row = |name: &str, p: &Percentiles| {
        eprintln!(
            "  {name:<22} p50 {:>8.1}  p99 {:>8.1}  p99.9 {:>8.1}  max {:>8.1} us  (n = {})",
            p.p50_us, p.p99_us, p.p999_us, p.max_us, p.count
        );
    };
    eprintln!(
        "{what}: {} fixes in the steady state, {} missed cycles, {} fused states",
        r.fixes, r.missed_cycles, r.fused
    );
    row("uwb publish -> fused", &r.e2e_uwb_fused);
    row("imu publish -> ins", &r.hops.imu_ins);
    row("ins publish -> fused", &r.hops.ins_fusion);
    row("fused -> logger recv", &r.hops.fusion_logger);
    row("period - 100 ms", &r.jitter);
    let cpu: Vec<String> = cpu.iter().map(|(n, p)| format!("{n} {p:.2} %")).collect();
    eprintln!("  cpu (one core): {}", cpu.join(", "));
}

/// A probe of a bridge's poses from outside the robot: `insuwb-station
/// probe` (which has the transports this command leaves out), its own
/// process, printing `(stamp, receive time)` of each pose, CLOCK_MONOTONIC
/// ns. It stops when its standard input closes or after its bound.
struct PoseProbe {
    what: &'static str,
    child: std::process::Child,
    reader: std::thread::JoinHandle<Vec<(u64, u64)>>,
}

impl PoseProbe {
    /// Starts `insuwb-station probe ARGS` and waits (at most 30 s) until its
    /// reader is open.
    fn spawn(what: &'static str, bound: Duration, args: &[String]) -> Result<Self> {
        use std::io::{BufRead, BufReader};
        use std::process::{Command, Stdio};
        let exe = crate::beside::program("insuwb-station")?;
        let mut child = Command::new(exe)
            .arg("probe")
            .args(args)
            .args(["--seconds", &format!("{:.1}", bound.as_secs_f64())])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting the {what} (insuwb-station probe)"))?;
        let out = child.stdout.take().context("the probe's standard output")?;
        let err = child.stderr.take().context("the probe's standard error")?;
        let reader = std::thread::spawn(move || {
            BufReader::new(out)
                .lines()
                .map_while(std::result::Result::ok)
                .filter_map(|l| {
                    let mut it = l.split_whitespace().map(str::parse::<u64>);
                    match (it.next(), it.next()) {
                        (Some(Ok(a)), Some(Ok(b))) => Some((a, b)),
                        _ => None,
                    }
                })
                .collect()
        });
        // Its first line on standard error is `ready`, or why it failed.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut first = true;
            for line in BufReader::new(err)
                .lines()
                .map_while(std::result::Result::ok)
            {
                if first {
                    let _ = tx.send(line.clone());
                    first = false;
                }
                if line != "ready" {
                    eprintln!("insuwb-station probe: {line}");
                }
            }
        });
        match rx.recv_timeout(Duration::from_secs(30)) {
            Ok(l) if l == "ready" => Ok(Self {
                what,
                child,
                reader,
            }),
            got => {
                let _ = child.kill();
                let _ = child.wait();
                bail!("the {what} did not start: {got:?}")
            }
        }
    }

    /// A DDS reader of the ROS 2 bridge's odometry, with the `[ros2]` of
    /// the group's config file.
    fn dds(config: &Path, bound: Duration) -> Result<Self> {
        Self::spawn(
            "DDS reader",
            bound,
            &["ros2".to_owned(), config.display().to_string()],
        )
    }

    /// A Zenoh subscriber of the Zenoh bridge's poses, listening on
    /// `endpoint` (the bridge connects to it).
    fn zenoh(endpoint: String, bound: Duration) -> Result<Self> {
        Self::spawn(
            "Zenoh subscriber",
            bound,
            &["zenoh".to_owned(), endpoint, ZENOH_ROBOT.to_owned()],
        )
    }

    /// Stops the probe and returns what it received.
    fn finish(mut self) -> Result<Vec<(u64, u64)>> {
        drop(self.child.stdin.take());
        let status = self.child.wait()?;
        let got = self
            .reader
            .join()
            .map_err(|_| anyhow::anyhow!("the {} reader thread panicked", self.what))?;
        if !status.success() {
            bail!("the {} failed ({status})", self.what);
        }
        Ok(got)
    }
}

/// The robot id of the group's Zenoh bridge (`--with zenoh`).
const ZENOH_ROBOT: &str = "bench";

/// `(fix -> odometry received, fix -> fused published)`, ns, for every
/// odometry message whose stamp is the measurement time of a fused update
/// more than `warmup_s` after the first one.
fn fix_to_dds(
    records: &[insuwb_log::Record],
    odom: &[(u64, u64)],
    warmup_s: f64,
) -> Vec<(u64, u64)> {
    use insuwb_log::Record;
    use std::collections::HashMap;
    let fix_pub: HashMap<u64, u64> = records
        .iter()
        .filter_map(|r| match r {
            Record::Fix(f) => Some((f.header.seq, f.header.pub_time_ns)),
            _ => None,
        })
        .collect();
    // Fused updates by measurement time: (fix pub, fused pub).
    let mut fused: HashMap<u64, (u64, u64)> = HashMap::new();
    for r in records {
        if let Record::Fused(f) = r {
            if f.header.flags & insuwb_msg::FusedState::FLAG_DEGRADED != 0 {
                continue;
            }
            if let Some(&fp) = fix_pub.get(&f.uwb_seq) {
                fused
                    .entry(f.header.meas_time_ns)
                    .or_insert((fp, f.header.pub_time_ns));
            }
        }
    }
    let Some(first) = fused.keys().min().copied() else {
        return Vec::new();
    };
    let from = first.saturating_add((warmup_s * 1e9) as u64);
    odom.iter()
        .filter(|(stamp, _)| *stamp >= from)
        .filter_map(|(stamp, rx)| {
            let (fix, fused_pub) = fused.get(stamp)?;
            Some((rx.checked_sub(*fix)?, fused_pub.checked_sub(*fix)?))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_rounds_are_the_3_s_rounds_the_duration_holds() {
        assert_eq!(rounds_for(None, 30.0), 10);
        assert_eq!(rounds_for(None, 20.0), 6);
        assert_eq!(rounds_for(None, 300.0), MAX_ROUNDS);
        // Too short for one round: one round, which `latency` then refuses.
        assert_eq!(rounds_for(None, 2.0), 1);
        assert_eq!(rounds_for(None, f64::NAN), 1);
        assert_eq!(rounds_for(Some(3), 30.0), 3, "--rounds wins");
    }
}
