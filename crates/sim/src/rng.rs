//! The simulator's own pseudo-random numbers: SplitMix64 seeding a
//! xoshiro256** generator, uniform doubles and Box-Muller Gaussians.
//!
//! Written here (instead of using the `rand` crate) so a scenario and a seed
//! give the same bits forever, whatever happens to dependencies. Not for
//! cryptography.
//!
//! - [`SplitMix64`]: Steele, Lea and Flood's 64-bit mixer (as in Java's
//!   `SplittableRandom`), used only to expand a seed into generator state.
//! - [`Rng`]: Blackman and Vigna's xoshiro256** 1.0, period 2^256 - 1.
//! - Uniform doubles take the top 53 bits: `(x >> 11) * 2^-53`, in `[0, 1)`.
//! - Gaussians use the Box-Muller transform on two uniforms, returning the
//!   cosine branch first and caching the sine branch for the next call.
//!
//! Each independent random quantity of a simulation draws from its own
//! stream ([`Rng::stream`]), so changing, say, the UWB noise of a scenario
//! leaves its IMU noise bit-identical.

/// SplitMix64: a 64-bit state advanced by the golden-ratio increment and
/// passed through a bijective mixer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator whose first output is `mix(seed + 0x9E3779B97F4A7C15)`.
    #[must_use]
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// Next 64-bit output.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// xoshiro256** with a cached Box-Muller spare.
#[derive(Debug, Clone, PartialEq)]
pub struct Rng {
    s: [u64; 4],
    spare_gauss: Option<f64>,
}

impl Rng {
    /// Generator with the given raw state. An all-zero state (the one fixed
    /// point of xoshiro) is replaced by the SplitMix64 expansion of 0.
    #[must_use]
    pub fn from_state(s: [u64; 4]) -> Self {
        if s == [0; 4] {
            return Self::from_seed(0);
        }
        Self {
            s,
            spare_gauss: None,
        }
    }

    /// Generator whose state is four consecutive SplitMix64 outputs from `seed`
    /// (the seeding recommended by the xoshiro authors).
    #[must_use]
    pub fn from_seed(seed: u64) -> Self {
        let mut sm = SplitMix64::new(seed);
        let s = [sm.next_u64(), sm.next_u64(), sm.next_u64(), sm.next_u64()];
        // SplitMix64 is a bijection of a counter: four outputs are never all zero.
        Self {
            s,
            spare_gauss: None,
        }
    }

    /// Independent stream number `stream` of `seed`: seeds [`Rng::from_seed`]
    /// with `SplitMix64(seed).next() ^ SplitMix64(!stream).next()`, so
    /// different `(seed, stream)` pairs give unrelated sequences.
    #[must_use]
    pub fn stream(seed: u64, stream: u64) -> Self {
        let a = SplitMix64::new(seed).next_u64();
        let b = SplitMix64::new(!stream).next_u64();
        Self::from_seed(a ^ b)
    }

    /// Next 64-bit output (xoshiro256** 1.0).
    pub fn next_u64(&mut self) -> u64 {
        let [s0, s1, s2, s3] = self.s;
        let result = s1.wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = s1 << 17;
        let s2 = s2 ^ s0;
        let s3 = s3 ^ s1;
        let s1 = s1 ^ s2;
        let s0 = s0 ^ s3;
        let s2 = s2 ^ t;
        let s3 = s3.rotate_left(45);
        self.s = [s0, s1, s2, s3];
        result
    }

