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
struct ChaosReport {
    faults: u32,
    restarts: u32,
    max_gap_ms: f64,
    /// The undisturbed run's: the scenario's own gaps (its scripted UWB
    /// dropouts, where INS-only coasting is the answer).
    max_gap_undisturbed_ms: f64,
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
        max_gap_undisturbed_ms: calm.max_gap_ms,
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
