//! Fix builder: groups a stream of [`UwbTdoa`] measurements into epochs,
//! multilaterates each epoch into a [`UwbFix`] and attaches the regression
//! velocity.
//!
//! ```
//! use insuwb_msg::{Header, UwbTdoa};
//! use insuwb_uwb::fix::{FixBuilder, FixConfig, FixMode};
//! let cfg = FixConfig { mode: FixMode::Mode2d { height_m: 0.0 }, ..FixConfig::default() };
//! let mut builder = FixBuilder::new(cfg).unwrap();
//! let anchors = [[-5.0, -5.0, 0.0], [5.0, -5.0, 0.0], [-5.0, 5.0, 0.0], [5.0, 5.0, 0.0]];
//! let p = [1.0, 2.0, 0.0];
//! let range = |a: [f64; 3]| ((p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2)).sqrt();
//! let mut fixes = Vec::new();
//! for b in 1..4 {
//!     let m = UwbTdoa {
//!         header: Header::new(b as u64, 50_000_000),
//!         anchor_a: 0,
//!         anchor_b: b as u32,
//!         diff_m: range(anchors[b]) - range(anchors[0]),
//!         anchor_a_pos_m: anchors[0],
//!         anchor_b_pos_m: anchors[b],
//!     };
//!     fixes.extend(builder.push(&m).unwrap());
//! }
//! fixes.extend(builder.flush());
//! assert_eq!(fixes.len(), 1);
//! assert!((fixes[0].pos_m[0] - 1.0).abs() < 1e-9);
//! assert_eq!(fixes[0].header.meas_time_ns, 50_000_000);
//! ```
//!
//! # Epochs
//!
//! With `P` = [`FixConfig::period_s`] in ns, epoch `k` covers measurement
//! times in `((k-1) P, k P]` on the absolute ns grid (`k = ceil(t / P)`).
//! Within an epoch the latest measurement of each unordered anchor pair is
//! kept; `(a, b)` and `(b, a)` are the same pair with the sign flipped. An
//! epoch closes when
//! 1. a measurement of a later epoch arrives (it then opens the next one),
//! 2. a measurement carries [`UwbTdoa::FLAG_EPOCH_END`], or
//! 3. the caller calls [`FixBuilder::flush`].
//!
//! Measurements of the same epoch window that arrive after a flag or flush
//! closed it open a fresh group for that window and give a fix of their own
//! (a flagged group is a complete set: with groups faster than `P` every
//! flagged group gives a fix). The output is a function of the measurement
//! sequence and the flush points only: pushing in chunks changes nothing,
//! and a flush between the last measurement of one epoch and the first of
//! the next changes nothing either.
//!
//! # Fixes
//!
//! A closed epoch with at least [`FixConfig::min_pairs`] pairs is solved
//! ([`crate::solve`]) with the previous fix as the seed; when that attempt
//! fails the solver re-starts from the closed form and the anchor centroid
//! ([`FixStats::reseeded`] counts those). The fix's `header.meas_time_ns` is
//! the time of the latest measurement used (all measurements are taken as
//! simultaneous: at 1 m/s and 0.1 s epochs that smears the fix by up to
//! 0.1 m, so prefer flagged simultaneous groups or short periods for fast
//! motion); `header.seq` counts fixes from 0; `n_meas` is the number of pairs
//! used; `FLAG_2D` marks 2D fixes and `FLAG_VEL_VALID` a valid regression
//! velocity ([`crate::velocity`]). Epochs without a fix are counted per reason
//! in [`FixStats`], and the last reason is kept ([`FixBuilder::last_skip`]).
//! Measurements with a non-finite value, equal anchor ids, a difference
//! longer than the distance between its anchors (impossible), a time before
//! the previous accepted measurement, or no room left in the epoch's pair
//! table are dropped, counted, and reported as a [`PushError`]; the builder
//! stays usable after any error. The value checks are the ones every reader
//! of a measurement shares ([`insuwb_msg::check::tdoa_values`]), applied
//! after the site calibration; the drivers and `insuwb eval` pass every
//! measurement through [`insuwb_msg::check::TdoaGate`] before the builder,
//! so there only the calibration's correction or a full pair table makes it
//! refuse one. With [`FixConfig::average_pairs`] an epoch is solved from
//! each pair's mean, weighted by its count.
//!
//! # Ranges
//!
//! Two-way ranges ([`UwbRange`], [`FixBuilder::push_range`]) are grouped
//! into the same epochs, one entry per anchor (the latest range, or with
//! [`FixConfig::average_pairs`] the mean of its ranges in the epoch,
//! weighted `range_sigma_m / sqrt(n)`), and solved by [`crate::range`];
//! `min_pairs` is then the fewest anchors, `n_meas` the anchors used. A
//! builder takes one kind: an epoch that holds ranges is solved from its
//! ranges (a robot's UWB is either TDOA or TWR). The value checks are
//! [`insuwb_msg::check::range_values`]; the site calibration applies to
//! TDOA only.
//!
//! Every range of a tag carries its antenna delay, one common offset. With
//! [`FixConfig::range_offset_tau_s`] > 0 the builder estimates it: each
//! epoch with two anchors more than the fix's unknowns is also solved for
//! position and offset together ([`crate::range::solve_ranges_with_offset`]),
//! and the offsets so found are averaged, each weighted by its inverse
//! variance, older epochs forgotten with that time constant. Ranges are
//! corrected by the average on [`FixBuilder::push_range`] (before the
//! first estimate they pass unchanged) and flagged
//! [`UwbRange::FLAG_OFFSET_REMOVED`]; [`FixBuilder::correct_range`] gives a
//! range as `push_range` uses it, for callers that forward it (to the tight
//! filter, onto a topic).
//!
//! # Site calibration
//!
//! With a [`SiteCalibration`] ([`FixBuilder::with_calibration`]) every
//! measurement is corrected on [`FixBuilder::push`] by the bias its pair
//! has at the previous fix's position (before the first fix, and after a
//! [`FixBuilder::reset`], the pair's constant), and flagged
//! [`UwbTdoa::FLAG_CALIBRATED`]; a flagged measurement is used as it is.
//! [`FixBuilder::calibrate`] gives the measurement as `push` would use it:
//! callers that forward the measurement too (to the tight filter, onto a
//! topic) forward that one, then push it.

