//! Measures the cost of one `Ins::step` (release build):
//! `cargo run -p insuwb-nav --release --example ins_step_cost`.

use std::hint::black_box;
use std::time::Instant;

use insuwb_nav::{Ins, InsConfig, InsState};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut ins = Ins::new(InsConfig::default(), InsState::default())?;
    let n: u64 = 10_000_000;
    let start = Instant::now();
    for k in 0..n {
        let t = k as f64 * 1e-3;
        let accel = [0.1 * t.sin(), 0.05, 9.81];
        let gyro = [0.01, -0.02, 0.3 * t.cos()];
        black_box(ins.step(k * 1_000_000, black_box(accel), black_box(gyro))?);
    }
    let ns = start.elapsed().as_nanos() as f64 / n as f64;
    println!("Ins::step: {ns:.1} ns per step over {n} steps (input generation included)");
    Ok(())
}
