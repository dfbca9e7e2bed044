//! AR(p) model fitting of a sensor-error record by Yule-Walker with
//! Levinson-Durbin (paper eqs. 4-5; READING.md "The model").
//!
//! The series is de-meaned, its biased autocorrelation
//! `r_k = (1/N) sum_{t=k}^{N-1} x_t x_{t-k}` (k = 0..p) is taken, and the
//! Toeplitz system `R phi = [r_1 .. r_p]` is solved by Levinson-Durbin, giving
//! `x_t = phi_1 x_{t-1} + ... + phi_p x_{t-p} + w_t` with
//! `sigma_w^2 = r_0 - phi . [r_1 .. r_p]`. The paper writes the same model as
//! `a_k = -m_1 a_{k-1} - ... - m_p a_{k-p} + w_k`, so `m = -phi`.
//!
//! Rate (erratum 6): the coefficients describe the series at its own sample
//! interval. Fitted on a 100 Hz record they are a 100 Hz model; a filter that
//! propagates at another rate must predict at the IMU rate, or refit on the
//! series decimated to its own rate.
//!
//! The mean is removed, not modelled: a constant bias plus white noise fits as
//! nearly white (erratum 19).

use thiserror::Error;

/// Highest AR order accepted (bounds the work and the allocation of a fit).
pub const MAX_AR_ORDER: usize = 64;

/// Fewest samples per AR order: a series needs at least `10 * order` samples.
pub const MIN_SAMPLES_PER_ORDER: usize = 10;

/// An AR(p) fit.
#[derive(Debug, Clone, PartialEq)]
pub struct ArFit {
    /// Yule-Walker coefficients `phi_1..phi_p`: `x_t = sum phi_i x_{t-i} + w_t`.
    pub phi: Vec<f64>,
    /// Paper convention (eq. 4), `m = -phi`: `a_k = -m_1 a_{k-1} - ... + w_k`.
    pub m: Vec<f64>,
    /// Driving white-noise variance `sigma_w^2 = r_0 - phi . r`, in the
    /// series' unit squared, per sample.
    pub noise_var: f64,
    /// Mean removed before fitting, in the series' unit.
    pub mean: f64,
    /// Variance of the series (the biased `r_0`), in the series' unit squared.
    pub variance: f64,
}

/// An AR(3) fit in the paper's convention (eqs. 4-5).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ar3Fit {
    /// `[m_1, m_2, m_3]` of `a_k = -m_1 a_{k-1} - m_2 a_{k-2} - m_3 a_{k-3} + w_k`.
    pub m: [f64; 3],
    /// Driving white-noise variance, the series' unit squared, per sample.
    pub noise_var: f64,
    /// Mean removed before fitting.
    pub mean: f64,
    /// Variance of the series (biased `r_0`).
    pub variance: f64,
}

/// Why an AR fit failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ArFitError {
    /// The order is 0 or above [`MAX_AR_ORDER`].
    #[error("AR order must be in 1..={MAX_AR_ORDER}, got {0}")]
    Order(usize),
    /// Fewer than `10 * order` samples.
    #[error("AR({order}) fit needs at least {min_len} samples, got {len}")]
    TooShort {
        /// Samples given.
        len: usize,
        /// Order asked.
        order: usize,
        /// Samples needed.
        min_len: usize,
    },
    /// A sample is NaN or infinite.
    #[error("AR fit series[{index}] is not finite: {value}")]
    NonFinite {
        /// Index of the sample.
        index: usize,
        /// Offending value.
        value: f64,
    },
    /// The series is constant (its variance is zero to rounding).
    #[error("AR fit series has zero variance ({variance}) around its mean {mean}")]
    ZeroVariance {
        /// Variance found.
        variance: f64,
        /// Mean of the series.
        mean: f64,
    },
    /// The autocorrelation overflowed (values too large to square).
    #[error("AR fit autocorrelation overflowed: r_{lag} = {value}")]
    Overflow {
        /// Lag whose autocorrelation is not finite.
        lag: usize,
        /// Its value.
        value: f64,
    },
    /// The Toeplitz system is singular (the series is perfectly predictable
    /// at a lower order, e.g. a pure sinusoid).
    #[error("AR fit Toeplitz system is singular at order {order}: prediction error {error}")]
    Singular {
        /// Order at which the prediction error vanished.
        order: usize,
        /// Prediction error found.
        error: f64,
    },
}