use insuwb_msg::check::{self, InvalidRange, InvalidTdoa};
use insuwb_msg::{Header, UwbFix, UwbRange, UwbTdoa};
use serde::{Deserialize, Serialize};

use std::sync::Arc;

use crate::calibration::SiteCalibration;
use crate::range::{self as ranging, RangeObs};
use crate::solve::{self, Seed, SolveError, SolverConfig, SolverConfigError, TdoaObs};
use crate::velocity::{VelocityConfig, VelocityConfigError, VelocityEstimator};

/// Largest [`FixConfig::max_pairs`] accepted (bounds the allocation).
pub const MAX_PAIRS_LIMIT: usize = 1024;

/// Whether fixes are 2D (height held) or 3D.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", deny_unknown_fields)]
pub enum FixMode {
    /// East/north with the tag height fixed (`kind = "2d"`).
    #[serde(rename = "2d")]
    Mode2d {
        /// Tag (antenna) height, ENU z, m: a measurement of the robot.
        height_m: f64,
    },
    /// Full 3D position (`kind = "3d"`); needs non-coplanar anchors.
    #[serde(rename = "3d")]
    Mode3d,
}

impl Default for FixMode {
    /// 2D at height 0: the paper's robot moves in the plane of its anchors
    /// (READING.md erratum 17: tag height fixed in 2D).
    fn default() -> Self {
        Self::Mode2d { height_m: 0.0 }
    }
}

/// Settings of the fix builder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FixConfig {
    /// 2D (height held) or 3D. Default 2D at 0 m (see [`FixMode::default`]).
    pub mode: FixMode,
    /// Fix epoch period, s. Default 0.1: the paper's experiment filters at
    /// 10 Hz (READING.md erratum 6); the UTIL README's reference fix rate.
    pub period_s: f64,
    /// Fewest distinct pairs in an epoch to attempt a fix (>= 2 in 2D, >= 3
    /// in 3D, <= `max_pairs`). Default 3.
    pub min_pairs: usize,
    /// Capacity of an epoch's pair table, allocated once; a new pair beyond
    /// it is dropped. Default 64 (8 anchors have 28 unordered pairs).
    pub max_pairs: usize,
    /// Velocity regression settings.
    pub velocity: VelocityConfig,
    /// Multilateration settings; `solver.tdoa_sigma_m` is the TDOA sigma of
    /// the fix covariance.
    pub solver: SolverConfig,
    /// Solve each epoch from the mean of every measurement of a pair in it
    /// instead of the pair's latest one, weighted by the count (`sigma /
    /// sqrt(n)` per pair): the least-squares fix of every measurement of the
    /// epoch. Default false. At 50 Hz per pair (UTIL TDOA2) a 0.1 s epoch
    /// holds about five measurements of each pair, whose independent part
    /// the mean averages.
    pub average_pairs: bool,
    /// Time constant of the tag's range-offset average, s (see "Ranges" in
    /// the module doc); 0 leaves ranges as they are. Default 30 (the
    /// offset is the tag's antenna delay, a constant: a long average, that
    /// still follows a change of tag within a minute).
    pub range_offset_tau_s: f64,
}

