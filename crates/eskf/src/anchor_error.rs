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
//! the anchors' states (the radio's height below enters them too).
//!
//! # Without a lasting part
//!
//! With `tdoa_anchor_highpass_s` = `T` above 0, each anchor's part is the
//! Gauss-Markov state `x` less its own running mean `m` over `T` (`ṁ = (x -
//! m) / T`): `β = x - m` has no power at zero frequency, so it explains an
//! anchor's shared error over fractions of a second and leaves what lasts
//! (a pair's bias along its geometry, the site calibration's business) to
//! be weighted as every other difference error. A plain Gauss-Markov state
//! also carries the lasting part, and so weights the differences over the
//! long run by the anchors' structure; on flights whose anchors read off
//! by tenths of a metre for the whole flight that moves the filter's mean
//! position away from the fixes' (docs/REAL_FLIGHTS.md). Per anchor the
//! pair `(x, m)` moves by the exact transition of `ẋ = -x / τ`, `ṁ = (x -
//! m) / T` over each step; its stationary covariance `S` (`var x = σ²`,
//! `cov(x, m) = var m = σ² τ / (τ + T)`, so `var β = σ² T / (τ + T)`) is a
//! new anchor's prior, and the process noise `S - M S Mᵀ` keeps it
//! stationary. With `T` = 0, `m` stays zero and `β = x`.
//!
//! # The radio's height
//!
//! One more state in the block, off until [`AnchorErrors::enable_height`]
//! (a filter that measures its height another way, a range finder, turns
//! it on): the height at which the radio places the tag above the
//! vehicle's, a first-order Gauss-Markov state, entering every difference
//! along its vertical gradient. A range bias proportional to the sine of
//! an anchor's elevation (an antenna's pattern, the anchors' survey) is a
//! vertical shift of the radio's position, exactly, so with the height
//! known the radio's own height error goes here instead of into the
//! horizontal.
//!
//! The augmented covariance is kept in blocks (the 15 x 15 core, the
//! 15 x K cross-covariance with the anchors' errors, their K x K block), so
//! the core's structured propagation stays as it is and the anchors cost a
//! 15 x K product per step; the anchors' transition is applied pair by
//! pair, never as a K x K product. Anchors are told apart by their positions
//! (bit-exact); `ANCHOR_SLOTS` of them hold a state at a time, and an
//! anchor heard when all are taken replaces the one heard least recently
//! (its state starts again from the prior).

use nalgebra::{SMatrix, SVector};

use crate::eskf::{StateVector, N_STATES};

/// Number of anchors that hold a state at a time.
pub const ANCHOR_SLOTS: usize = 8;
/// Number of error states: per anchor slot `x` (index `i`), then its mean
/// `m` (index `i + ANCHOR_SLOTS`).
pub(crate) const ERROR_STATES: usize = 2 * ANCHOR_SLOTS + 1;
/// The anchors' states, `x` then `m`.
const ANCHOR_STATES: usize = 2 * ANCHOR_SLOTS;
/// Index of the radio's height error.
pub(crate) const HEIGHT: usize = ANCHOR_STATES;

/// The anchors' errors.
pub(crate) type ErrorVector = SVector<f64, ERROR_STATES>;
/// Cross-covariance of the 15 error states with the anchors' errors.
pub(crate) type CrossCov = SMatrix<f64, N_STATES, ERROR_STATES>;
/// Covariance of the anchors' errors.
pub(crate) type ErrorCov = SMatrix<f64, ERROR_STATES, ERROR_STATES>;

