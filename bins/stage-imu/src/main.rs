//! The insuwb imu stage: a thin `main` over `insuwb_stage`.
fn main() -> std::process::ExitCode {
    insuwb_stage::cli::main(insuwb_stage::cli::StageRole::Imu)
}