impl Default for FixConfig {
    fn default() -> Self {
        Self {
            mode: FixMode::default(),
            period_s: 0.1,
            min_pairs: 3,
            max_pairs: 64,
            velocity: VelocityConfig::default(),
            solver: SolverConfig::default(),
            average_pairs: false,
            range_offset_tau_s: 30.0,
        }
    }
}

/// A [`FixConfig`] value out of range (keys relative to the UWB fix table).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum FixConfigError {
    /// A setting is outside its valid range.
    #[error("{key} must be {requirement}, got {value}")]
    OutOfRange {
        /// Configuration key, e.g. `period_s`.
        key: &'static str,
        /// What the value must satisfy.
        requirement: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A solver setting is out of range.
    #[error(transparent)]
    Solver(#[from] SolverConfigError),
    /// A velocity setting is out of range.
    #[error(transparent)]
    Velocity(#[from] VelocityConfigError),
}

impl FixConfig {
    /// Checks every setting, naming the first offending key.
    ///
    /// # Errors
    /// The first value out of range.
    pub fn validate(&self) -> Result<(), FixConfigError> {
        let fail = |key, requirement, value| {
            Err(FixConfigError::OutOfRange {
                key,
                requirement,
                value,
            })
        };
        let min_pairs_mode = match self.mode {
            FixMode::Mode2d { height_m } => {
                if !height_m.is_finite() {
                    return fail("mode.height_m", "finite", height_m);
                }
                2
            }
            FixMode::Mode3d => 3,
        };
        if !(self.period_s.is_finite() && (1e-3..=60.0).contains(&self.period_s)) {
            return fail("period_s", "in [0.001, 60]", self.period_s);
        }
        if !(1..=MAX_PAIRS_LIMIT).contains(&self.max_pairs) {
            return fail("max_pairs", "in 1..=1024", self.max_pairs as f64);
        }
        if self.min_pairs < min_pairs_mode || self.min_pairs > self.max_pairs {
            let req = if min_pairs_mode == 2 {
                ">= 2 (2D) and <= max_pairs"
            } else {
                ">= 3 (3D) and <= max_pairs"
            };
            return fail("min_pairs", req, self.min_pairs as f64);
        }
        if !(self.range_offset_tau_s.is_finite() && self.range_offset_tau_s >= 0.0) {
            return fail(
                "range_offset_tau_s",
                "finite and >= 0",
                self.range_offset_tau_s,
            );
        }
        self.velocity.validate()?;
        self.solver.validate()?;
        Ok(())
    }

    /// The epoch period in ns (at least 1).
    #[must_use]
    pub fn period_ns(&self) -> u64 {
        ((self.period_s * 1e9).round() as u64).max(1)
    }
}

/// Counters of a [`FixBuilder`]: every input and every epoch is accounted for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct FixStats {
    /// Measurements accepted into an epoch.
    pub accepted: u64,
    /// Accepted measurements later superseded by a newer one of the same pair.
    pub superseded: u64,
    /// Measurements dropped for a NaN or infinite value.
    pub dropped_non_finite: u64,
    /// Measurements dropped because anchor A and B have the same id.
    pub dropped_same_anchor: u64,
    /// Measurements dropped for a time before the previous accepted one.
    pub dropped_time_backwards: u64,
    /// Measurements dropped because the epoch's pair table was full.
    pub dropped_capacity: u64,
    /// Measurements dropped as physically impossible: a range difference
    /// longer than the distance between its two anchors, a negative or too
    /// long range, a range quality above 100.
    #[serde(default)]
    pub dropped_impossible: u64,
    /// Non-empty epochs closed.
    pub epochs: u64,
    /// Fixes produced.
    pub fixes: u64,
    /// Fixes whose previous-fix seed failed and a fallback seed succeeded.
    pub reseeded: u64,
    /// Epochs skipped: fewer pairs than `min_pairs`.
    pub skipped_too_few_pairs: u64,
    /// Epochs skipped: too few distinct anchors, or of independent pairs, or too many anchors.
    pub skipped_too_few_anchors: u64,
    /// Epochs skipped: degenerate geometry (anchor spread or `J^T J`).
    pub skipped_degenerate: u64,
    /// Epochs skipped: the solver did not converge.
    pub skipped_no_convergence: u64,
    /// Epochs skipped: the solution ran away from the anchors.
    pub skipped_runaway: u64,
    /// Epochs skipped for another solver error (invalid input that passed the push checks).
    pub skipped_other: u64,
}

/// Why an epoch gave no fix.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SkipReason {
    /// Fewer distinct pairs than `min_pairs`.
    #[error("epoch had {count} pairs, need {min}")]
    TooFewPairs {
        /// Pairs in the epoch.
        count: usize,
        /// Configured minimum.
        min: usize,
    },
    /// The solver refused or failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
}

