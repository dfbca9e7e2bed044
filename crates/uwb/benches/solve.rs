//! Multilateration on the fusion path: one 3D fix from the 7 consecutive
//! pairs of 8 anchors (a UTIL-like room), cold (closed-form seed) and warm
//! (seeded by the previous fix), and one 2D fix from the paper's 4 anchors.
#![allow(clippy::unwrap_used, missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use insuwb_uwb::solve::{solve_2d, solve_3d, SolverConfig, TdoaObs};

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn obs(anchors: &[[f64; 3]], pairs: &[(usize, usize)], p: [f64; 3]) -> Vec<TdoaObs> {
    pairs
        .iter()
        .map(|&(i, j)| TdoaObs {
            a_m: anchors[i],
            b_m: anchors[j],
            diff_m: dist(p, anchors[j]) - dist(p, anchors[i]),
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let room = [
        [-3.5, -3.5, 0.2],
        [3.5, -3.5, 2.8],
        [3.5, 3.5, 0.2],
        [-3.5, 3.5, 2.8],
        [-3.5, -3.5, 2.8],
        [3.5, -3.5, 0.2],
        [3.5, 3.5, 2.8],
        [-3.5, 3.5, 0.2],
    ];
    let pairs: Vec<(usize, usize)> = (0..7).map(|i| (i, i + 1)).collect();
    let p = [0.7, -1.2, 1.4];
    let o3 = obs(&room, &pairs, p);
    let cfg = SolverConfig::default();
    c.bench_function("solve_3d/8_anchors_cold", |b| {
        b.iter(|| solve_3d(std::hint::black_box(&o3), None, &cfg).unwrap())
    });
    c.bench_function("solve_3d/8_anchors_warm", |b| {
        b.iter(|| solve_3d(std::hint::black_box(&o3), Some([0.68, -1.18, 1.42]), &cfg).unwrap())
    });
    let square = [
        [-5.0, -5.0, 0.0],
        [5.0, -5.0, 0.0],
        [-5.0, 5.0, 0.0],
        [5.0, 5.0, 0.0],
    ];
    let o2 = obs(&square, &[(0, 1), (0, 2), (0, 3)], [1.0, 2.0, 0.0]);
    c.bench_function("solve_2d/4_anchors_cold", |b| {
        b.iter(|| solve_2d(std::hint::black_box(&o2), 0.0, None, &cfg).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
