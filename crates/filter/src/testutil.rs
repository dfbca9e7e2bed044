//! Seeded random numbers for tests: `rand_xoshiro`'s xoshiro256**, `rand`'s
//! uniform and `rand_distr`'s standard normal laws.

use rand::{RngExt as _, SeedableRng as _};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256StarStar;

pub struct Rng(Xoshiro256StarStar);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(Xoshiro256StarStar::seed_from_u64(seed))
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0.random()
    }

    /// Standard normal.
    pub fn normal(&mut self) -> f64 {
        self.0.sample(StandardNormal)
    }
}
