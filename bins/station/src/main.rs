//! `insuwb-station`: what listens to the robots from outside them, with
//! the transports the `insuwb` command leaves out (Zenoh, DDS): the fleet's
//! station (`insuwb fleet`, `insuwb fleet record DIR`), its load generator
//! (`insuwb bench fleet`) and the pose probes of `insuwb bench latency
//! --with ros2|zenoh`. `insuwb fleet ...` and `insuwb bench fleet ...` run
//! this executable; it builds with `cargo build --release -p insuwb-station`
//! (or `--workspace`).

mod bench_fleet;
mod fleet_cmd;
mod probe;

use clap::Parser;

/// The fleet's station over Zenoh: every robot's pose, rate, age, status (ok, degraded, stale, lost after 2 s silent) and restarts, live or as JSON snapshots; `record DIR` also records each robot into its own log; `bench` loads it with simulated robots; `probe` listens to one bridge.
#[derive(Debug, Parser)]
#[command(name = "insuwb-station", version, about, long_about = None)]
struct Cli {
    #[command(flatten)]
    fleet: fleet_cmd::FleetArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    // The refusals of the station's access control reach it as Zenoh's
    // own log events (`insuwb_zenoh::identity`).
    let refusals = insuwb_zenoh::identity::Refusals::new();
    let layer = insuwb_zenoh::identity::RefusalLayer::filtered(refusals.clone());
    insuwb_runtime::command_main_with(Some(layer), || fleet_cmd::run(&cli.fleet, refusals))
}
