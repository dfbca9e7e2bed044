//! What the fusion stage computes on the 10 Hz path: the time of the
//! `FusionEngine::on_nav` call that completes a UWB update (predict to the
//! fix epoch, update, correction, fused state), hot (back to back, caches
//! warm), cold (8 MiB of other memory touched between cycles, as the other
//! processes of the group do on a shared core), after a 9 ms sleep before
//! each INS state (as the fusion stage, woken for each one), and after the
//! sleep and the stage's warm-up (`FusionEngine::warm_up`) right before it.
//!
//! `cargo run --release -p insuwb-bench --example engine_on_path [EAGER_LAG_S]`
//! (with a lag, the engine predicts through INS states as they arrive, as
//! the fusion stage does in real time).

use std::time::Instant;

use insuwb_fusion::engine::{FusionEngine, Measurement, Outputs};
use insuwb_fusion::ins_engine::InsEngine;
use insuwb_msg::FilterKind;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let sc = insuwb_fusion::scenario::ScenarioFile::load("nlos-long")?;
    let mut cfg = sc.fusion_for_seed(1)?;
    cfg.engine.eager_lag_s = std::env::args().nth(1).and_then(|a| a.parse().ok());
    let sim = insuwb_sim::simulate(&sc.sim, 1)?;
    let fixes = insuwb_fusion::runner::run_fixes(&sim.tdoa, &cfg)?;
    let mut junk = vec![0u8; 8 << 20];
    for (cold, idle, warm) in [
        (false, false, false),
        (true, false, false),
        (false, true, false),
        (false, true, true),
    ] {
        let est = insuwb_fusion::config::build_estimator(FilterKind::Iakf, &cfg)?;
        let mut ins = InsEngine::new(cfg.ins_engine_config())?;
        let mut eng = FusionEngine::new(cfg.engine.clone(), est);
        let mut out = Outputs::default();
        let mut renav = Vec::new();
        let mut next_fix = 0;
        let mut times = Vec::new();
        for s in &sim.imu {
            let t = s.header.meas_time_ns;
            while let Some(f) = fixes.get(next_fix).filter(|f| f.header.meas_time_ns <= t) {
                eng.on_measurement(Measurement::Fix(*f), &mut out);
                next_fix += 1;
            }
            let Some(n) = ins.on_imu(s) else { continue };
            if cold && t % 100_000_000 == 0 {
                for (i, b) in junk.iter_mut().enumerate().step_by(64) {
                    *b = b.wrapping_add(i as u8);
                }
            }
            if idle && (5_000_000_000..15_000_000_000).contains(&t) {
                std::thread::sleep(std::time::Duration::from_millis(9));
                if warm {
                    eng.warm_up();
                }
            }
            let a = Instant::now();
            eng.on_nav(&n, &mut out);
            let dt = a.elapsed();
            let window = if idle {
                5_000_000_000..15_000_000_000
            } else {
                5_000_000_000..u64::MAX
            };
            if !out.fused.is_empty() && window.contains(&t) {
                times.push(dt.as_nanos() as u64);
            }
            let corr = std::mem::take(&mut out.corrections);
            out.clear();
            for c in &corr {
                ins.on_correction(c, &mut renav);
                for r in renav.drain(..) {
                    eng.on_nav(&r, &mut out);
                }
            }
            out.clear();
        }
        times.sort_unstable();
        let p = |q: f64| {
            let i = ((times.len() as f64 * q) as usize).min(times.len().saturating_sub(1));
            times.get(i).map_or(f64::NAN, |&ns| ns as f64 * 1e-3)
        };
        println!(
            "{}: {} updates, on_nav with the update p50 {:.1} us, p90 {:.1} us",
            if warm {
                "idle, warmed"
            } else if idle {
                "idle"
            } else if cold {
                "cold"
            } else {
                "hot "
            },
            times.len(),
            p(0.5),
            p(0.9)
        );
    }
    std::hint::black_box(&junk);
    Ok(())
}