/// Why a measurement was dropped (it is also counted in [`FixStats`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PushError {
    /// A value is NaN or infinite.
    #[error("measurement {field} is not finite ({value})")]
    NonFinite {
        /// `diff_m`, `anchor_a_pos_m` or `anchor_b_pos_m`.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// Anchor A and anchor B have the same id.
    #[error("measurement pairs anchor {id} with itself")]
    SameAnchor {
        /// The anchor id.
        id: u32,
    },
    /// The measurement is older than the previous accepted one.
    #[error("measurement time {time_ns} ns is before the previous accepted {last_ns} ns")]
    TimeBackwards {
        /// Time of the dropped measurement, ns.
        time_ns: u64,
        /// Time of the previous accepted measurement, ns.
        last_ns: u64,
    },
    /// The range difference is longer than the distance between its anchors
    /// (the triangle inequality allows at most that): a corrupted or
    /// multipath-wrapped measurement.
    #[error(
        "range difference {diff_m} m is longer than the {baseline_m} m between anchors {a} and {b}"
    )]
    Impossible {
        /// The measured difference, m.
        diff_m: f64,
        /// Distance between the two anchors, m.
        baseline_m: f64,
        /// Anchor A id.
        a: u32,
        /// Anchor B id.
        b: u32,
    },
    /// A range is negative, too long, or carries a quality above 100.
    #[error(transparent)]
    InvalidRange(InvalidRange),
    /// The epoch's pair table is full.
    #[error("epoch pair table full ({max} pairs); pair ({a}, {b}) dropped")]
    PairCapacity {
        /// Capacity (`max_pairs`).
        max: usize,
        /// Anchor A id.
        a: u32,
        /// Anchor B id.
        b: u32,
    },
}

impl From<InvalidRange> for PushError {
    fn from(e: InvalidRange) -> Self {
        match e {
            InvalidRange::NonFinite { field, value } => Self::NonFinite { field, value },
            other => Self::InvalidRange(other),
        }
    }
}

impl From<InvalidTdoa> for PushError {
    fn from(e: InvalidTdoa) -> Self {
        match e {
            InvalidTdoa::NonFinite { field, value } => Self::NonFinite { field, value },
            InvalidTdoa::SameAnchor { id } => Self::SameAnchor { id },
            InvalidTdoa::Impossible {
                diff_m,
                baseline_m,
                a,
                b,
            } => Self::Impossible {
                diff_m,
                baseline_m,
                a,
                b,
            },
        }
    }
}

/// Turns a [`UwbTdoa`] stream into [`UwbFix`]es (see the module doc).
/// Allocates its tables once, in [`FixBuilder::new`].
#[derive(Debug, Clone)]
pub struct FixBuilder {
    cfg: FixConfig,
    period_ns: u64,
    /// Where the epoch windows start: `phase_ns + k * period_ns`
    /// ([`FixBuilder::align_to`]; 0 by default).
    phase_ns: u64,
    /// Unordered pair keys `(min id, max id)` of the open epoch.
    keys: Vec<(u32, u32)>,
    /// Observations of the open epoch, oriented A = min id, B = max id.
    obs: Vec<TdoaObs>,
    /// Per pair of the open epoch: the differences averaged so far (sum,
    /// count), oriented as `obs` (`average_pairs`).
    sums: Vec<(f64, u32)>,
    /// Per pair of the open epoch: the sigma of its mean (`average_pairs`).
    sigmas: Vec<f64>,
    /// Anchor ids of the open epoch's ranges.
    range_keys: Vec<u32>,
    /// Range observations of the open epoch, one per anchor.
    ranges: Vec<RangeObs>,
    /// Per anchor of the open epoch: the ranges averaged so far (sum, count).
    range_sums: Vec<(f64, u32)>,
    /// The tag's range offset: the weighted average, its weight (1/m^2)
    /// and the time of the last epoch that moved it.
    range_offset: Option<(f64, f64, u64)>,
    /// Epoch index of the open group.
    epoch: Option<u64>,
    /// Time of the latest accepted measurement.
    last_time_ns: Option<u64>,
    /// Position of the previous fix: the next solve's seed.
    prev_pos_m: Option<[f64; 3]>,
    seq: u64,
    velocity: VelocityEstimator,
    stats: FixStats,
    last_skip: Option<SkipReason>,
    /// Site calibration applied on push.
    calibration: Option<Arc<SiteCalibration>>,
}

