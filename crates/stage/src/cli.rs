//! The command line shared by the stage binaries.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;

use crate::group::{start_epoch_ns, RobotConfig};
use crate::lock::STAGE_LOCK_WAIT;
use crate::source::Want;

/// Which stage a binary runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageKind {
    /// IMU driver.
    Imu,
    /// UWB driver.
    Uwb,
    /// INS mechanisation.
    Ins,
    /// Fusion.
    Fusion,
    /// Logger.
    Logger,
}

impl StageKind {
    /// The stage's name: its role in the group (`imu`, `uwb`, `ins`, `fusion`, `logger`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Imu => "imu",
            Self::Uwb => "uwb",
            Self::Ins => "ins",
            Self::Fusion => "fusion",
            Self::Logger => "logger",
        }
    }
}

/// Arguments of every stage binary.
#[derive(Debug, Parser)]
#[command(
    version,
    about = "An insuwb stage process (normally started by `insuwb launch`)."
)]
pub struct StageArgs {
    /// The robot group configuration (config/robot.toml).
    #[arg(long)]
    pub config: PathBuf,
    /// Driver source, overriding the config: `sim` or `replay:FILE`.
    #[arg(long)]
    pub source: Option<String>,
    /// Replay speed, overriding the config: a factor (10 = ten times real
    /// time) or `max` (lockstep with the consumers, never dropping a sample).
    #[arg(long, value_parser = parse_speed)]
    pub speed: Option<f64>,
    /// Start epoch (CLOCK_MONOTONIC ns) shared by the drivers and fusion;
    /// default: the launcher's (INSUWB_START_EPOCH_NS) or the next whole
    /// second plus 2.5 ms (off the kernel's tick).
    #[arg(long)]
    pub start_epoch_ns: Option<u64>,
}

fn parse_speed(s: &str) -> Result<f64, String> {
    if s == "max" {
        return Ok(f64::INFINITY);
    }
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("expected a positive factor or `max`, got '{s}'")),
    }
}

/// Parses the arguments, sets up tracing and runs the stage; exit code 0 on a clean stop.
#[must_use]
pub fn main(kind: StageKind) -> ExitCode {
    let args = StageArgs::parse();
    let _ = insuwb_runtime::init_tracing(kind.name());
    match run(kind, &args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(kind: StageKind, args: &StageArgs) -> anyhow::Result<()> {
    let cfg = RobotConfig::load(&args.config)?;
    // One process per role and group, before anything of the group is
    // opened: a stage started by hand beside its running group refuses.
    let _role = crate::lock::StageLock::acquire(&cfg.group, kind.name(), STAGE_LOCK_WAIT)?;
    let epoch = args.start_epoch_ns.unwrap_or_else(start_epoch_ns);
    let speed = args.speed.unwrap_or(cfg.sources.speed);
    if speed.is_nan() || speed <= 0.0 {
        anyhow::bail!("--speed must be > 0, got {speed}");
    }
    let result = match kind {
        StageKind::Imu => {
            let src = args
                .source
                .clone()
                .unwrap_or_else(|| cfg.sources.imu.clone());
            crate::driver::run(Want::Imu, &cfg, &src, speed, epoch)
        }
        StageKind::Uwb => {
            let src = args
                .source
                .clone()
                .unwrap_or_else(|| cfg.sources.uwb.clone());
            crate::driver::run(Want::Uwb, &cfg, &src, speed, epoch)
        }
        StageKind::Ins => crate::ins::run(&cfg),
        StageKind::Fusion => crate::fusion::run(&cfg, epoch),
        StageKind::Logger => crate::logger::run(&cfg),
    };
    match result {
        Err(e)
            if e.downcast_ref::<insuwb_runtime::StageError>()
                .is_some_and(|s| matches!(s, insuwb_runtime::StageError::ShutdownRequested(_))) =>
        {
            Ok(())
        }
        r => r,
    }
}
