//! One prediction step and one TDOA update of the 15-state filter.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use insuwb_eskf::{Eskf, EskfConfig};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let Ok(mut f) = Eskf::new(EskfConfig::default()) else {
        return;
    };
    let q = [0.9659258262890683, 0.0, 0.0, 0.25881904510252074]; // 30 deg yaw
    let fnav = [0.8, -0.3, 9.81];
    c.bench_function("eskf_predict", |b| {
        b.iter(|| f.predict(black_box(0.001), black_box(q), black_box(fnav)))
    });
    let (a, bb) = ([-3.0, -4.0, 0.2], [4.1, -4.3, 3.2]);
    let p = [0.5, 1.0, 1.5];
    let lever = [-0.01245, 0.00127, 0.0908];
    c.bench_function("eskf_update_tdoa", |b| {
        b.iter(|| {
            // A measurement consistent with the state keeps the filter steady.
            let r = f.update_tdoa(black_box(p), q, lever, a, bb, black_box(0.05));
            let _ = f.take_correction();
            r
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
