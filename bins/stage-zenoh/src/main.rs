//! The insuwb Zenoh bridge stage (`insuwb-stage-zenoh`): reads the robot
//! config, takes the `zenoh` role's lock, and runs `insuwb_zenoh::bridge`
//! (iceoryx2 `fused`, `health`, and `uwb_fix`, `diag` when asked, in;
//! Zenoh `insuwb/<robot>/pose`, `health`, `fix`, `diag` out to the
//! endpoints of `[zenoh]`) until SIGINT/SIGTERM. Normally started by
//! `insuwb launch` when `stages` lists `zenoh`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use insuwb_group::robot::RobotConfig;
use insuwb_msg::StageRole;
use insuwb_stage::lock::{StageLock, STAGE_LOCK_WAIT};
use insuwb_zenoh::bridge::{Bridge, BridgeSetup};

/// Arguments.
#[derive(Debug, Parser)]
#[command(
    version,
    about = "The insuwb Zenoh bridge: the fused pose, the stages' health and optionally UWB fixes and filter diagnostics to the fleet's station over Zenoh, under insuwb/<robot>/... (normally started by `insuwb launch`)."
)]
struct Args {
    /// The robot group configuration (config/robot.toml) with its `[zenoh]` table.
    #[arg(long)]
    config: PathBuf,
    /// Refuse a plain tcp/ endpoint off the loopback instead of warning
    /// about it (also `[zenoh] require_tls`).
    #[arg(long)]
    require_tls: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    insuwb_runtime::stage_main(StageRole::Zenoh.name(), || run(&args))
}

fn run(args: &Args) -> Result<()> {
    let cfg = RobotConfig::load(&args.config)?;
    let role = StageRole::Zenoh.name();
    // One bridge per group, before anything of the group is opened.
    let _lock = StageLock::acquire(&cfg.group, role, STAGE_LOCK_WAIT)?;
    let setup = BridgeSetup {
        runtime: cfg.runtime(role),
        zenoh: insuwb_zenoh::config::ZenohConfig {
            require_tls: cfg.zenoh.require_tls || args.require_tls,
            ..cfg.zenoh.clone()
        },
        stages: cfg.stages.iter().map(|s| s.name().to_owned()).collect(),
    };
    // SIGTERM while starting ends in a clean stop (`stage_main`).
    let bridge = Bridge::open(setup).context("opening the Zenoh bridge")?;
    let stats = bridge.run().context("the Zenoh bridge")?;
    tracing::info!(
        "zenoh: put {} poses, {} health, {} fixes, {} diagnostics; {} invalid samples, {} too old, {} put failures",
        stats.poses,
        stats.health,
        stats.fixes,
        stats.diags,
        stats.invalid,
        stats.old,
        stats.put_failures
    );
    Ok(())
}
