//! The simulator's pseudo-random numbers, from the rand family of crates:
//! the generator is `rand_xoshiro`'s [`Xoshiro256StarStar`] (Blackman and
//! Vigna's xoshiro256** 1.0, period 2^256 - 1), seeded by
//! [`SeedableRng::seed_from_u64`] (four SplitMix64 outputs, the seeding its
//! authors recommend); the distributions are `rand`'s (uniform) and
//! `rand_distr`'s (standard normal by the Ziggurat method, exponential).
//! Not for cryptography.
//!
//! Each independent random quantity of a simulation draws from its own
//! stream ([`stream`]): stream `k` of a seed is the seed's generator jumped
//! ahead by `k * 2^128` outputs, so streams never overlap and changing, say,
//! the UWB noise of a scenario leaves its IMU noise bit-identical. The
//! same scenario and seed give the same bits as long as `Cargo.lock` pins
//! the same versions of these crates (the rand project treats a change of
//! a seeded generator's output as a breaking change).
//!
//! Written here, on top of those crates, is only [`Noise`]: the few draws
//! of the simulator with the rules the scenarios rely on (a zero standard
//! deviation draws nothing, so a noise-free configuration consumes no
//! randomness; an empty range gives its lower end instead of panicking).

use rand_distr::{Distribution, Exp1, StandardNormal, Uniform};
pub use rand_xoshiro::Xoshiro256StarStar;

/// The traits of the generator, for callers without a dependency on the
/// rand crates: [`Rng`] (`next_u64`), [`RngExt`] (`random`,
/// `random_range`, `sample`) and [`SeedableRng`] (`seed_from_u64`).
pub use rand::{Rng, RngExt, SeedableRng};

/// The simulator's generator.
pub type SimRng = Xoshiro256StarStar;

/// Stream number `stream` of `seed`: the generator seeded with `seed`
/// ([`SeedableRng::seed_from_u64`]), jumped ahead by `stream * 2^128`
/// outputs (`Xoshiro256StarStar::jump_ce`). Stream 0 is the seed's
/// generator itself; distinct streams of one seed are disjoint stretches of
/// one sequence, each 2^128 outputs long.
#[must_use]
pub fn stream(seed: u64, stream: u64) -> SimRng {
    let mut r = SimRng::seed_from_u64(seed);
    if stream != 0 {
        r.jump_ce(stream, 128);
    }
    r
}

/// The simulator's draws, on any generator of the rand family.
pub trait Noise: RngExt {
    /// Normal double with standard deviation `sigma` (exactly 0.0 when
    /// `sigma == 0`, without drawing, so a noise-free configuration
    /// consumes no randomness).
    fn normal(&mut self, sigma: f64) -> f64 {
        if sigma == 0.0 {
            0.0
        } else {
            let z: f64 = StandardNormal.sample(self);
            sigma * z
        }
    }

    /// Uniform double in `[lo, hi)`; `lo` without drawing when the range
    /// is empty or not finite.
    fn uniform_in(&mut self, lo: f64, hi: f64) -> f64 {
        match Uniform::new(lo, hi) {
            Ok(u) => u.sample(self),
            Err(_) => lo,
        }
    }

    /// `+1.0` or `-1.0` with equal probability.
    fn sign(&mut self) -> f64 {
        if self.random::<bool>() {
            1.0
        } else {
            -1.0
        }
    }

    /// `true` with probability `p` (below 0: never; above 1: always): a
    /// uniform double in `[0, 1)` below `p`. Always draws one number.
    fn bernoulli(&mut self, p: f64) -> bool {
        self.random::<f64>() < p
    }

    /// Exponentially distributed double with the given mean.
    fn exponential(&mut self, mean: f64) -> f64 {
        let e: f64 = Exp1.sample(self);
        mean * e
    }
}

impl<R: RngExt + ?Sized> Noise for R {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_generator_is_xoshiro256starstar_seeded_by_splitmix64() {
        // Reference outputs of xoshiro256starstar.c (Vigna) from the state
        // splitmix64.c gives for seed 0: 0xE220A8397B1DCDAF,
        // 0x6E789E6AA1B965F4, 0x06C45D188009454F, 0xF88BB8A8724C81EC.
        let mut r = SimRng::seed_from_u64(0);
        let s1: u64 = 0x6E78_9E6A_A1B9_65F4;
        assert_eq!(
            r.next_u64(),
            s1.wrapping_mul(5).rotate_left(7).wrapping_mul(9)
        );
    }

    #[test]
    fn streams_are_distinct_and_repeatable() {
        let take = |seed, k| -> Vec<u64> {
            let mut r = stream(seed, k);
            (0..4).map(|_| r.next_u64()).collect()
        };
        assert_eq!(take(42, 1), take(42, 1));
        assert_ne!(take(42, 1), take(42, 2));
        assert_ne!(take(42, 1), take(43, 1));
        assert_ne!(take(42, 0), take(42, 1));
        // Stream 0 is the seed's generator; stream 1 is one jump ahead.
        let mut jumped = SimRng::seed_from_u64(42);
        assert_eq!(stream(42, 0), jumped);
        jumped.jump();
        assert_eq!(stream(42, 1), jumped);
    }

    #[test]
    fn uniform_and_normal_have_the_right_moments() {
        let mut r = SimRng::seed_from_u64(7);
        let n = 200_000;
        let (mut su, mut suu) = (0.0, 0.0);
        for _ in 0..n {
            let u = r.uniform_in(0.0, 1.0);
            assert!((0.0..1.0).contains(&u));
            su += u;
            suu += u * u;
        }
        let mean = su / n as f64;
        let var = suu / n as f64 - mean * mean;
        // Standard errors: 0.29/sqrt(n) = 6.5e-4 for the mean.
        assert!((mean - 0.5).abs() < 4e-3, "{mean}");
        assert!((var - 1.0 / 12.0).abs() < 2e-3, "{var}");

        let (mut s, mut ss, mut s4) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let z = r.normal(1.0);
            s += z;
            ss += z * z;
            s4 += z * z * z * z;
        }
        let mean = s / n as f64;
        let var = ss / n as f64 - mean * mean;
        let kurt = s4 / n as f64;
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.015, "{var}");
        // E[z^4] = 3 for a normal law (a uniform would give 1.8).
        assert!((kurt - 3.0).abs() < 0.1, "{kurt}");
    }

    #[test]
    fn sign_is_balanced_and_exponential_has_its_mean() {
        let mut r = SimRng::seed_from_u64(9);
        let n = 100_000;
        let plus = (0..n).filter(|_| r.sign() > 0.0).count();
        assert!((plus as f64 / n as f64 - 0.5).abs() < 0.01);
        let m: f64 = (0..n).map(|_| r.exponential(2.0)).sum::<f64>() / n as f64;
        assert!((m - 2.0).abs() < 0.05, "{m}");
        let hits = (0..n).filter(|_| r.bernoulli(0.25)).count();
        assert!((hits as f64 / n as f64 - 0.25).abs() < 0.01, "{hits}");
    }

    #[test]
    fn zero_sigma_and_empty_ranges_draw_nothing() {
        let mut a = SimRng::seed_from_u64(3);
        let b = a.clone();
        assert_eq!(a.normal(0.0), 0.0);
        assert_eq!(a.uniform_in(2.0, 2.0), 2.0);
        assert_eq!(a.uniform_in(2.0, 1.0), 2.0);
        assert_eq!(a.uniform_in(0.0, f64::NAN), 0.0);
        assert_eq!(a, b);
    }
}
