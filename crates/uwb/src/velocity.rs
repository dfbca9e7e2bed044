//! UWB velocity from successive position fixes: least-squares slope over a
//! sliding window, with its covariance and validity.
//!
//! ```
//! use insuwb_uwb::velocity::{VelocityConfig, VelocityEstimator};
//! let mut est = VelocityEstimator::new(VelocityConfig::default()).unwrap();
//! let cov = [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]];
//! let mut last = None;
//! for k in 0..10u64 {
//!     let t = k as f64 * 0.1;
//!     last = Some(est.push(k * 100_000_000, [0.5 * t, -0.2 * t, 1.0], cov).unwrap());
//! }
//! let v = last.unwrap();
//! assert!(v.valid && (v.vel_mps[0] - 0.5).abs() < 1e-9 && (v.vel_mps[1] + 0.2).abs() < 1e-9);
//! ```
//!
//! # Estimator
//!
//! The window holds the last [`VelocityConfig::window_len`] fixes no older
//! than [`VelocityConfig::max_span_s`] before the newest. Per axis, the
//! ordinary least-squares slope of position on time is
//! `v = sum w_i p_i` with `w_i = (t_i - tbar) / S`, `S = sum (t_i - tbar)^2`,
//! and, the fixes' errors being taken as independent with covariances `P_i`,
//! `Cov(v) = sum w_i^2 P_i` (with equal variances `sigma_p^2 / S` per axis).
//! The slope is the mean velocity over the window: it refers to `tbar`, half
//! a window span before the newest fix ([`VelocityEstimate::mean_time_ns`]).
//! An estimate is valid when the window holds at least
//! [`VelocityConfig::min_fixes`] fixes spanning at least
//! [`VelocityConfig::min_span_s`].
//!
//! # Correlation, and what it means for the filter's R
//!
//! Successive estimates share all but one fix. For equally spaced fixes of
//! equal variance, windows of `N` fixes sliding by one give estimates with
//! correlation `rho = sum_{j=1}^{N-1} c_j c_{j-1} / sum_j c_j^2`,
//! `c_j = j - (N-1)/2` ([`successive_correlation`]): 0 for N = 3, 0.25 for
//! N = 4, 0.7 for N = 10. Each velocity is also correlated with the position
//! fix of the same epoch (`Cov(v, p_k) = w_k P_k`) and UWB fix errors
//! themselves are correlated in time (per-pair biases, UTIL README), so
//! `Cov(v)` is optimistic. A Kalman filter that takes every estimate as an
//! independent measurement with `R_v = Cov(v)` over-weights velocity by up
//! to `(1 + rho) / (1 - rho)` (about 5.7 for N = 10). Remedies: inflate
//! `R_v` by that factor, or use one velocity per `N` fixes (disjoint
//! windows), or fuse positions only and let the filter derive velocity.
//! READING.md erratum 17 asks for this noise to be modelled.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Most fixes a window may be configured to hold (bounds the allocation).
pub const MAX_WINDOW_LEN: usize = 1024;

/// Settings of the velocity regression.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VelocityConfig {
    /// Most fixes in the regression window (N). Default 10: at 10 fixes/s a
    /// 0.9 s window gives `sigma_v = sigma_p / 0.91 s` (0.08 m/s for
    /// 0.07 m fixes; engineering choice trading lag for noise).
    pub window_len: usize,
    /// Fewest fixes for a valid estimate (>= 2). Default 4.
    pub min_fixes: usize,
    /// Shortest window span for a valid estimate, s. Default 0.3 (three
    /// 0.1 s fix periods).
    pub min_span_s: f64,
    /// Fixes older than this before the newest leave the window, s.
    /// Default 1.0 (ten 0.1 s fix periods; bounds the lag after a gap).
    pub max_span_s: f64,
}

impl Default for VelocityConfig {
    fn default() -> Self {
        Self {
            window_len: 10,
            min_fixes: 4,
            min_span_s: 0.3,
            max_span_s: 1.0,
        }
    }
}

