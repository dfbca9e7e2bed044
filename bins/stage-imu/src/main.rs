//! The insuwb imu stage: a thin `main` over `insuwb_stage`.

/// The log filter when `RUST_LOG` is unset: RustDDS (the `ros2:/TOPIC`
/// source) reports every socket and discovery event at `info`, and
/// ros2-client warns when `ROS_DISTRO` is unset.
const DEFAULT_FILTER: &str = "info,rustdds=warn,ros2_client=warn,ros2_client::distributions=error";

fn main() -> std::process::ExitCode {
    if std::env::var_os("RUST_LOG").is_none_or(|v| v.is_empty()) {
        // Single-threaded still: nothing reads the environment concurrently.
        std::env::set_var("RUST_LOG", DEFAULT_FILTER);
    }
    insuwb_stage::cli::main(insuwb_stage::cli::StageRole::Imu)
}
