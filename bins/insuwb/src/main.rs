//! The `insuwb` command line: evaluation, simulation, AR fitting, import of
//! real flights, site calibration of the UWB errors, log tools, the process group (launch, demo, inspect),
//! device emulators (emulate), and the fleet's station (fleet).
//!
//! Logs go to standard error (`RUST_LOG` sets the level); with `--json` a
//! command prints exactly one JSON object on standard output.

mod batch_cmd;
mod bench_cmd;
mod beside;
mod calibrate_cmd;
mod chaos_cmd;
mod dataset;
mod demo_cmd;
mod emulate_cmd;
mod eval_cmd;
mod group_run;
mod inspect_cmd;
mod launch_cmd;
mod log_cmd;
mod monitor;
mod resources;
mod soak_cmd;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// INS/UWB positioning with the paper's improved adaptive Kalman filter, as a
/// zero-copy multi-process pipeline.
#[derive(Debug, Parser)]
#[command(name = "insuwb", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Run UWB-only, INS-only and the filters on a log or a simulated scenario, and print Table 1.
    Eval(eval_cmd::EvalArgs),
    /// Learn a site calibration of the UWB TDOA errors from flights with ground truth (`--cross-validate`: leave-one-flight-out figures of every candidate family).
    Calibrate(calibrate_cmd::CalibrateArgs),
    /// Simulate a scenario into a log.
    Sim(eval_cmd::SimArgs),
    /// Fit the AR(3) sensor error models on a static segment and print a config snippet.
    FitAr(eval_cmd::FitArArgs),
    /// Convert another format into an insuwb log.
    #[command(subcommand)]
    Import(ImportCmd),
    /// Inspect logs.
    #[command(subcommand)]
    Log(log_cmd::LogCmd),
    /// Start the process group of a robot config and keep it running.
    Launch(launch_cmd::LaunchArgs),
    /// Run the whole group on simulated sensors, then report accuracy, rates and latency.
    Demo(demo_cmd::DemoArgs),
    /// Run the group on simulated sensors under random SIGKILL/SIGSTOP faults and check recovery.
    Chaos(chaos_cmd::ChaosArgs),
    /// The group for hours under periodic random faults with the Foxglove view, the Zenoh bridge and the logger: every minute each process's memory, descriptors, shared-memory files and the fused rate, then what grew after warm-up.
    Soak(soak_cmd::SoakArgs),
    /// Benchmarks: the process pipeline's latency against bare iceoryx2, the fleet's station under load.
    #[command(subcommand)]
    Bench(bench_cmd::BenchCmd),
    /// Emulate a real IMU or UWB device on a pseudo-terminal or a loopback TCP port, fed by a scenario or a log.
    #[command(subcommand)]
    Emulate(emulate_cmd::EmulateCmd),
    /// Live per-topic rates, last-sample ages, publishers and subscribers of a running group.
    Inspect(inspect_cmd::InspectArgs),
    /// The fleet's station over Zenoh: every robot's pose, rate, age, status (ok, degraded, stale, lost after 2 s silent) and restarts, live or as JSON snapshots; `fleet record DIR` also records each robot into its own log. Runs insuwb-station (`insuwb fleet --help` for its options; build it with `cargo build --release -p insuwb-station`).
    #[command(disable_help_flag = true)]
    Fleet {
        /// The station's arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
}

#[derive(Debug, Subcommand)]
enum ImportCmd {
    /// A UTIL dataset Crazyflie micro-SD log.
    Util(eval_cmd::ImportUtilArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    insuwb_runtime::command_main(|| run(cli))
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Eval(a) => eval_cmd::eval(&a),
        Cmd::Calibrate(a) => calibrate_cmd::run(&a),
        Cmd::Sim(a) => eval_cmd::sim(&a),
        Cmd::FitAr(a) => eval_cmd::fit_ar(&a),
        Cmd::Import(ImportCmd::Util(a)) => eval_cmd::import_util(&a),
        Cmd::Log(c) => log_cmd::run(&c),
        Cmd::Launch(a) => launch_cmd::launch(&a),
        Cmd::Demo(a) => demo_cmd::demo(&a),
        Cmd::Inspect(a) => inspect_cmd::inspect(&a),
        Cmd::Chaos(a) => chaos_cmd::chaos(&a),
        Cmd::Soak(a) => soak_cmd::soak(&a),
        Cmd::Bench(c) => bench_cmd::run(&c),
        Cmd::Emulate(c) => emulate_cmd::run(&c),
        Cmd::Fleet { args } => beside::exec("insuwb-station", &args),
    }
}