impl FixBuilder {
    /// A builder with empty tables.
    ///
    /// # Errors
    /// The configuration's validation error.
    pub fn new(cfg: FixConfig) -> Result<Self, FixConfigError> {
        cfg.validate()?;
        let velocity = VelocityEstimator::new(cfg.velocity.clone())?;
        Ok(Self {
            period_ns: cfg.period_ns(),
            phase_ns: 0,
            keys: Vec::with_capacity(cfg.max_pairs),
            obs: Vec::with_capacity(cfg.max_pairs),
            sums: Vec::with_capacity(cfg.max_pairs),
            sigmas: Vec::with_capacity(cfg.max_pairs),
            range_keys: Vec::with_capacity(cfg.max_pairs),
            ranges: Vec::with_capacity(cfg.max_pairs),
            range_sums: Vec::with_capacity(cfg.max_pairs),
            range_offset: None,
            epoch: None,
            last_time_ns: None,
            prev_pos_m: None,
            seq: 0,
            velocity,
            stats: FixStats::default(),
            last_skip: None,
            calibration: None,
            cfg,
        })
    }

    /// The builder with a site calibration applied to every measurement
    /// (see the module doc); `None` removes it.
    #[must_use]
    pub fn with_calibration(mut self, calibration: Option<Arc<SiteCalibration>>) -> Self {
        self.calibration = calibration;
        self
    }

    /// The site calibration in use.
    #[must_use]
    pub fn calibration(&self) -> Option<&Arc<SiteCalibration>> {
        self.calibration.as_ref()
    }

    /// `m` as [`FixBuilder::push`] uses it now: corrected by the site
    /// calibration at the previous fix (flagged), or unchanged without a
    /// calibration, when already flagged or when its anchors are not the
    /// calibration's.
    #[must_use]
    pub fn calibrate(&self, m: &UwbTdoa) -> UwbTdoa {
        match &self.calibration {
            Some(c) => c.correct(m, self.prev_pos_m.as_ref()),
            None => *m,
        }
    }

    /// The settings in use.
    #[must_use]
    pub fn config(&self) -> &FixConfig {
        &self.cfg
    }

    /// The counters so far.
    #[must_use]
    pub fn stats(&self) -> &FixStats {
        &self.stats
    }

    /// Why the most recent epoch without a fix had none.
    #[must_use]
    pub fn last_skip(&self) -> Option<&SkipReason> {
        self.last_skip.as_ref()
    }

    /// Pairs held in the open epoch.
    #[must_use]
    pub fn pending_pairs(&self) -> usize {
        self.keys.len() + self.range_keys.len()
    }

    /// Forgets the open epoch, the time order, the seed and the velocity
    /// window (e.g. after a source restart); keeps the counters and `seq`.
    pub fn reset(&mut self) {
        self.keys.clear();
        self.obs.clear();
        self.sums.clear();
        self.range_keys.clear();
        self.ranges.clear();
        self.range_sums.clear();
        self.epoch = None;
        self.last_time_ns = None;
        self.prev_pos_m = None;
        self.velocity.reset();
    }

