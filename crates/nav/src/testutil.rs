//! Test-only seeded standard normal samples: `rand_xoshiro`'s xoshiro256**
//! and `rand_distr`'s standard normal law.

use rand::{RngExt as _, SeedableRng as _};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256StarStar;

/// Standard normal samples from a seed.
pub(crate) struct Gauss(Xoshiro256StarStar);

impl Gauss {
    pub(crate) fn new(seed: u64) -> Self {
        Self(Xoshiro256StarStar::seed_from_u64(seed))
    }

    pub(crate) fn sample(&mut self) -> f64 {
        self.0.sample(StandardNormal)
    }
}

#[test]
fn gauss_has_unit_variance() {
    let mut g = Gauss::new(1);
    let n = 100_000;
    let xs: Vec<f64> = (0..n).map(|_| g.sample()).collect();
    let mean = xs.iter().sum::<f64>() / n as f64;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
    assert!(
        mean.abs() < 0.01 && (var - 1.0).abs() < 0.02,
        "{mean} {var}"
    );
}