    /// Uniform double in `[0, 1)` with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        // 2^-53
        const SCALE: f64 = 1.0 / 9_007_199_254_740_992.0;
        (self.next_u64() >> 11) as f64 * SCALE
    }

    /// Uniform double in `[lo, hi)` (`lo` when `hi <= lo`).
    pub fn uniform_in(&mut self, lo: f64, hi: f64) -> f64 {
        let u = self.uniform();
        if hi > lo {
            lo + (hi - lo) * u
        } else {
            lo
        }
    }

    /// `+1.0` or `-1.0` with equal probability (the top bit of one output).
    pub fn sign(&mut self) -> f64 {
        if self.next_u64() >> 63 == 1 {
            1.0
        } else {
            -1.0
        }
    }

    /// `true` with probability `p` (clamped to `[0, 1]`); always draws one uniform.
    pub fn bernoulli(&mut self, p: f64) -> bool {
        self.uniform() < p
    }

    /// Exponentially distributed double with the given mean (inverse transform).
    pub fn exponential(&mut self, mean: f64) -> f64 {
        // 1 - u is in (0, 1]: the logarithm is finite.
        -mean * (1.0 - self.uniform()).ln()
    }

    /// Standard normal double (Box-Muller; pairs are generated together).
    pub fn gauss(&mut self) -> f64 {
        if let Some(z) = self.spare_gauss.take() {
            return z;
        }
        // u1 in (0, 1] keeps ln finite; u2 in [0, 1).
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (core::f64::consts::TAU * u2).sin_cos();
        self.spare_gauss = Some(r * s);
        r * c
    }

    /// Normal double with standard deviation `sigma` (exactly 0.0 when `sigma == 0`,
    /// without drawing, so a noise-free configuration consumes no randomness).
    pub fn normal(&mut self, sigma: f64) -> f64 {
        if sigma == 0.0 {
            0.0
        } else {
            sigma * self.gauss()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_the_reference_outputs() {
        // Reference values of splitmix64.c (Vigna) from state 0.
        let mut sm = SplitMix64::new(0);
        assert_eq!(sm.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(sm.next_u64(), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(sm.next_u64(), 0x06C4_5D18_8009_454F);
    }

    #[test]
    fn xoshiro256starstar_matches_the_reference_outputs() {
        // Reference outputs of xoshiro256starstar.c from state [1, 2, 3, 4].
        let mut r = Rng::from_state([1, 2, 3, 4]);
        let got: Vec<u64> = (0..6).map(|_| r.next_u64()).collect();
        assert_eq!(
            got,
            vec![
                11520,
                0,
                1_509_978_240,
                1_215_971_899_390_074_240,
                1_216_172_134_540_287_360,
                607_988_272_756_665_600
            ]
        );
    }

    #[test]
    fn streams_are_distinct_and_repeatable() {
        let a: Vec<u64> = {
            let mut r = Rng::stream(42, 1);
            (0..4).map(|_| r.next_u64()).collect()
        };
        let a2: Vec<u64> = {
            let mut r = Rng::stream(42, 1);
            (0..4).map(|_| r.next_u64()).collect()
        };
        let b: Vec<u64> = {
            let mut r = Rng::stream(42, 2);
            (0..4).map(|_| r.next_u64()).collect()
        };
        let c: Vec<u64> = {
            let mut r = Rng::stream(43, 1);
            (0..4).map(|_| r.next_u64()).collect()
        };
        assert_eq!(a, a2);
        assert_ne!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn uniform_and_gauss_have_the_right_moments() {
        let mut r = Rng::from_seed(7);
        let n = 200_000;
        let (mut su, mut suu) = (0.0, 0.0);
        for _ in 0..n {
            let u = r.uniform();
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
            let z = r.gauss();
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
        let mut r = Rng::from_seed(9);
        let n = 100_000;
        let plus = (0..n).filter(|_| r.sign() > 0.0).count();
        assert!((plus as f64 / n as f64 - 0.5).abs() < 0.01);
        let m: f64 = (0..n).map(|_| r.exponential(2.0)).sum::<f64>() / n as f64;
        assert!((m - 2.0).abs() < 0.05, "{m}");
    }

    #[test]
    fn zero_sigma_draws_nothing() {
        let mut a = Rng::from_seed(3);
        let mut b = Rng::from_seed(3);
        assert_eq!(a.normal(0.0), 0.0);
        assert_eq!(a.next_u64(), b.next_u64());
    }
}