/// A [`VelocityConfig`] value out of range (keys relative to the UWB fix table).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum VelocityConfigError {
    /// A setting is outside its valid range.
    #[error("{key} must be {requirement}, got {value}")]
    OutOfRange {
        /// Configuration key, e.g. `velocity.window_len`.
        key: &'static str,
        /// What the value must satisfy.
        requirement: &'static str,
        /// The offending value.
        value: f64,
    },
}

impl VelocityConfig {
    /// Checks every setting, naming the first offending key.
    ///
    /// # Errors
    /// [`VelocityConfigError::OutOfRange`] for a value outside its range.
    pub fn validate(&self) -> Result<(), VelocityConfigError> {
        let fail = |key, requirement, value| {
            Err(VelocityConfigError::OutOfRange {
                key,
                requirement,
                value,
            })
        };
        if !(2..=MAX_WINDOW_LEN).contains(&self.window_len) {
            return fail("velocity.window_len", "in 2..=1024", self.window_len as f64);
        }
        if !(2..=self.window_len).contains(&self.min_fixes) {
            return fail(
                "velocity.min_fixes",
                "in 2..=velocity.window_len",
                self.min_fixes as f64,
            );
        }
        if !(self.max_span_s.is_finite() && self.max_span_s > 0.0) {
            return fail("velocity.max_span_s", "finite and > 0", self.max_span_s);
        }
        if !(self.min_span_s.is_finite()
            && self.min_span_s >= 0.0
            && self.min_span_s <= self.max_span_s)
        {
            return fail(
                "velocity.min_span_s",
                "finite, >= 0 and <= velocity.max_span_s",
                self.min_span_s,
            );
        }
        Ok(())
    }
}

/// Why a fix was not taken into the window.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum VelocityError {
    /// A position or covariance entry is NaN or infinite.
    #[error("fix {what} is not finite ({value})")]
    NonFinite {
        /// `pos_m` or `cov_m2`.
        what: &'static str,
        /// The offending value.
        value: f64,
    },
    /// The fix is older than the newest one in the window.
    #[error("fix time {time_ns} ns is before the newest fix {last_ns} ns")]
    TimeBackwards {
        /// Time of the rejected fix, ns.
        time_ns: u64,
        /// Time of the newest fix, ns.
        last_ns: u64,
    },
}

/// A velocity estimate from the current window.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct VelocityEstimate {
    /// Velocity, ENU, m/s (zero when `valid` is false).
    pub vel_mps: [f64; 3],
    /// Velocity covariance `sum w_i^2 P_i`, (m/s)^2, row-major (zero when invalid).
    pub cov_mps2: [[f64; 3]; 3],
    /// The window meets `min_fixes` and `min_span_s`.
    pub valid: bool,
    /// Fixes in the window.
    pub n_fixes: usize,
    /// Time from the oldest to the newest fix in the window, s.
    pub span_s: f64,
    /// Mean time of the window's fixes: the instant the slope refers to, ns.
    pub mean_time_ns: u64,
}

#[derive(Debug, Clone, Copy)]
struct Entry {
    time_ns: u64,
    pos_m: [f64; 3],
    cov_m2: [[f64; 3]; 3],
}

/// Sliding-window regression of position on time (allocates once, in `new`).
#[derive(Debug, Clone)]
pub struct VelocityEstimator {
    cfg: VelocityConfig,
    window: VecDeque<Entry>,
}

impl VelocityEstimator {
    /// An empty estimator.
    ///
    /// # Errors
    /// The configuration's validation error.
    pub fn new(cfg: VelocityConfig) -> Result<Self, VelocityConfigError> {
        cfg.validate()?;
        let window = VecDeque::with_capacity(cfg.window_len);
        Ok(Self { cfg, window })
    }

    /// The settings in use.
    #[must_use]
    pub fn config(&self) -> &VelocityConfig {
        &self.cfg
    }

    /// Fixes in the window.
    #[must_use]
    pub fn len(&self) -> usize {
        self.window.len()
    }

