//! The insuwb Foxglove live-view stage (`insuwb-stage-foxglove`): reads the
//! robot config, takes the `foxglove` role's lock, and runs
//! `insuwb_foxglove::live` (iceoryx2 `fused`, `uwb_fix`, `uwb_tdoa`,
//! `diag`, `truth`, `body_vel`, `height`, `health` in; the Foxglove WebSocket protocol out on
//! `[foxglove] bind`) until SIGINT/SIGTERM. Normally started by
//! `insuwb launch` when `stages` lists `foxglove`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use insuwb_foxglove::convert::Anchor;
use insuwb_foxglove::live::{LiveSetup, LiveView};
use insuwb_group::robot::RobotConfig;
use insuwb_group::sources::Source;
use insuwb_msg::StageRole;
use insuwb_stage::lock::{StageLock, STAGE_LOCK_WAIT};

/// Arguments.
#[derive(Debug, Parser)]
#[command(
    version,
    about = "The insuwb Foxglove live view: fused pose, path, UWB fixes, anchors, truth, filter diagnostics, body velocities, heights, UWB ranges and stage health over the Foxglove WebSocket protocol (normally started by `insuwb launch`)."
)]
struct Args {
    /// The robot group configuration (config/robot.toml) with its `[foxglove]` table.
    #[arg(long)]
    config: PathBuf,
}

fn main() -> ExitCode {
    let args = Args::parse();
    insuwb_runtime::stage_main(StageRole::Foxglove.name(), || run(&args))
}

/// The anchors the config knows: the simulated scenario's (other sources
/// name theirs in their TDOA samples).
fn configured_anchors(cfg: &RobotConfig) -> Result<Vec<Anchor>> {
    if cfg.sources.uwb != Source::Sim {
        return Ok(Vec::new());
    }
    let sc = insuwb_fusion::scenario::ScenarioFile::load(&cfg.sources.scenario)
        .with_context(|| format!("reading the anchors of scenario {}", cfg.sources.scenario))?;
    Ok(sc
        .sim
        .uwb
        .anchors
        .iter()
        .map(|a| Anchor {
            id: a.id,
            pos_m: a.pos_m,
        })
        .collect())
}

fn run(args: &Args) -> Result<()> {
    let cfg = RobotConfig::load(&args.config)?;
    let role = StageRole::Foxglove.name();
    // One live view per group, before anything of the group is opened.
    let _lock = StageLock::acquire(&cfg.group, role, STAGE_LOCK_WAIT)?;
    let setup = LiveSetup {
        runtime: cfg.runtime(role),
        foxglove: cfg.foxglove.clone(),
        stages: cfg.stages.iter().map(|s| s.name().to_owned()).collect(),
        server_name: format!("insuwb {}", cfg.group.name),
        anchors: configured_anchors(&cfg)?,
        // The IMU driver publishes truth for simulated and replayed sources.
        truth: cfg.sources.imu.is_recorded(),
    };
    // SIGTERM while starting ends in a clean stop (`stage_main`).
    let view = LiveView::open(setup).context("opening the Foxglove live view")?;
    let stats = view.run().context("the Foxglove live view")?;
    tracing::info!(
        "foxglove: logged {} poses, {} fixes, {} truth, {} errors, {} diagnostics, {} body velocities, {} heights, {} UWB ranges, {} health; {} invalid samples, {} too old",
        stats.poses,
        stats.fixes,
        stats.truth,
        stats.errors,
        stats.diags,
        stats.velocities,
        stats.heights,
        stats.ranges,
        stats.health,
        stats.invalid,
        stats.old
    );
    Ok(())
}