    /// Adds one measurement, corrected as [`FixBuilder::calibrate`] says;
    /// returns the fix of the epoch it closed, if any.
    ///
    /// A measurement can close two groups (the open epoch, being of a later
    /// epoch, and then its own, when flagged [`UwbTdoa::FLAG_EPOCH_END`]), but
    /// the second then holds this one measurement only, fewer than
    /// `min_pairs` (>= 2): at most one fix comes out; the other closure is
    /// counted in [`FixStats::skipped_too_few_pairs`].
    ///
    /// # Errors
    /// The measurement was dropped (and counted); nothing else changed.
    pub fn push(&mut self, m: &UwbTdoa) -> Result<Option<UwbFix>, PushError> {
        let corrected = self.calibrate(m);
        let m = &corrected;
        if let Err(e) = self.check(m) {
            self.count_drop(&e);
            return Err(e);
        }
        let t = m.header.meas_time_ns;
        let (k, out) = self.enter_epoch(t);
        let (key, o) = if m.anchor_a < m.anchor_b {
            ((m.anchor_a, m.anchor_b), TdoaObs::from_msg(m))
        } else {
            ((m.anchor_b, m.anchor_a), TdoaObs::from_msg(m).flipped())
        };
        match self.keys.iter().position(|q| *q == key) {
            Some(i) => {
                if let (Some(slot), Some(sum)) = (self.obs.get_mut(i), self.sums.get_mut(i)) {
                    if self.cfg.average_pairs {
                        sum.0 += o.diff_m;
                        sum.1 += 1;
                        slot.diff_m = sum.0 / f64::from(sum.1);
                    } else {
                        *slot = o;
                    }
                }
                self.stats.superseded += 1;
            }
            None => {
                // Capacity was checked in `check` (or the table was just emptied).
                self.keys.push(key);
                self.sums.push((o.diff_m, 1));
                self.obs.push(o);
            }
        }
        Ok(self.accepted(k, t, m.header.flags & UwbTdoa::FLAG_EPOCH_END != 0, out))
    }

    /// Counts a dropped measurement under its reason.
    fn count_drop(&mut self, e: &PushError) {
        let s = &mut self.stats;
        match e {
            PushError::NonFinite { .. } => s.dropped_non_finite += 1,
            PushError::SameAnchor { .. } => s.dropped_same_anchor += 1,
            PushError::TimeBackwards { .. } => s.dropped_time_backwards += 1,
            PushError::PairCapacity { .. } => s.dropped_capacity += 1,
            PushError::Impossible { .. } | PushError::InvalidRange(_) => s.dropped_impossible += 1,
        }
    }

    /// The epoch window of a measurement at `t`, and the fix of the open
    /// epoch when `t` is in a later one (which closes it).
    fn enter_epoch(&mut self, t: u64) -> (u64, Option<UwbFix>) {
        let k = self.window_of(t);
        let out = if self.epoch.is_some_and(|e| k > e) {
            self.close()
        } else {
            None
        };
        (k, out)
    }

    /// Books an accepted measurement of window `k` at `t`; closes its
    /// epoch when it ends one. The fix to return: `closed`, else this one's.
    fn accepted(
        &mut self,
        k: u64,
        t: u64,
        epoch_end: bool,
        closed: Option<UwbFix>,
    ) -> Option<UwbFix> {
        self.stats.accepted += 1;
        self.epoch = Some(k);
        self.last_time_ns = Some(t);
        if epoch_end {
            let own = self.close();
            return closed.or(own);
        }
        closed
    }

    /// The tag's range offset estimated so far, m (`None`: not yet, or
    /// not estimated).
    #[must_use]
    pub fn range_offset_m(&self) -> Option<f64> {
        self.range_offset.map(|(b, _, _)| b)
    }

    /// `m` as [`FixBuilder::push_range`] uses it now: less the tag's range
    /// offset estimated so far, flagged; unchanged before the first
    /// estimate, without estimation, or when already flagged.
    #[must_use]
    pub fn correct_range(&self, m: &UwbRange) -> UwbRange {
        match self.range_offset {
            Some((b, _, _)) if m.header.flags & UwbRange::FLAG_OFFSET_REMOVED == 0 => {
                let mut out = *m;
                out.range_m -= b;
                out.header.flags |= UwbRange::FLAG_OFFSET_REMOVED;
                out
            }
            _ => *m,
        }
    }

    /// Adds one two-way range, corrected as [`FixBuilder::correct_range`]
    /// says (see "Ranges" in the module doc); returns the fix of the epoch
    /// it closed, if any, as [`FixBuilder::push`] does.
    ///
    /// # Errors
    /// The range was dropped (and counted); nothing else changed.
    pub fn push_range(&mut self, m: &UwbRange) -> Result<Option<UwbFix>, PushError> {
        let corrected = self.correct_range(m);
        let m = &corrected;
        if let Err(e) = self.check_range(m) {
            self.count_drop(&e);
            return Err(e);
        }
        let t = m.header.meas_time_ns;
        let (k, out) = self.enter_epoch(t);
        let o = RangeObs::from_msg(m);
        match self.range_keys.iter().position(|q| *q == m.anchor) {
            Some(i) => {
                if let (Some(slot), Some(sum)) =
                    (self.ranges.get_mut(i), self.range_sums.get_mut(i))
                {
                    if self.cfg.average_pairs {
                        sum.0 += o.range_m;
                        sum.1 += 1;
                        slot.range_m = sum.0 / f64::from(sum.1);
                    } else {
                        *slot = o;
                    }
                }
                self.stats.superseded += 1;
            }
            None => {
                self.range_keys.push(m.anchor);
                self.range_sums.push((o.range_m, 1));
                self.ranges.push(o);
            }
        }
        Ok(self.accepted(k, t, m.header.flags & UwbRange::FLAG_EPOCH_END != 0, out))
    }

