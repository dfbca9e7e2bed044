//! One 100 ms filter cycle (10 IMU-rate predicts + 1 UWB update) for each
//! filter, and the sparse `F P F^T + Q` against the dense 14 x 14 product.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use insuwb_filter::{
    build, dense, predict_dense, predict_sparse, FilterParams, FilterSetup, Mat14, ModelConfig,
    PaperModel,
};
use insuwb_msg::FilterKind;
use nalgebra::SVector;

fn model() -> Option<PaperModel> {
    PaperModel::new(ModelConfig::default()).ok()
}

fn cycle(c: &mut Criterion) {
    let Some(model) = model() else {
        eprintln!("default model config does not validate");
        return;
    };
    let mut group = c.benchmark_group("cycle_100ms");
    for kind in [
        FilterKind::Kf,
        FilterKind::Shaf,
        FilterKind::Stf,
        FilterKind::Iakf,
    ] {
        let Ok(mut f) = build(
            kind,
            model.clone(),
            &FilterParams::default(),
            &FilterSetup::default(),
        ) else {
            eprintln!("cannot build {kind:?}");
            return;
        };
        let mut k = 0u64;
        group.bench_function(format!("{kind:?}"), |b| {
            b.iter(|| {
                for i in 0..10 {
                    let t = (k * 10 + i) as f64 * 0.01;
                    let ok = f.predict(0.01, 0.5 * t.sin(), 0.3 * t.cos()).is_ok();
                    black_box(ok);
                }
                k += 1;
                let s = (k as f64 * 0.37).sin() * 0.05;
                let z = SVector::<f64, 4>::new(s, -s, 0.5 * s, 0.2 * s);
                let rep = f.update(black_box(&z));
                black_box(rep.map(|r| r.nis).unwrap_or(0.0));
                black_box(f.take_correction());
            });
        });
    }
    group.finish();
}

fn fpft(c: &mut Criterion) {
    let Some(model) = model() else {
        return;
    };
    let a = Mat14::from_fn(|i, j| ((i * 14 + j) as f64 * 0.618).sin());
    let p = a * a.transpose() + Mat14::identity();
    let t = model.transition(0.01, 0.4, -0.3);
    let q_diag = model.process_noise_diag(0.01);
    let f = dense(&t);
    let q = model.process_noise(0.01);
    let mut group = c.benchmark_group("fpft_plus_q");
    group.bench_function("sparse", |b| {
        b.iter(|| predict_sparse(black_box(&p), black_box(&t), black_box(&q_diag)))
    });
    group.bench_function("dense", |b| {
        b.iter(|| predict_dense(black_box(&p), black_box(&f), black_box(&q)))
    });
    group.finish();
}

criterion_group!(benches, cycle, fpft);
criterion_main!(benches);
