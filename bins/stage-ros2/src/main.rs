//! The insuwb ROS 2 bridge stage (`insuwb-stage-ros2`): reads the robot config,
//! takes the `ros2` role's lock, and runs `insuwb_ros2::bridge` (iceoryx2
//! `fused`, `imu`, `health` in; ROS 2 topics out over DDS; with `[ros2]
//! odometry_in`, a base's odometry in over DDS and `body_vel` out) until
//! SIGINT/SIGTERM. Normally started by `insuwb launch` when `stages` lists
//! `ros2`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use insuwb_group::robot::RobotConfig;
use insuwb_msg::StageRole;
use insuwb_ros2::bridge::{Bridge, BridgeSetup};
use insuwb_stage::lock::{StageLock, STAGE_LOCK_WAIT};

/// Arguments.
#[derive(Debug, Parser)]
#[command(
    version,
    about = "The insuwb ROS 2 bridge stage: fused pose, TF, IMU and diagnostics as ROS 2 topics, and a base's odometry from ROS as body velocities (normally started by `insuwb launch`)."
)]
struct Args {
    /// The robot group configuration (config/robot.toml) with its `[ros2]` table.
    #[arg(long)]
    config: PathBuf,
}

fn main() -> ExitCode {
    let args = Args::parse();
    insuwb_runtime::stage_main(StageRole::Ros2.name(), || run(&args))
}

fn run(args: &Args) -> Result<()> {
    let cfg = RobotConfig::load(&args.config)?;
    let role = StageRole::Ros2.name();
    // One bridge per group, before anything of the group is opened.
    let _lock = StageLock::acquire(&cfg.group, role, STAGE_LOCK_WAIT)?;
    let lever_arm = match cfg.ros2.antenna_lever_arm_m {
        Some(l) => l,
        None => {
            cfg.fusion_config()
                .context("reading the fusion settings for the antenna lever arm")?
                .loose
                .lever_arm_m
        }
    };
    let setup = BridgeSetup {
        runtime: cfg.runtime(role),
        ros2: cfg.ros2.clone(),
        stages: cfg.stages.iter().map(|s| s.name().to_owned()).collect(),
        hardware_id: cfg.group.name.clone(),
        antenna_lever_arm_m: lever_arm,
    };
    // SIGTERM while starting ends in a clean stop (`stage_main`).
    let bridge = Bridge::open(setup).context("opening the ROS 2 bridge")?;
    let stats = bridge.run().context("the ROS 2 bridge")?;
    tracing::info!(
        "ros2: published {} odometry, {} tf, {} imu, {} diagnostics; {} invalid samples, {} too old, {} failed writes; odometry in: {} body velocities, {} refused, {} in another frame, {} failed reads; range finder in: {} heights, {} refused, {} failed reads",
        stats.odometry,
        stats.tf,
        stats.imu,
        stats.diagnostics,
        stats.invalid,
        stats.old,
        stats.write_failures,
        stats.velocities,
        stats.velocities_refused,
        stats.velocities_other_frame,
        stats.odometry_in_read_failures,
        stats.heights,
        stats.heights_refused,
        stats.height_in_read_failures
    );
    Ok(())
}