    /// The range's value check, its time order, room in the epoch's table
    /// and an epoch not already holding TDOA differences.
    fn check_range(&self, m: &UwbRange) -> Result<(), PushError> {
        check::range_values(m)?;
        let t = m.header.meas_time_ns;
        if let Some(last_ns) = self.last_time_ns.filter(|last| t < *last) {
            return Err(PushError::TimeBackwards {
                time_ns: t,
                last_ns,
            });
        }
        let same_epoch = self.epoch.is_some_and(|e| e == self.window_of(t));
        if same_epoch
            && self.range_keys.len() + self.keys.len() >= self.cfg.max_pairs
            && !self.range_keys.contains(&m.anchor)
        {
            return Err(PushError::PairCapacity {
                max: self.cfg.max_pairs,
                a: m.anchor,
                b: m.anchor,
            });
        }
        Ok(())
    }

    /// Aligns the epoch windows to a recording replayed from `epoch_ns`
    /// (measurement times `epoch_ns + t`): the windows then hold the same
    /// measurements as for the recording's own times `t`, whatever the
    /// epoch (a group's is the start epoch, `insuwb_runtime::epoch`).
    /// Call before the first push.
    pub fn align_to(&mut self, epoch_ns: u64) {
        self.phase_ns = epoch_ns % self.period_ns.max(1);
    }

    /// The index of the epoch window `(phase + (k-1) P, phase + k P]` holding `t`.
    fn window_of(&self, t_ns: u64) -> u64 {
        t_ns.saturating_sub(self.phase_ns)
            .div_ceil(self.period_ns.max(1))
    }

    /// Closes the open epoch now; returns its fix if it gave one.
    pub fn flush(&mut self) -> Option<UwbFix> {
        self.close()
    }

    /// The shared value check, then the builder's own: time order against
    /// the last accepted measurement, room in the epoch's pair table.
    fn check(&self, m: &UwbTdoa) -> Result<(), PushError> {
        check::tdoa_values(m)?;
        let t = m.header.meas_time_ns;
        if let Some(last_ns) = self.last_time_ns.filter(|last| t < *last) {
            return Err(PushError::TimeBackwards {
                time_ns: t,
                last_ns,
            });
        }
        let k = self.window_of(t);
        let same_epoch = self.epoch.is_some_and(|e| e == k);
        let key = (m.anchor_a.min(m.anchor_b), m.anchor_a.max(m.anchor_b));
        if same_epoch && self.keys.len() >= self.cfg.max_pairs && !self.keys.contains(&key) {
            return Err(PushError::PairCapacity {
                max: self.cfg.max_pairs,
                a: m.anchor_a,
                b: m.anchor_b,
            });
        }
        Ok(())
    }

    /// Solves the open group, if any, and empties it.
    fn close(&mut self) -> Option<UwbFix> {
        if self.obs.is_empty() && self.ranges.is_empty() {
            return None;
        }
        self.stats.epochs += 1;
        let time_ns = self.last_time_ns.unwrap_or_default();
        let result = if self.ranges.is_empty() {
            self.solve_group()
        } else {
            self.solve_ranges()
        };
        self.keys.clear();
        self.obs.clear();
        self.sums.clear();
        self.range_keys.clear();
        self.ranges.clear();
        self.range_sums.clear();
        match result {
            Ok((fix, seed)) => {
                if seed != Seed::Init && self.prev_pos_m.is_some() {
                    self.stats.reseeded += 1;
                }
                self.prev_pos_m = Some(fix.pos_m);
                let mut flags = 0;
                if matches!(self.cfg.mode, FixMode::Mode2d { .. }) {
                    flags |= UwbFix::FLAG_2D;
                }
                let mut out = UwbFix {
                    header: Header::new(self.seq, time_ns),
                    pos_m: fix.pos_m,
                    pos_cov_m2: fix.cov_m2,
                    gdop: fix.gdop,
                    n_meas: u32::try_from(fix.n_obs).unwrap_or(u32::MAX),
                    iterations: fix.iterations,
                    ..UwbFix::default()
                };
                if let Ok(v) = self.velocity.push(time_ns, fix.pos_m, fix.cov_m2) {
                    if v.valid {
                        out.vel_mps = v.vel_mps;
                        out.vel_cov = v.cov_mps2;
                        flags |= UwbFix::FLAG_VEL_VALID;
                    }
                }
                out.header.flags = flags;
                self.seq += 1;
                self.stats.fixes += 1;
                Some(out)
            }
            Err(reason) => {
                let s = &mut self.stats;
                match reason {
                    SkipReason::TooFewPairs { .. } => s.skipped_too_few_pairs += 1,
                    SkipReason::Solve(e) => match e {
                        SolveError::TooFewAnchors { .. }
                        | SolveError::TooFewPairs { .. }
                        | SolveError::TooManyAnchors { .. } => s.skipped_too_few_anchors += 1,
                        SolveError::DegenerateGeometry { .. } => s.skipped_degenerate += 1,
                        SolveError::NoConvergence { .. } => s.skipped_no_convergence += 1,
                        SolveError::Runaway { .. } => s.skipped_runaway += 1,
                        SolveError::Config(_)
                        | SolveError::NonFiniteObs { .. }
                        | SolveError::NonFiniteArg { .. }
                        | SolveError::InvalidSigma { .. }
                        | SolveError::SigmaCount { .. }
                        | SolveError::SameAnchor { .. } => s.skipped_other += 1,
                    },
                }
                self.last_skip = Some(reason);
                None
            }
        }
    }

