//! Each anchor's part of the TDOA error as a first-order Gauss-Markov
//! state beside the 15 error states (`[fusion.eskf] tdoa_anchor_sigma_m`).
//!
//! A TDOA difference `|p - b| - |p - a|` is formed from the tag's receive
//! times of anchor `a`'s and anchor `b`'s packets, so a receive-time error of
//! one anchor's packets (its first path through the site's multipath, its
//! antenna's pattern) enters every difference that anchor is in. The
//! differences then read `+ β_b - β_a` on top of the geometry, each `β`
//! decaying towards zero with `tdoa_anchor_corr_time_s` at a stationary
//! sigma of `tdoa_anchor_sigma_m`. On the UTIL flights two differences with
//! one anchor in common co-vary by a third of their variance and two with
//! none do not (`tools/util_anchor_corr.py`). Two-way ranges do not use
//! these states.
//!
//! The augmented covariance is kept in blocks (the 15 x 15 core, the
//! 15 x K cross-covariance with the anchors' errors, their K x K block), so
//! the core's structured propagation stays as it is and the anchors cost a
//! 15 x K product per step. Anchors are told apart by their positions
//! (bit-exact); `ANCHOR_SLOTS` of them hold a state at a time, and an
//! anchor heard when all are taken replaces the one heard least recently
//! (its state starts again from the prior).

use nalgebra::{SMatrix, SVector};

use crate::eskf::{StateVector, N_STATES};

/// Number of anchors that hold a state at a time.
pub const ANCHOR_SLOTS: usize = 8;

/// The anchors' errors.
pub(crate) type ErrorVector = SVector<f64, ANCHOR_SLOTS>;
/// Cross-covariance of the 15 error states with the anchors' errors.
pub(crate) type CrossCov = SMatrix<f64, N_STATES, ANCHOR_SLOTS>;
/// Covariance of the anchors' errors.
pub(crate) type ErrorCov = SMatrix<f64, ANCHOR_SLOTS, ANCHOR_SLOTS>;

/// The anchors' error states and their covariance blocks.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct AnchorErrors {
    /// Stationary sigma, m (0: off).
    sigma_m: f64,
    /// Correlation time, s.
    tau_s: f64,
    /// Bit patterns of each slot's anchor position; `None`: free.
    keys: [Option<[u64; 3]>; ANCHOR_SLOTS],
    /// When each slot's anchor was last measured (filter time, s).
    last_used_s: [f64; ANCHOR_SLOTS],
    /// The estimates, m.
    pub(crate) b: ErrorVector,
    /// `P_xb`.
    pub(crate) pxb: CrossCov,
    /// `P_bb`.
    pub(crate) pbb: ErrorCov,
}

impl AnchorErrors {
    /// No anchor seen yet; `sigma_m` 0 turns the states off.
    pub(crate) fn new(sigma_m: f64, tau_s: f64) -> Self {
        Self {
            sigma_m,
            tau_s,
            keys: [None; ANCHOR_SLOTS],
            last_used_s: [f64::NEG_INFINITY; ANCHOR_SLOTS],
            b: ErrorVector::zeros(),
            pxb: CrossCov::zeros(),
            pbb: ErrorCov::zeros(),
        }
    }

    /// Whether the states are in use.
    pub(crate) fn enabled(&self) -> bool {
        self.sigma_m > 0.0
    }

    /// The slot of an anchor measured at `now_s`. An anchor not seen
    /// before takes a free slot, else the least recently measured one's
    /// (never one measured at `now_s`: then `None`, no state this time),
    /// with a zero error of the stationary variance, uncorrelated.
    pub(crate) fn slot(&mut self, anchor_m: &[f64; 3], now_s: f64) -> Option<usize> {
        if !self.enabled() {
            return None;
        }
        let key = anchor_m.map(f64::to_bits);
        let found = self.keys.iter().position(|k| *k == Some(key));
        let i = match found {
            Some(i) => i,
            None => {
                let i = self.keys.iter().position(Option::is_none).or_else(|| {
                    // Never a slot measured at this instant (the other
                    // anchor of the same difference).
                    (0..ANCHOR_SLOTS)
                        .filter(|&a| self.last_used_s.get(a).is_some_and(|t| *t < now_s))
                        .min_by(|&a, &b| {
                            let ta = self.last_used_s.get(a).copied().unwrap_or(0.0);
                            let tb = self.last_used_s.get(b).copied().unwrap_or(0.0);
                            ta.total_cmp(&tb)
                        })
                })?;
                self.pxb.column_mut(i).fill(0.0);
                self.pbb.column_mut(i).fill(0.0);
                self.pbb.row_mut(i).fill(0.0);
                self.pbb[(i, i)] = self.sigma_m * self.sigma_m;
                self.b[i] = 0.0;
                if let Some(k) = self.keys.get_mut(i) {
                    *k = Some(key);
                }
                i
            }
        };
        if let Some(t) = self.last_used_s.get_mut(i) {
            *t = now_s;
        }
        Some(i)
    }

