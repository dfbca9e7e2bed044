//! One strapdown mechanisation step (`Ins::step`), the INS stage's compute
//! per IMU sample.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use insuwb_nav::{Ins, InsConfig, InsState};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let Ok(mut ins) = Ins::new(InsConfig::default(), InsState::default()) else {
        return;
    };
    let mut k: u64 = 0;
    c.bench_function("ins_step", |b| {
        b.iter(|| {
            k += 1;
            let t = k as f64 * 1e-2;
            let accel = [0.1 * t.sin(), 0.05, 9.81];
            let gyro = [0.01, -0.02, 0.3 * t.cos()];
            black_box(ins.step(k * 10_000_000, black_box(accel), black_box(gyro)))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