    fn solve_ranges(&mut self) -> Result<(solve::Fix, Seed), SkipReason> {
        if self.ranges.len() < self.cfg.min_pairs {
            return Err(SkipReason::TooFewPairs {
                count: self.ranges.len(),
                min: self.cfg.min_pairs,
            });
        }
        let solver = &self.cfg.solver;
        let height = match self.cfg.mode {
            FixMode::Mode2d { height_m } => Some(height_m),
            FixMode::Mode3d => None,
        };
        let sigmas = if self.cfg.average_pairs {
            // The mean of n ranges has sigma / sqrt(n).
            self.sigmas.clear();
            self.sigmas.extend(
                self.range_sums
                    .iter()
                    .map(|s| solver.range_sigma_m / f64::from(s.1.max(1)).sqrt()),
            );
            Some(self.sigmas.as_slice())
        } else {
            None
        };
        if self.cfg.range_offset_tau_s > 0.0 {
            // The offset left in the corrected ranges, added to the average.
            if let Ok(f) = ranging::solve_ranges_with_offset(
                &self.ranges,
                sigmas,
                height,
                self.prev_pos_m,
                solver,
            ) {
                let t = self.last_time_ns.unwrap_or_default();
                let w = 1.0 / f.offset_var_m2;
                self.range_offset = Some(match self.range_offset {
                    None => (f.offset_m, w, t),
                    Some((b, w0, t0)) => {
                        let dt_s = t.saturating_sub(t0) as f64 * 1e-9;
                        let w_old = w0 * (-dt_s / self.cfg.range_offset_tau_s).exp();
                        let sum = w_old + w;
                        (b + f.offset_m * w / sum, sum, t)
                    }
                });
            }
        }
        let fix =
            ranging::solve_ranges_weighted(&self.ranges, sigmas, height, self.prev_pos_m, solver)?;
        Ok((fix, fix.seed))
    }

    fn solve_group(&mut self) -> Result<(solve::Fix, Seed), SkipReason> {
        if self.obs.len() < self.cfg.min_pairs {
            return Err(SkipReason::TooFewPairs {
                count: self.obs.len(),
                min: self.cfg.min_pairs,
            });
        }
        let (obs, init, solver) = (&self.obs, self.prev_pos_m, &self.cfg.solver);
        let fix = if self.cfg.average_pairs {
            // The mean of n differences has sigma / sqrt(n).
            self.sigmas.clear();
            self.sigmas.extend(
                self.sums
                    .iter()
                    .map(|s| solver.tdoa_sigma_m / f64::from(s.1.max(1)).sqrt()),
            );
            match self.cfg.mode {
                FixMode::Mode2d { height_m } => {
                    solve::solve_2d_weighted(obs, &self.sigmas, height_m, init, solver)?
                }
                FixMode::Mode3d => solve::solve_3d_weighted(obs, &self.sigmas, init, solver)?,
            }
        } else {
            match self.cfg.mode {
                FixMode::Mode2d { height_m } => solve::solve_2d(obs, height_m, init, solver)?,
                FixMode::Mode3d => solve::solve_3d(obs, init, solver)?,
            }
        };
        Ok((fix, fix.seed))
    }
}
