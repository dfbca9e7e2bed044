//! The INS stage's work per IMU sample: `InsEngine::on_imu` (checks, one
//! mechanisation step, the NavState, the history ring for re-propagation).
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use insuwb_fusion::ins_engine::{InsEngine, InsEngineConfig};
use insuwb_msg::{Header, ImuSample};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let Ok(mut eng) = InsEngine::new(InsEngineConfig::default()) else {
        return;
    };
    let mut k: u64 = 0;
    let mut sample = move || {
        k += 1;
        let t = k as f64 * 1e-2;
        ImuSample {
            header: Header::new(k, k * 10_000_000),
            accel_mps2: [0.1 * t.sin(), 0.05, 9.81],
            gyro_rps: [0.01, -0.02, 0.3 * t.cos()],
        }
    };
    // Past the start-up and through one lap of the history ring.
    for _ in 0..5000 {
        let _ = eng.on_imu(&sample());
    }
    c.bench_function("ins_engine_on_imu", |b| {
        b.iter(|| black_box(eng.on_imu(black_box(&sample()))))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