/// The anchors' error states and their covariance blocks.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct AnchorErrors {
    /// Stationary sigma, m (0: off).
    sigma_m: f64,
    /// Correlation time, s.
    tau_s: f64,
    /// Time constant of the running mean removed, s (0: none).
    hp_s: f64,
    /// The radio's height state: stationary sigma (m) and correlation
    /// time (s); sigma 0: off.
    height: (f64, f64),
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
    /// No anchor seen yet; `sigma_m` 0 turns the states off, `hp_s` 0
    /// keeps the lasting part.
    pub(crate) fn new(sigma_m: f64, tau_s: f64, hp_s: f64) -> Self {
        Self {
            sigma_m,
            tau_s,
            hp_s,
            height: (0.0, 0.0),
            keys: [None; ANCHOR_SLOTS],
            last_used_s: [f64::NEG_INFINITY; ANCHOR_SLOTS],
            b: ErrorVector::zeros(),
            pxb: CrossCov::zeros(),
            pbb: ErrorCov::zeros(),
        }
    }

    /// Whether the states are in use.
    pub(crate) fn enabled(&self) -> bool {
        self.sigma_m > 0.0 || self.height_on()
    }

    /// Whether the radio's height state is in use.
    pub(crate) fn height_on(&self) -> bool {
        self.height.0 > 0.0
    }

    /// Turns the radio's height state on, at zero with its stationary
    /// sigma `sigma_m` and correlation time `corr_time_s`, uncorrelated
    /// with every other state; nothing when it is on already.
    pub(crate) fn enable_height(&mut self, sigma_m: f64, corr_time_s: f64) {
        if self.height_on() {
            return;
        }
        self.height = (sigma_m, corr_time_s);
        self.pxb.column_mut(HEIGHT).fill(0.0);
        self.pbb.column_mut(HEIGHT).fill(0.0);
        self.pbb.row_mut(HEIGHT).fill(0.0);
        self.b[HEIGHT] = 0.0;
        self.pbb[(HEIGHT, HEIGHT)] = sigma_m * sigma_m;
    }

    /// Sets the radio's height state to `value_m` with sigma
    /// `value_sigma_m`, uncorrelated with every other state (a resumed
    /// one), turning it on first with `sigma_m` and `corr_time_s`.
    pub(crate) fn set_height(
        &mut self,
        sigma_m: f64,
        corr_time_s: f64,
        value_m: f64,
        value_sigma_m: f64,
    ) {
        self.enable_height(sigma_m, corr_time_s);
        self.pxb.column_mut(HEIGHT).fill(0.0);
        self.pbb.column_mut(HEIGHT).fill(0.0);
        self.pbb.row_mut(HEIGHT).fill(0.0);
        self.b[HEIGHT] = value_m;
        self.pbb[(HEIGHT, HEIGHT)] = value_sigma_m * value_sigma_m;
    }

    /// The radio's height error and its sigma, m, while the state is on.
    pub(crate) fn height_error(&self) -> Option<(f64, f64)> {
        self.height_on()
            .then(|| (self.b[HEIGHT], self.pbb[(HEIGHT, HEIGHT)].max(0.0).sqrt()))
    }

    /// The stationary `(var x, cov(x, m) = var m)` of a slot's pair.
    fn stationary(&self) -> (f64, f64) {
        let v = self.sigma_m * self.sigma_m;
        let c = if self.hp_s > 0.0 {
            v * self.tau_s / (self.tau_s + self.hp_s)
        } else {
            0.0
        };
        (v, c)
    }

    /// The slot of an anchor measured at `now_s`. An anchor not seen
    /// before takes a free slot, else the least recently measured one's
    /// (never one measured at `now_s`: then `None`, no state this time),
    /// with a zero error at its stationary covariance, uncorrelated with
    /// every other state.
    pub(crate) fn slot(&mut self, anchor_m: &[f64; 3], now_s: f64) -> Option<usize> {
        if self.sigma_m <= 0.0 {
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
                let j = i + ANCHOR_SLOTS;
                for k in [i, j] {
                    self.pxb.column_mut(k).fill(0.0);
                    self.pbb.column_mut(k).fill(0.0);
                    self.pbb.row_mut(k).fill(0.0);
                    self.b[k] = 0.0;
                }
                let (v, c) = self.stationary();
                self.pbb[(i, i)] = v;
                self.pbb[(i, j)] = c;
                self.pbb[(j, i)] = c;
                self.pbb[(j, j)] = c;
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

    /// Propagates over `dt_s`: `P_xb <- Φ P_xb Mᵀ`, `P_bb <- M P_bb Mᵀ + Q`
    /// on the used slots, `b <- M b`, with `M` each slot's transition of
    /// `(x, m)` (`x` decays by `φ = exp(-dt / tau)`; module doc) and `Φ P_xb
    /// = P_xb + dt F P_xb` (`f_times` applies `F`).
    pub(crate) fn predict(&mut self, dt_s: f64, f_times: impl Fn(&CrossCov) -> CrossCov) {
        if !self.enabled() {
            return;
        }
        let phi = if self.tau_s > 0.0 {
            (-dt_s / self.tau_s).exp()
        } else {
            1.0
        };
        // m's transition: itself by phi2, from x by c21 (the response of
        // the running mean to a unit x decaying with tau).
        let (phi2, c21) = if self.hp_s > 0.0 && self.tau_s > 0.0 {
            let p2 = (-dt_s / self.hp_s).exp();
            let r = 1.0 - self.hp_s / self.tau_s;
            let c21 = if r.abs() > 1e-9 {
                (phi - p2) / r
            } else {
                dt_s / self.hp_s * phi
            };
            (p2, c21)
        } else {
            (0.0, 0.0)
        };
        let fp = f_times(&self.pxb);
        self.pxb += fp * dt_s;
        let n = ANCHOR_SLOTS;
        if self.hp_s > 0.0 {
            // Each slot's (x, m) by M, as columns of P_xb, P_bb's rows
            // (columns of its transpose) and columns, and the estimates.
            let t = (phi, c21, phi2);
            mix_columns(&mut self.pxb, t);
            self.pbb.transpose_mut();
            mix_columns(&mut self.pbb, t);
            self.pbb.transpose_mut();
            mix_columns(&mut self.pbb, t);
            let mut b = self.b.transpose();
            mix_columns(&mut b, t);
            self.b = b.transpose();
        } else {
            // m stays zero: x decays alone.
            self.pxb
                .fixed_columns_mut::<ANCHOR_STATES>(0)
                .scale_mut(phi);
            self.pbb
                .fixed_columns_mut::<ANCHOR_STATES>(0)
                .scale_mut(phi);
            self.pbb.fixed_rows_mut::<ANCHOR_STATES>(0).scale_mut(phi);
            self.b.fixed_rows_mut::<ANCHOR_STATES>(0).scale_mut(phi);
        }
        let (hs, ht) = self.height;
        if hs > 0.0 {
            let ph = if ht > 0.0 { (-dt_s / ht).exp() } else { 1.0 };
            self.pxb.column_mut(HEIGHT).scale_mut(ph);
            self.pbb.column_mut(HEIGHT).scale_mut(ph);
            self.pbb.row_mut(HEIGHT).scale_mut(ph);
            self.b[HEIGHT] *= ph;
            self.pbb[(HEIGHT, HEIGHT)] += hs * hs * (1.0 - ph * ph);
        }
        // Q = S - M S M^T: a slot's pair at its stationary S stays there.
        let (v, c) = self.stationary();
        let q11 = v - phi * phi * v;
        let q21 = c - phi * (c21 * v + phi2 * c);
        let q22 = c - (c21 * c21 * v + 2.0 * c21 * phi2 * c + phi2 * phi2 * c);
        for (i, k) in self.keys.iter().enumerate() {
            if k.is_some() {
                let j = i + n;
                self.pbb[(i, i)] += q11;
                self.pbb[(i, j)] += q21;
                self.pbb[(j, i)] += q21;
                self.pbb[(j, j)] += q22;
            }
        }
    }

    /// The anchors' part of a difference's row: `β = x - m` of `plus`
    /// counted `+1`, of `minus` `-1`.
    pub(crate) fn row(plus: Option<usize>, minus: Option<usize>) -> ErrorVector {
        let mut h = ErrorVector::zeros();
        if let Some(i) = plus {
            h[i] += 1.0;
            h[i + ANCHOR_SLOTS] -= 1.0;
        }
        if let Some(i) = minus {
            h[i] -= 1.0;
            h[i + ANCHOR_SLOTS] += 1.0;
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
            let j = i + ANCHOR_SLOTS;
            k.map(|bits| {
                (
                    bits.map(f64::from_bits),
                    self.b[i] - self.b[j],
                    (self.pbb[(i, i)] - 2.0 * self.pbb[(i, j)] + self.pbb[(j, j)])
                        .max(0.0)
                        .sqrt(),
                )
            })
        })
    }

    /// Forgets every anchor (after a reset of the filter).
    pub(crate) fn clear(&mut self) {
        *self = Self::new(self.sigma_m, self.tau_s, self.hp_s);
        // The radio's height state, too: the next height turns it on again.
    }
}

/// Each slot's pair of columns `(x, m)` of `a` by the transition `(φ, c21,
/// φ2)`: `m <- c21 x + φ2 m`, then `x <- φ x`.
fn mix_columns<const R: usize>(
    a: &mut SMatrix<f64, R, ERROR_STATES>,
    (phi, c21, phi2): (f64, f64, f64),
) {
    for i in 0..ANCHOR_SLOTS {
        let j = i + ANCHOR_SLOTS;
        let ci = a.column(i).clone_owned();
        let cj = a.column(j).clone_owned();
        a.set_column(j, &(ci * c21 + cj * phi2));
        a.set_column(i, &(ci * phi));
    }
}