/// Fit an AR(`order`) model to `series` (one sensor axis of a static record,
/// at its own sample rate) by Yule-Walker / Levinson-Durbin.
///
/// # Errors
/// See [`ArFitError`]: bad order, fewer than `10 * order` samples, a
/// non-finite sample, a constant series, overflow, or a singular system.
pub fn fit_ar(series: &[f64], order: usize) -> Result<ArFit, ArFitError> {
    if order == 0 || order > MAX_AR_ORDER {
        return Err(ArFitError::Order(order));
    }
    let min_len = MIN_SAMPLES_PER_ORDER * order;
    if series.len() < min_len {
        return Err(ArFitError::TooShort {
            len: series.len(),
            order,
            min_len,
        });
    }
    if let Some((index, &value)) = series.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(ArFitError::NonFinite { index, value });
    }
    let n = series.len() as f64;
    let mean = series.iter().sum::<f64>() / n;
    if !mean.is_finite() {
        return Err(ArFitError::Overflow {
            lag: 0,
            value: mean,
        });
    }

    // Biased autocorrelation r_0..r_p of the de-meaned series.
    let r: Vec<f64> = (0..=order)
        .map(|k| {
            series
                .iter()
                .zip(series.iter().skip(k))
                .map(|(a, b)| (a - mean) * (b - mean))
                .sum::<f64>()
                / n
        })
        .collect();
    if let Some((lag, &value)) = r.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(ArFitError::Overflow { lag, value });
    }
    let r0 = r.first().copied().unwrap_or(0.0);
    // Zero to rounding: below (1e-12 |mean|)^2, or exactly zero.
    let floor = (1e-12 * mean.abs()).powi(2);
    if r0 <= floor {
        return Err(ArFitError::ZeroVariance { variance: r0, mean });
    }

    let (phi, noise_var) = levinson_durbin(&r, order)?;
    let m = phi.iter().map(|p| -p).collect();
    Ok(ArFit {
        phi,
        m,
        noise_var,
        mean,
        variance: r0,
    })
}

/// Solve the Yule-Walker system for `r = [r_0 .. r_p]` (`r.len() == order + 1`):
/// returns `phi` and the final prediction error `r_0 - phi . r_{1..p}`.
fn levinson_durbin(r: &[f64], order: usize) -> Result<(Vec<f64>, f64), ArFitError> {
    let mut phi = vec![0.0; order];
    let mut prev = vec![0.0; order];
    let mut err = r.first().copied().unwrap_or(0.0);
    for k in 0..order {
        // kappa_k = (r_{k+1} - sum_{j<k} phi_j r_{k-j}) / err
        let mut acc = r.get(k + 1).copied().unwrap_or(0.0);
        for (j, p) in phi.iter().take(k).enumerate() {
            acc -= p * r.get(k - j).copied().unwrap_or(0.0);
        }
        let kappa = acc / err;
        prev.copy_from_slice(&phi);
        for j in 0..k {
            if let (Some(p), Some(q)) = (phi.get_mut(j), prev.get(k - 1 - j)) {
                *p -= kappa * q;
            }
        }
        if let Some(p) = phi.get_mut(k) {
            *p = kappa;
        }
        err *= 1.0 - kappa * kappa;
        if !(err > 0.0 && err.is_finite()) {
            return Err(ArFitError::Singular {
                order: k + 1,
                error: err,
            });
        }
    }
    Ok((phi, err))
}

