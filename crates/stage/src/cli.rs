//! The command line shared by the stage binaries.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;

use crate::lock::STAGE_LOCK_WAIT;
use crate::source::Want;
use insuwb_group::robot::{start_epoch_ns, RobotConfig};
use insuwb_group::sources::Source;

pub use insuwb_msg::StageRole;

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
    /// Driver source, overriding the config: `sim`, `replay:FILE` (relative
    /// to the current directory), `device` or (IMU) `ros2:/TOPIC`.
    #[arg(long)]
    pub source: Option<Source>,
    /// Replay speed, overriding the config's `sources.speed` for every stage
    /// (the drivers' pacing and the fusion stage's eager updates alike): a
    /// factor (10 = ten times real time) or `max` (lockstep with the
    /// consumers, never dropping a sample).
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

/// Puts `--speed` (when given) into the config for every stage: the
/// drivers pace by it and the fusion stage chooses eager or lazy updates by
/// it, so a fusion stage started by hand with `--speed max` predicts lazily
/// behind drivers that run in lockstep, as the launcher's group does.
/// Returns the speed in force.
///
/// # Errors
/// A speed that is not > 0.
pub fn apply_speed(cfg: &mut RobotConfig, speed: Option<f64>) -> anyhow::Result<f64> {
    let speed = speed.unwrap_or(cfg.sources.speed);
    if speed.is_nan() || speed <= 0.0 {
        anyhow::bail!("--speed must be > 0, got {speed}");
    }
    cfg.sources.speed = speed;
    Ok(speed)
}

/// Parses the arguments, sets up tracing and runs the stage; exit code 0 on a clean stop.
#[must_use]
pub fn main(kind: StageRole) -> ExitCode {
    let args = StageArgs::parse();
    insuwb_runtime::stage_main(kind.name(), || run(kind, &args))
}

fn run(kind: StageRole, args: &StageArgs) -> anyhow::Result<()> {
    let mut cfg = RobotConfig::load(&args.config)?;
    // One process per role and group, before anything of the group is
    // opened: a stage started by hand beside its running group refuses.
    let _role = crate::lock::StageLock::acquire(&cfg.group, kind.name(), STAGE_LOCK_WAIT)?;
    let epoch = args.start_epoch_ns.unwrap_or_else(start_epoch_ns);
    let speed = apply_speed(&mut cfg, args.speed)?;
    let result = match kind {
        StageRole::Imu => {
            let src = args.source.as_ref().unwrap_or(&cfg.sources.imu);
            crate::driver::run(Want::Imu, &cfg, src, speed, epoch)
        }
        StageRole::Uwb => {
            let src = args.source.as_ref().unwrap_or(&cfg.sources.uwb);
            crate::driver::run(Want::Uwb, &cfg, src, speed, epoch)
        }
        StageRole::Ins => crate::ins::run(&cfg),
        StageRole::Fusion => crate::fusion::run(&cfg, epoch),
        StageRole::Logger => crate::logger::run(&cfg),
        StageRole::Ros2 => Err(anyhow::anyhow!(
            "the ros2 stage is its own binary insuwb-stage-ros2"
        )),
        StageRole::Foxglove => Err(anyhow::anyhow!(
            "the foxglove stage is its own binary insuwb-stage-foxglove"
        )),
        StageRole::Zenoh => Err(anyhow::anyhow!(
            "the zenoh stage is its own binary insuwb-stage-zenoh"
        )),
    };
    // SIGTERM while starting: `stage_main` makes it a clean stop.
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    const ROBOT: &str = include_str!("../../../config/robot.toml");

    fn robot() -> RobotConfig {
        RobotConfig::from_str(ROBOT, "config/robot.toml", std::path::Path::new("/tmp"))
            .expect("config/robot.toml loads")
    }

    /// `--speed max` reaches the fusion stage too: it then predicts lazily,
    /// as behind the launcher's lockstep drivers (issue: it used to read the
    /// file's speed and ran eager behind lockstep drivers).
    #[test]
    fn speed_override_reaches_every_stage() {
        let mut cfg = robot();
        assert!(cfg.sources.speed.is_finite());
        let eager = crate::fusion::eager_lag_s(&cfg);
        assert!(eager.is_some(), "the robot config runs eager in real time");
        assert_eq!(
            apply_speed(&mut cfg, Some(f64::INFINITY)).unwrap(),
            f64::INFINITY
        );
        assert_eq!(cfg.sources.speed, f64::INFINITY);
        assert_eq!(crate::fusion::eager_lag_s(&cfg), None);
        // No override: the file's speed stays.
        let mut plain = robot();
        let file = plain.sources.speed;
        assert_eq!(apply_speed(&mut plain, None).unwrap(), file);
        assert!(apply_speed(&mut plain, Some(0.0)).is_err());
        assert!(apply_speed(&mut plain, Some(f64::NAN)).is_err());
    }
}
