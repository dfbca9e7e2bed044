//! `insuwb-bench-floor`: one process of the latency benchmark's floor graph (a
//! thin `main` over `insuwb_bench::floor`; normally started by
//! `insuwb bench latency`). It forwards samples with bare iceoryx2 through
//! the runtime's ports, with no maths and no logging, until SIGINT/SIGTERM.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use insuwb_bench::floor::{run_role, FloorConfig, Role};

/// One role of the floor graph of `insuwb bench latency`.
#[derive(Debug, Parser)]
#[command(name = "insuwb-bench-floor", version, about)]
struct Args {
    /// Role: imu, uwb, ins, fusion or logger.
    #[arg(long)]
    role: Role,
    /// iceoryx2 service prefix of the floor graph.
    #[arg(long, default_value = "insuwb_floor_")]
    prefix: String,
    /// iceoryx2 root folder (absolute).
    #[arg(long)]
    root_path: Option<PathBuf>,
    /// Start epoch shared by the drivers (CLOCK_MONOTONIC ns); 0: the next
    /// start epoch at least 0.5 s ahead (`insuwb_runtime::epoch`), as the
    /// pipeline's.
    #[arg(long, default_value_t = 0)]
    start_epoch_ns: u64,
    /// IMU rate, Hz.
    #[arg(long, default_value_t = 100.0)]
    imu_rate_hz: f64,
    /// UWB fix rate, Hz.
    #[arg(long, default_value_t = 10.0)]
    uwb_rate_hz: f64,
    /// TDOA measurements per fix epoch.
    #[arg(long, default_value_t = 3)]
    tdoa_per_epoch: u32,
    /// Folder the logger role writes its records and receive trace to at exit.
    #[arg(long)]
    trace_dir: Option<PathBuf>,
    /// SCHED_FIFO priority (1-99) of this role, as a stage's
    /// `[realtime.*] fifo_priority` (needs CAP_SYS_NICE); none: the normal scheduler.
    #[arg(long)]
    fifo_priority: Option<i32>,
}

fn main() -> ExitCode {
    let a = Args::parse();
    let name = format!("floor-{}", a.role.name());
    let cfg = FloorConfig {
        prefix: a.prefix,
        root_path: a.root_path,
        start_epoch_ns: a.start_epoch_ns,
        imu_rate_hz: a.imu_rate_hz,
        uwb_rate_hz: a.uwb_rate_hz,
        tdoa_per_epoch: a.tdoa_per_epoch,
        trace_dir: a.trace_dir,
        fifo_priority: a.fifo_priority,
        ..FloorConfig::default()
    };
    insuwb_runtime::stage_main(&name, || {
        run_role(a.role, &cfg).map_err(Box::<dyn std::error::Error + Send + Sync>::from)
    })
}