/// [`fit_ar`] of order 3 in the paper's form (eqs. 4-5).
///
/// # Errors
/// As [`fit_ar`] (fewer than 30 samples, non-finite, constant, ...).
pub fn fit_ar3(series: &[f64]) -> Result<Ar3Fit, ArFitError> {
    let fit = fit_ar(series, 3)?;
    let m = match fit.m.as_slice() {
        &[m1, m2, m3] => [m1, m2, m3],
        // fit_ar(_, 3) returns three coefficients.
        _ => return Err(ArFitError::Order(fit.m.len())),
    };
    Ok(Ar3Fit {
        m,
        noise_var: fit.noise_var,
        mean: fit.mean,
        variance: fit.variance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Gauss;

    /// `n` samples of `x_t = sum phi_i x_{t-i} + sigma w_t + mean`, after a burn-in.
    fn simulate(phi: &[f64], sigma: f64, mean: f64, n: usize, seed: u64) -> Vec<f64> {
        let mut g = Gauss::new(seed);
        let mut hist = vec![0.0; phi.len()]; // hist[0] = x_{t-1}
        let mut out = Vec::with_capacity(n);
        for t in 0..n + 1000 {
            let x: f64 =
                phi.iter().zip(&hist).map(|(p, h)| p * h).sum::<f64>() + sigma * g.sample();
            hist.rotate_right(1);
            hist[0] = x;
            if t >= 1000 {
                out.push(x + mean);
            }
        }
        out
    }

    #[test]
    fn recovers_known_ar3_coefficients() {
        for (phi, sigma, mean, seed) in [
            ([0.5, -0.3, 0.1], 0.3, 0.02, 7u64),
            ([1.2, -0.5, 0.1], 0.01, -1.5, 11u64),
        ] {
            let x = simulate(&phi, sigma, mean, 100_000, seed);
            let fit = fit_ar3(&x).unwrap();
            for i in 0..3 {
                assert!(
                    (fit.m[i] + phi[i]).abs() < 0.02,
                    "m {:?} vs phi {phi:?}",
                    fit.m
                );
            }
            let var = sigma * sigma;
            assert!(
                (fit.noise_var - var).abs() < 0.05 * var,
                "noise_var {} vs {var}",
                fit.noise_var
            );
            assert!(
                (fit.mean - mean).abs() < 0.05 * (fit.variance.sqrt()),
                "{}",
                fit.mean
            );
        }
    }

    #[test]
    fn ar1_known_answer_by_hand() {
        // x = 1..10: mean 5.5, r0 = 82.5/10 = 8.25, r1 = 57.75/10 = 5.775,
        // phi = r1/r0 = 0.7, sigma^2 = r0 - phi r1 = 4.2075.
        let x: Vec<f64> = (1..=10).map(f64::from).collect();
        let fit = fit_ar(&x, 1).unwrap();
        assert!((fit.mean - 5.5).abs() < 1e-12);
        assert!((fit.variance - 8.25).abs() < 1e-12);
        assert!((fit.phi[0] - 0.7).abs() < 1e-12, "{:?}", fit.phi);
        assert!((fit.m[0] + 0.7).abs() < 1e-12);
        assert!((fit.noise_var - 4.2075).abs() < 1e-12);
    }

    #[test]
    fn levinson_solves_the_toeplitz_system() {
        // Check phi against the Yule-Walker equations built independently.
        let x = simulate(&[0.6, 0.2, -0.25, 0.1, 0.05], 1.0, 0.0, 2000, 3);
        let p = 5;
        let fit = fit_ar(&x, p).unwrap();
        let n = x.len() as f64;
        let mean = x.iter().sum::<f64>() / n;
        let r: Vec<f64> = (0..=p)
            .map(|k| {
                (k..x.len())
                    .map(|t| (x[t] - mean) * (x[t - k] - mean))
                    .sum::<f64>()
                    / n
            })
            .collect();
        for i in 0..p {
            let lhs: f64 = (0..p).map(|j| r[i.abs_diff(j)] * fit.phi[j]).sum();
            assert!(
                (lhs - r[i + 1]).abs() < 1e-10 * r[0],
                "row {i}: {lhs} vs {}",
                r[i + 1]
            );
        }
        let nv = r[0] - (0..p).map(|j| fit.phi[j] * r[j + 1]).sum::<f64>();
        assert!((fit.noise_var - nv).abs() < 1e-10 * r[0]);
    }

    #[test]
    fn white_noise_fits_near_zero() {
        // Bias plus white noise (erratum 19): m ~ 0, noise_var ~ variance.
        let x: Vec<f64> = simulate(&[0.0], 0.05, 0.3, 50_000, 5);
        let fit = fit_ar3(&x).unwrap();
        assert!(fit.m.iter().all(|m| m.abs() < 0.02), "{:?}", fit.m);
        assert!((fit.noise_var / fit.variance - 1.0).abs() < 1e-3);
    }

    #[test]
    fn refuses_bad_series() {
        assert_eq!(
            fit_ar3(&[1.0; 29]),
            Err(ArFitError::TooShort {
                len: 29,
                order: 3,
                min_len: 30
            })
        );
        assert!(matches!(
            fit_ar3(&[2.5; 40]),
            Err(ArFitError::ZeroVariance { .. })
        ));
        let mut x: Vec<f64> = (0..40).map(|i| f64::from(i % 7)).collect();
        x[13] = f64::NAN;
        let e = fit_ar3(&x).unwrap_err();
        assert!(matches!(e, ArFitError::NonFinite { index: 13, .. }));
        assert_eq!(e.to_string(), "AR fit series[13] is not finite: NaN");
        assert_eq!(fit_ar(&x, 0), Err(ArFitError::Order(0)));
        assert_eq!(fit_ar(&x, 65), Err(ArFitError::Order(65)));
        let big = vec![
            1e200, -1e200, 1e200, -3e200, 0.0, 1e200, 1e200, -1e200, 1e200, 0.0,
        ];
        assert!(matches!(fit_ar(&big, 1), Err(ArFitError::Overflow { .. })));
    }
}
