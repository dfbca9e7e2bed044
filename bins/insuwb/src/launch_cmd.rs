//! `insuwb launch`: runs a robot's process group until stopped.

use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use insuwb_group::robot::RobotConfig;

use crate::group_run::{run_group, Fault, RunOptions};

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
            sample_every: None,
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
