//! `insuwb chaos`: the group under random SIGKILL and SIGSTOP faults,
//! beside an undisturbed twin; checks recovery, the recording and the
//! cleanup of shared memory.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use insuwb_group::robot::RobotConfig;
use insuwb_runtime::monotonic_ns;

use crate::group_run::{run_group, RunOptions};

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
pub struct ChaosReport {
    pub faults: u32,
    pub restarts: u32,
    pub max_gap_ms: f64,
    /// When the largest gap started, s after the start.
    pub max_gap_at_s: f64,
    /// The last fault before it (`STAGE SIGNAL at T s`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_gap_after: Option<String>,
    /// The undisturbed run's: the scenario's own gaps (its scripted UWB
    /// dropouts, where INS-only coasting is the answer).
    pub max_gap_undisturbed_ms: f64,
    pub records_lost: u64,
    pub leftover_files: usize,
    pub deadlocks: u32,
    pub rmse_horizontal: Option<f64>,
    /// The same scenario, seed and length without faults, run beside.
    pub rmse_undisturbed: Option<f64>,
    /// `rmse_horizontal / rmse_undisturbed`.
    pub rmse_ratio: Option<f64>,
    pub fused_rate_hz: f64,
    /// The periodic looks at the faulted group (`sample_every`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub samples: Vec<crate::group_run::ResourceSample>,
    /// The undisturbed twin's horizontal RMS over each of the same periods
    /// (`sample_every`), beside `samples`' `rmse_horizontal`, m.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub undisturbed_rmse_per_look: Vec<Option<f64>>,
}

/// Runs `insuwb chaos`: the group on simulated sensors under random SIGKILL
/// and SIGSTOP faults, then checks recovery, the recording and the cleanup.
pub fn chaos(a: &ChaosArgs) -> Result<()> {
    if !(a.duration.is_finite() && a.duration >= 5.0 && a.duration <= 3600.0) {
        bail!("--duration must be in [5, 3600] s, got {}", a.duration);
    }
    let report = run_chaos(&ChaosRun {
        duration_s: a.duration,
        seed: a.seed,
        live: !a.json,
        keep: a.keep,
        bridges: false,
        sample_every: None,
    })?;
    print_report(&report, a.json)
}

/// Prints `report` as one JSON line (`json`) or pretty.
pub fn print_report<T: serde::Serialize>(report: &T, json: bool) -> Result<()> {
    if json {
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &serde_json::to_value(report)?)?;
        writeln!(out)?;
    } else {
        println!("{}", serde_json::to_string_pretty(report)?);
    }
    Ok(())
}

/// What a chaos run does.
#[derive(Debug, Clone, Copy)]
pub struct ChaosRun {
    /// Seconds to run.
    pub duration_s: f64,
    /// Seed of the fault schedule.
    pub seed: u64,
    /// The live line on standard error.
    pub live: bool,
    /// Keep the run directories.
    pub keep: bool,
    /// The faulted group runs the Foxglove live view and the Zenoh bridge
    /// too, each on a free loopback port.
    pub bridges: bool,
    /// Periodic looks at the faulted group's processes.
    pub sample_every: Option<Duration>,
}

/// Runs the faulted group and its undisturbed twin side by side.
pub fn run_chaos(a: &ChaosRun) -> Result<ChaosReport> {
    let id = format!("{}_{}", std::process::id(), monotonic_ns() % 1_000_000);
    let chaos_group = ChaosGroup::write(&format!("chaos{id}"), a.duration_s, a.bridges)?;
    let control = ChaosGroup::write(&format!("calm{id}"), a.duration_s, false)?;
    let duration = Some(Duration::from_secs_f64(a.duration_s));
    // The undisturbed run: the same scenario, seed and length, beside the
    // chaos group on the same machine at the same time.
    let calm = std::thread::spawn({
        let (path, cfg) = (control.cfg_path.clone(), control.cfg.clone());
        let sample_every = a.sample_every;
        move || {
            run_group(
                &path,
                &cfg,
                &RunOptions {
                    duration,
                    live: false,
                    faults: Vec::new(),
                    chaos_seed: None,
                    sample_every,
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
            live: a.live,
            faults: Vec::new(),
            chaos_seed: Some(a.seed),
            sample_every: a.sample_every,
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
    Ok(ChaosReport {
        faults: r.faults,
        restarts: r.restarts,
        max_gap_ms: r.max_gap_ms,
        max_gap_at_s: r.max_gap_at_s,
        max_gap_after: r.max_gap_after.clone(),
        max_gap_undisturbed_ms: calm.max_gap_ms,
        records_lost: lost?,
        leftover_files: leftover,
        deadlocks: r.deadlocks,
        rmse_horizontal: r.rmse_horizontal,
        rmse_undisturbed: calm.rmse_horizontal,
        rmse_ratio,
        fused_rate_hz: r.fused_rate_hz,
        samples: r.samples,
        undisturbed_rmse_per_look: calm.samples.iter().map(|s| s.rmse_horizontal).collect(),
    })
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
    fn write(name: &str, duration_s: f64, bridges: bool) -> Result<Self> {
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
        // The bridges: every stage, the live view and the Zenoh bridge
        // (a peer with nobody else) each on a free loopback port.
        let bridges = if bridges {
            format!(
                "stages = [\"imu\", \"uwb\", \"ins\", \"fusion\", \"foxglove\", \"zenoh\", \"logger\"]\n\
                 [foxglove]\nbind = \"127.0.0.1:{}\"\n\
                 [zenoh]\nrobot = \"soak\"\nlisten = [\"tcp/127.0.0.1:{}\"]\n",
                free_port()?,
                free_port()?
            )
        } else {
            String::new()
        };
        let text = format!(
            "{bridges}[group]\nname = \"{name}\"\nprefix = \"{prefix}\"\nrun_dir = \"{}\"\n\
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
        crate::resources::group_files(&self.prefix, &self.cfg.iox_root())
    }
}

/// A loopback TCP port free now.
fn free_port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
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
