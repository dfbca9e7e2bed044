//! Shared test helpers: seeded random numbers and anchor layouts.
#![allow(dead_code)]

use insuwb_uwb::solve::TdoaObs;
use rand::{RngExt as _, SeedableRng as _};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256StarStar;

/// Seeded random numbers: `rand_xoshiro`'s xoshiro256**, `rand`'s uniform
/// and `rand_distr`'s standard normal laws.
pub struct Gauss(Xoshiro256StarStar);

impl Gauss {
    pub fn new(seed: u64) -> Self {
        Self(Xoshiro256StarStar::seed_from_u64(seed))
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0.random()
    }

    pub fn normal(&mut self) -> f64 {
        self.0.sample(StandardNormal)
    }
}

/// UTIL `anchors-const3.txt` (an0..an7), m.
pub const CONST3: [[f64; 3]; 8] = [
    [-3.0400739913644617, -4.029878605797746, 0.2086374396157397],
    [-3.2322604228535727, 3.7560564637264355, 2.946689630262403],
    [3.676682796054712, 3.715609004632582, 0.17403476155729386],
    [4.104077249319202, -4.274469287062838, 3.2020642683316893],
    [-3.041510989575704, -4.410450309911892, 3.0430580370331044],
    [3.917772330969977, -3.786201138515536, 0.19753353417151204],
    [4.061509380447565, 3.8548627765644454, 3.1409729774538255],
    [-3.168670058421678, 3.3521825925451214, 0.17908062216020118],
];

/// The paper's simulation anchors (READING.md erratum 16), at height `z`.
pub fn paper_square(z: f64) -> [[f64; 3]; 4] {
    [
        [-5.0, -5.0, z],
        [5.0, -5.0, z],
        [-5.0, 5.0, z],
        [5.0, 5.0, z],
    ]
}

/// The paper's experiment anchors (erratum 16), at height `z`.
pub fn experiment_room(z: f64) -> [[f64; 3]; 4] {
    [[0.0, 0.0, z], [7.0, 0.0, z], [0.0, 5.0, z], [7.0, 5.0, z]]
}

pub fn dist(p: [f64; 3], a: [f64; 3]) -> f64 {
    ((p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2) + (p[2] - a[2]).powi(2)).sqrt()
}

/// Exact observation of pair (a, b) for a tag at `p`: |p - b| - |p - a|.
pub fn obs(a: [f64; 3], b: [f64; 3], p: [f64; 3]) -> TdoaObs {
    TdoaObs {
        a_m: a,
        b_m: b,
        diff_m: dist(p, b) - dist(p, a),
    }
}

/// Pairs (0, k) for every other anchor: a common reference.
pub fn star(anchors: &[[f64; 3]], p: [f64; 3]) -> Vec<TdoaObs> {
    anchors[1..]
        .iter()
        .map(|&b| obs(anchors[0], b, p))
        .collect()
}

/// Consecutive pairs (0,1), (1,2), ..., (n-1, 0), as UTIL TDOA2 logs.
pub fn ring(anchors: &[[f64; 3]], p: [f64; 3]) -> Vec<TdoaObs> {
    (0..anchors.len())
        .map(|k| obs(anchors[k], anchors[(k + 1) % anchors.len()], p))
        .collect()
}

pub fn err(a: [f64; 3], b: [f64; 3]) -> f64 {
    dist(a, b)
}