    /// Propagates over `dt_s`: `P_xb <- Φ P_xb φ`, `P_bb <- φ P_bb φ + (1 -
    /// φ^2) sigma^2` on the used slots, `b <- φ b`, with `φ = exp(-dt /
    /// tau)` and `Φ P_xb = P_xb + dt F P_xb` (`f_times` applies `F`).
    pub(crate) fn predict(&mut self, dt_s: f64, f_times: impl Fn(&CrossCov) -> CrossCov) {
        if !self.enabled() {
            return;
        }
        let phi = if self.tau_s > 0.0 {
            (-dt_s / self.tau_s).exp()
        } else {
            1.0
        };
        let fp = f_times(&self.pxb);
        self.pxb = (self.pxb + fp * dt_s) * phi;
        self.pbb *= phi * phi;
        let q = (1.0 - phi * phi) * self.sigma_m * self.sigma_m;
        for (i, k) in self.keys.iter().enumerate() {
            if k.is_some() {
                self.pbb[(i, i)] += q;
            }
        }
        self.b *= phi;
    }

    /// The anchors' part of a difference's row: `+1` at `plus`, `-1` at
    /// `minus`.
    pub(crate) fn row(plus: Option<usize>, minus: Option<usize>) -> ErrorVector {
        let mut h = ErrorVector::zeros();
        if let Some(i) = plus {
            h[i] += 1.0;
        }
        if let Some(i) = minus {
            h[i] -= 1.0;
        }
        h
    }

    /// A measurement's terms from the anchors, for a row `(h, h_b)`: `P_xb
    /// h_b` (added to the core's `P_xx h`), `P_bx h + P_bb h_b` (the
    /// anchors' part of `P h`) and `h_b . b` (what the estimates add to the
    /// prediction); zeros while the states are off.
    pub(crate) fn terms(
        &self,
        h: &StateVector,
        hb: &ErrorVector,
    ) -> (StateVector, ErrorVector, f64) {
        if !self.enabled() {
            return (StateVector::zeros(), ErrorVector::zeros(), 0.0);
        }
        (
            self.pxb * hb,
            self.pxb.transpose() * h + self.pbb * hb,
            hb.dot(&self.b),
        )
    }

    /// The scalar update's part on the anchors, given the core's gain `kx`,
    /// the anchors' gain `kb`, the core's `cx = P_xx h + P_xb h_b`, the anchors'
    /// `cb` and `s`: `b += kb v`, Joseph form on `P_xb` and `P_bb` (valid
    /// for any gain).
    pub(crate) fn update(
        &mut self,
        kx: &StateVector,
        kb: &ErrorVector,
        cx: &StateVector,
        cb: &ErrorVector,
        s: f64,
        v: f64,
    ) {
        self.b += kb * v;
        self.pxb += kx * kb.transpose() * s - kx * cb.transpose() - cx * kb.transpose();
        let kcb = kb * cb.transpose();
        self.pbb += kb * kb.transpose() * s - kcb - kcb.transpose();
        self.pbb = (self.pbb + self.pbb.transpose()) * 0.5;
    }

    /// Each used slot's anchor position, error estimate and sigma.
    pub(crate) fn states(&self) -> impl Iterator<Item = ([f64; 3], f64, f64)> + '_ {
        self.keys.iter().enumerate().filter_map(|(i, k)| {
            k.map(|bits| {
                (
                    bits.map(f64::from_bits),
                    self.b[i],
                    self.pbb[(i, i)].max(0.0).sqrt(),
                )
            })
        })
    }

    /// Forgets every anchor (after a reset of the filter).
    pub(crate) fn clear(&mut self) {
        *self = Self::new(self.sigma_m, self.tau_s);
    }
}