    /// The window is empty.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.window.is_empty()
    }

    /// Empties the window.
    pub fn reset(&mut self) {
        self.window.clear();
    }

    /// Adds a fix (time ns, position m, covariance m^2) and returns the
    /// estimate of the updated window. A fix at the same time as the newest
    /// replaces it.
    ///
    /// # Errors
    /// A non-finite input or a time before the newest fix; the window is unchanged.
    pub fn push(
        &mut self,
        time_ns: u64,
        pos_m: [f64; 3],
        cov_m2: [[f64; 3]; 3],
    ) -> Result<VelocityEstimate, VelocityError> {
        if let Some(&value) = pos_m.iter().find(|v| !v.is_finite()) {
            return Err(VelocityError::NonFinite {
                what: "pos_m",
                value,
            });
        }
        if let Some(&value) = cov_m2.iter().flatten().find(|v| !v.is_finite()) {
            return Err(VelocityError::NonFinite {
                what: "cov_m2",
                value,
            });
        }
        let entry = Entry {
            time_ns,
            pos_m,
            cov_m2,
        };
        match self.window.back_mut() {
            Some(last) if time_ns < last.time_ns => {
                return Err(VelocityError::TimeBackwards {
                    time_ns,
                    last_ns: last.time_ns,
                });
            }
            Some(last) if time_ns == last.time_ns => *last = entry,
            _ => {
                while self.window.len() >= self.cfg.window_len {
                    self.window.pop_front();
                }
                self.window.push_back(entry);
            }
        }
        let max_span_ns = (self.cfg.max_span_s * 1e9).round();
        while self
            .window
            .front()
            .is_some_and(|f| (time_ns - f.time_ns) as f64 > max_span_ns)
        {
            self.window.pop_front();
        }
        Ok(self.estimate())
    }

    /// The estimate of the current window.
    #[must_use]
    pub fn estimate(&self) -> VelocityEstimate {
        let (Some(first), Some(newest)) = (self.window.front(), self.window.back()) else {
            return VelocityEstimate::default();
        };
        let n = self.window.len();
        // Times relative to the newest fix, s (<= 0), for precision.
        let tau = |e: &Entry| -((newest.time_ns - e.time_ns) as f64) * 1e-9;
        let tbar = self.window.iter().map(tau).sum::<f64>() / n as f64;
        let stt: f64 = self.window.iter().map(|e| (tau(e) - tbar).powi(2)).sum();
        let span_s = (newest.time_ns - first.time_ns) as f64 * 1e-9;
        let mean_time_ns = newest.time_ns.saturating_sub((-tbar * 1e9).round() as u64);
        let mut out = VelocityEstimate {
            n_fixes: n,
            span_s,
            mean_time_ns,
            ..VelocityEstimate::default()
        };
        if !(n >= self.cfg.min_fixes && span_s >= self.cfg.min_span_s && stt > 0.0) {
            return out;
        }
        for e in &self.window {
            let w = (tau(e) - tbar) / stt;
            for ((v, p), p0) in out.vel_mps.iter_mut().zip(e.pos_m).zip(newest.pos_m) {
                *v += w * (p - p0);
            }
            for (row_out, row_in) in out.cov_mps2.iter_mut().zip(e.cov_m2) {
                for (c, x) in row_out.iter_mut().zip(row_in) {
                    *c += w * w * x;
                }
            }
        }
        out.valid = true;
        out
    }
}

/// Correlation between successive slope estimates of windows of `n` equally
/// spaced, equal-variance, independent fixes sliding by one fix (see the
/// module doc): `sum_{j=1}^{n-1} c_j c_{j-1} / sum_j c_j^2`, `c_j = j - (n-1)/2`.
/// Zero for `n < 2`.
#[must_use]
pub fn successive_correlation(n: usize) -> f64 {
    if n < 2 {
        return 0.0;
    }
    let c = |j: usize| j as f64 - (n as f64 - 1.0) / 2.0;
    let num: f64 = (1..n).map(|j| c(j) * c(j - 1)).sum();
    let den: f64 = (0..n).map(|j| c(j) * c(j)).sum();
    num / den
}
