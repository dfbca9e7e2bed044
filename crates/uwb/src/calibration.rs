//! Site calibration of the TDOA errors of one anchor constellation.
//!
//! Much of a TDOA difference's error is a slow bias per anchor pair that
//! depends on where the tag is (antenna patterns, multipath off the room) and
//! repeats from one flight to the next in the same site. A
//! [`SiteCalibration`] holds, per unordered anchor pair, a bias model learnt
//! from flights with ground truth ([`SiteCalibration::learn`], from
//! [`Sample`]s: measured minus true difference at the antenna position) and
//! the noise left after it, for the anchor positions it was learnt with.
//!
//! - The bias is that of the measured `diff_m = |p - b| - |p - a|` of
//!   [`UwbTdoa`] over the true one; `(a, b)` and `(b, a)` are the same pair
//!   with the sign flipped.
//! - Model families ([`Family`]): [`Family::PairConstant`], one median per
//!   pair; [`Family::Grid`], the median per pair and x-y cell, shrunk
//!   towards the pair's constant where a cell holds few samples, cells with
//!   fewer than `min_count` samples (and cells never visited) falling back
//!   to the constant, optionally interpolated bilinearly between cell
//!   centres.
//! - [`SiteCalibration::correct`] subtracts the bias at a position (the
//!   latest fix at run time; before the first fix, [`None`]: the pair's
//!   constant) and sets [`UwbTdoa::FLAG_CALIBRATED`]; a measurement already
//!   flagged is returned unchanged, and so is one whose anchors are not
//!   those of the calibration (more than [`ANCHOR_TOLERANCE_M`] away).
//! - Files: TOML ([`SiteCalibration::save`], [`SiteCalibration::load`]),
//!   `format_version`, a `[site]` table (family and anchors) and one
//!   `[[pairs]]` table per pair. [`SiteCalibration::check_anchors`] refuses
//!   another anchor survey that is not this constellation.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use insuwb_msg::UwbTdoa;
use serde::{Deserialize, Serialize};

/// The file format written and read.
pub const FORMAT_VERSION: u32 = 1;

/// Largest distance (m) between an anchor of the calibration and the same
/// anchor of another survey (or of a measurement) for them to be the same.
pub const ANCHOR_TOLERANCE_M: f64 = 0.05;

/// Fewest samples of a pair to learn it (fewer: the pair is left out, its
/// bias taken as 0).
pub const MIN_PAIR_SAMPLES: usize = 20;

/// A residual beyond this many robust SDs from its pair's median is a gross
/// outlier, left out of the medians ...
pub const GROSS_SIGMAS: f64 = 4.0;

/// ... and so is one beyond this many metres (whatever the spread).
pub const GROSS_MIN_M: f64 = 0.3;

/// A residual at its antenna position.
type Located = ([f64; 3], f64);

/// Robust SD from a median absolute deviation (normal distribution).
const MAD_TO_SD: f64 = 1.4826;

/// Settings of the grid family.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridParams {
    /// Cell side, m (x and y).
    pub cell_m: f64,
    /// Fewest samples of a cell to use it (fewer: the pair's constant).
    pub min_count: u32,
    /// Shrinkage: a cell of `n` samples keeps `n / (n + shrink_count)` of
    /// its median's departure from the pair's constant.
    pub shrink_count: f64,
    /// The share of each cell's departure (after `shrink_count`) that the
    /// calibration applies, in [0, 1]: 0 is the pair's constant, 1 the
    /// cell's median. What a cell learnt on some flights holds repeats
    /// only in part on others (the vehicle, the survey day), and leave
    /// one flight out scores half best on the UTIL flights
    /// (docs/REAL_FLIGHTS.md, "Site calibration").
    pub weight: f64,
    /// Interpolate bilinearly between the four cell centres around the
    /// position (else: the value of the cell holding it).
    pub bilinear: bool,
}

impl Default for GridParams {
    fn default() -> Self {
        Self {
            cell_m: 1.0,
            min_count: 20,
            shrink_count: 20.0,
            weight: 0.5,
            bilinear: true,
        }
    }
}

/// The bias model of every pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Family {
    /// One constant per pair: the median of its residuals.
    PairConstant,
    /// A median per pair and x-y cell (see [`GridParams`]).
    Grid(GridParams),
}

impl Family {
    /// The family's name in files and on the command line.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::PairConstant => "pair_constant",
            Self::Grid(_) => "grid",
        }
    }

    /// A short description with its settings, for reports.
    #[must_use]
    pub fn label(&self) -> String {
        match self {
            Self::PairConstant => "pair_constant".to_owned(),
            Self::Grid(g) => format!(
                "grid {} m{} weight {}",
                g.cell_m,
                if g.bilinear { " bilinear" } else { "" },
                g.weight
            ),
        }
    }

    fn validate(&self) -> Result<(), (&'static str, String)> {
        if let Self::Grid(g) = self {
            if !(g.cell_m.is_finite() && (0.05..=100.0).contains(&g.cell_m)) {
                return Err((
                    "cell_m",
                    format!("must be in [0.05, 100], got {}", g.cell_m),
                ));
            }
            if !(g.shrink_count.is_finite() && g.shrink_count >= 0.0) {
                return Err((
                    "shrink_count",
                    format!("must be finite and >= 0, got {}", g.shrink_count),
                ));
            }
            if !(0.0..=1.0).contains(&g.weight) {
                return Err(("weight", format!("must be in [0, 1], got {}", g.weight)));
            }
            if g.min_count == 0 {
                return Err(("min_count", "must be >= 1, got 0".to_owned()));
            }
        }
        Ok(())
    }
}

/// One residual to learn from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Anchor A of the difference.
    pub a: u32,
    /// Anchor B of the difference.
    pub b: u32,
    /// Antenna position (ENU, m) at the measurement time.
    pub pos_m: [f64; 3],
    /// Measured minus true `|p - b| - |p - a|`, m.
    pub residual_m: f64,
}

/// One pair's model, oriented from the lower anchor id to the higher.
#[derive(Debug, Clone, PartialEq)]
pub struct PairModel {
    /// The pair's constant bias (the median of its residuals), m.
    pub bias_m: f64,
    /// Robust SD of the residuals after the bias, m.
    pub noise_m: f64,
    /// Samples learnt from.
    pub samples: u64,
    /// Grid cells `(ix, iy) -> (bias, samples)`; cell `ix` covers `x` in
    /// `[ix * cell_m, (ix + 1) * cell_m)`. Empty for other families.
    pub cells: BTreeMap<(i32, i32), (f64, u32)>,
}

/// A learnt calibration of one constellation (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct SiteCalibration {
    anchors: BTreeMap<u32, [f64; 3]>,
    family: Family,
    pairs: BTreeMap<(u32, u32), PairModel>,
}

/// Why learning was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LearnError {
    /// A family setting is out of range.
    #[error("{key}: {reason}")]
    Family {
        /// The setting (`cell_m`, ...).
        key: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// No anchors given.
    #[error("no anchor positions to learn for")]
    NoAnchors,
    /// An anchor position is not finite.
    #[error("anchor {id}: position {pos_m:?} is not finite")]
    NonFiniteAnchor {
        /// The anchor id.
        id: u32,
        /// Its position.
        pos_m: [f64; 3],
    },
    /// No pair had enough usable samples.
    #[error("no anchor pair has {MIN_PAIR_SAMPLES} usable samples (of {samples} given)")]
    TooFewSamples {
        /// Samples given.
        samples: usize,
    },
}

/// Why a calibration file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The file cannot be read.
    #[error("{}: cannot read: {error}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        error: std::io::Error,
    },
    /// The text is not a calibration (TOML error, with its line).
    #[error("{origin}: {message}")]
    Parse {
        /// The file.
        origin: String,
        /// The parser's message.
        message: String,
    },
    /// The file is of another format version.
    #[error("{origin}: key 'format_version': {found} is not supported (this build reads {FORMAT_VERSION})")]
    Version {
        /// The file.
        origin: String,
        /// The version found.
        found: u32,
    },
    /// A value is out of range or inconsistent.
    #[error("{origin}: key '{key}': {reason}")]
    Invalid {
        /// The file.
        origin: String,
        /// The key (`site.cell_m`, `pairs[3].b`, ...).
        key: String,
        /// What is wrong.
        reason: String,
    },
}

/// Why a calibration could not be written.
#[derive(Debug, thiserror::Error)]
pub enum SaveError {
    /// Serialisation failed.
    #[error("{}: cannot serialise the calibration: {message}", path.display())]
    Serialize {
        /// The file.
        path: PathBuf,
        /// The serialiser's message.
        message: String,
    },
    /// The file cannot be written.
    #[error("{}: cannot write: {error}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The cause.
        error: std::io::Error,
    },
}

/// Why another anchor survey does not fit a calibration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnchorCheckError {
    /// An anchor is further from the calibration's than the tolerance.
    #[error(
        "anchor {id} of {anchors} is {distance_m:.3} m from the position the calibration {} was learnt for (at most {ANCHOR_TOLERANCE_M} m): another constellation",
        calibration.display()
    )]
    Moved {
        /// The calibration file.
        calibration: PathBuf,
        /// The other anchor survey.
        anchors: String,
        /// The anchor id.
        id: u32,
        /// The distance, m.
        distance_m: f64,
    },
    /// An anchor of one is absent from the other.
    #[error(
        "anchor {id} is in {} but not in {}: another constellation",
        if *in_calibration { calibration.display().to_string() } else { anchors.clone() },
        if *in_calibration { anchors.clone() } else { calibration.display().to_string() }
    )]
    Missing {
        /// The calibration file.
        calibration: PathBuf,
        /// The other anchor survey.
        anchors: String,
        /// The anchor id.
        id: u32,
        /// Whether the calibration has it (and the survey not), or the reverse.
        in_calibration: bool,
    },
}

/// The median of `v` (sorted in place); `None` when empty.
pub(crate) fn median_of(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// A pair's residuals `v` (sorted in place): their median and the distance
/// from it beyond which one is a gross outlier ([`GROSS_SIGMAS`] robust
/// SDs, at least [`GROSS_MIN_M`]); `None` when empty.
pub(crate) fn gross_gate(v: &mut [f64]) -> Option<(f64, f64)> {
    let centre = median_of(v)?;
    Some((
        centre,
        (GROSS_SIGMAS * robust_sd(v, centre)).max(GROSS_MIN_M),
    ))
}

/// Robust SD (1.4826 times the median absolute deviation from `centre`).
pub(crate) fn robust_sd(v: &[f64], centre: f64) -> f64 {
    let mut d: Vec<f64> = v.iter().map(|r| (r - centre).abs()).collect();
    MAD_TO_SD * median_of(&mut d).unwrap_or(0.0)
}

/// The true TDOA difference `|p - b| - |p - a|` at the antenna position `p`:
/// what a [`Sample`]'s residual is measured against.
#[must_use]
pub fn true_difference(p: &[f64; 3], a: &[f64; 3], b: &[f64; 3]) -> f64 {
    dist(p, b) - dist(p, a)
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// The unordered key of `(a, b)` and the sign of `(a, b)` against it.
fn key_of(a: u32, b: u32) -> ((u32, u32), f64) {
    if a <= b {
        ((a, b), 1.0)
    } else {
        ((b, a), -1.0)
    }
}

fn cell_of(x: f64, cell_m: f64) -> i32 {
    let c = (x / cell_m).floor();
    // Positions are within a room; clamp so that a wild value cannot wrap.
    c.clamp(f64::from(i32::MIN / 2), f64::from(i32::MAX / 2)) as i32
}

impl PairModel {
    /// Bias at `pos` (oriented lower id to higher), `None`: the constant.
    fn bias_at(&self, family: &Family, pos: Option<&[f64; 3]>) -> f64 {
        let (Family::Grid(g), Some(p)) = (family, pos) else {
            return self.bias_m;
        };
        if !(p[0].is_finite() && p[1].is_finite()) {
            return self.bias_m;
        }
        let cell = |ix: i32, iy: i32| self.cells.get(&(ix, iy)).map_or(self.bias_m, |c| c.0);
        if !g.bilinear {
            return cell(cell_of(p[0], g.cell_m), cell_of(p[1], g.cell_m));
        }
        // Cell centres at (i + 0.5) * cell_m.
        let u = p[0] / g.cell_m - 0.5;
        let v = p[1] / g.cell_m - 0.5;
        let (i0, j0) = (cell_of(u, 1.0), cell_of(v, 1.0));
        let (fx, fy) = (u - f64::from(i0), v - f64::from(j0));
        let (fx, fy) = (fx.clamp(0.0, 1.0), fy.clamp(0.0, 1.0));
        let (i1, j1) = (i0.saturating_add(1), j0.saturating_add(1));
        (1.0 - fx) * (1.0 - fy) * cell(i0, j0)
            + fx * (1.0 - fy) * cell(i1, j0)
            + (1.0 - fx) * fy * cell(i0, j1)
            + fx * fy * cell(i1, j1)
    }
}

impl SiteCalibration {
    /// Learns a calibration for the constellation `anchors` from residual
    /// samples: per unordered pair, gross outliers (beyond
    /// [`GROSS_SIGMAS`] robust SDs and [`GROSS_MIN_M`] from the pair's
    /// median) are left out, the constant is the median of the rest, the
    /// grid's cells the shrunk medians of theirs; the noise is the robust
    /// SD of every sample's residual after the bias. Samples with a
    /// non-finite value, equal anchors or an anchor not in `anchors` are
    /// skipped; pairs with fewer than [`MIN_PAIR_SAMPLES`] are left out.
    ///
    /// # Errors
    /// [`LearnError`]: a family setting out of range, no or non-finite
    /// anchors, no pair with enough samples.
    pub fn learn(
        anchors: BTreeMap<u32, [f64; 3]>,
        family: Family,
        samples: &[Sample],
    ) -> Result<Self, LearnError> {
        family
            .validate()
            .map_err(|(key, reason)| LearnError::Family { key, reason })?;
        if anchors.is_empty() {
            return Err(LearnError::NoAnchors);
        }
        if let Some((&id, &pos_m)) = anchors
            .iter()
            .find(|(_, p)| !p.iter().all(|v| v.is_finite()))
        {
            return Err(LearnError::NonFiniteAnchor { id, pos_m });
        }
        // (x, y, residual) per pair, oriented lower id to higher.
        let mut by_pair: BTreeMap<(u32, u32), Vec<Located>> = BTreeMap::new();
        for s in samples {
            let finite = s.residual_m.is_finite() && s.pos_m.iter().all(|v| v.is_finite());
            if !finite || s.a == s.b || !anchors.contains_key(&s.a) || !anchors.contains_key(&s.b) {
                continue;
            }
            let (key, sign) = key_of(s.a, s.b);
            by_pair
                .entry(key)
                .or_default()
                .push((s.pos_m, sign * s.residual_m));
        }
        let mut pairs = BTreeMap::new();
        for (key, rows) in by_pair {
            if rows.len() < MIN_PAIR_SAMPLES {
                continue;
            }
            let mut all: Vec<f64> = rows.iter().map(|r| r.1).collect();
            let Some((centre, gate)) = gross_gate(&mut all) else {
                continue;
            };
            let inliers: Vec<&Located> = rows
                .iter()
                .filter(|r| (r.1 - centre).abs() <= gate)
                .collect();
            let mut kept: Vec<f64> = inliers.iter().map(|r| r.1).collect();
            let Some(bias_m) = median_of(&mut kept) else {
                continue;
            };
            let mut model = PairModel {
                bias_m,
                noise_m: 0.0,
                samples: rows.len() as u64,
                cells: BTreeMap::new(),
            };
            if let Family::Grid(g) = &family {
                let mut cells: BTreeMap<(i32, i32), Vec<f64>> = BTreeMap::new();
                for (p, r) in &inliers {
                    cells
                        .entry((cell_of(p[0], g.cell_m), cell_of(p[1], g.cell_m)))
                        .or_default()
                        .push(*r);
                }
                for (c, mut v) in cells {
                    let n = v.len();
                    let Ok(n32) = u32::try_from(n) else { continue };
                    if n32 < g.min_count {
                        continue;
                    }
                    if let Some(m) = median_of(&mut v) {
                        let w = g.weight * n as f64 / (n as f64 + g.shrink_count);
                        model.cells.insert(c, (bias_m + w * (m - bias_m), n32));
                    }
                }
            }
            let after: Vec<f64> = rows
                .iter()
                .map(|(p, r)| r - model.bias_at(&family, Some(p)))
                .collect();
            model.noise_m = robust_sd(&after, 0.0);
            pairs.insert(key, model);
        }
        if pairs.is_empty() {
            return Err(LearnError::TooFewSamples {
                samples: samples.len(),
            });
        }
        Ok(Self {
            anchors,
            family,
            pairs,
        })
    }

    /// The anchor positions it was learnt for (id -> ENU, m).
    #[must_use]
    pub fn anchors(&self) -> &BTreeMap<u32, [f64; 3]> {
        &self.anchors
    }

    /// The model family.
    #[must_use]
    pub fn family(&self) -> &Family {
        &self.family
    }

    /// The pairs' models, keyed `(lower id, higher id)`.
    #[must_use]
    pub fn pairs(&self) -> &BTreeMap<(u32, u32), PairModel> {
        &self.pairs
    }

    /// Bias (m) of the measured `|p - b| - |p - a|` at antenna position
    /// `pos`; `None`: the pair's constant (before the first fix). 0 for a
    /// pair not learnt.
    #[must_use]
    pub fn bias(&self, a: u32, b: u32, pos: Option<&[f64; 3]>) -> f64 {
        let (key, sign) = key_of(a, b);
        self.pairs
            .get(&key)
            .map_or(0.0, |m| sign * m.bias_at(&self.family, pos))
    }

    /// Robust SD (m) of the pair's residuals after the bias; `None` for a
    /// pair not learnt.
    #[must_use]
    pub fn noise(&self, a: u32, b: u32) -> Option<f64> {
        self.pairs.get(&key_of(a, b).0).map(|m| m.noise_m)
    }

    /// Whether both anchors of `m` are the calibration's (same ids, within
    /// [`ANCHOR_TOLERANCE_M`]).
    #[must_use]
    pub fn fits(&self, m: &UwbTdoa) -> bool {
        let near = |id: u32, p: &[f64; 3]| {
            self.anchors
                .get(&id)
                .is_some_and(|q| dist(p, q) <= ANCHOR_TOLERANCE_M)
        };
        near(m.anchor_a, &m.anchor_a_pos_m) && near(m.anchor_b, &m.anchor_b_pos_m)
    }

    /// `m` with the bias at `pos` (`None`: the pair's constant) subtracted
    /// and [`UwbTdoa::FLAG_CALIBRATED`] set. Returned unchanged when it is
    /// already flagged, or when its anchors are not the calibration's
    /// ([`SiteCalibration::fits`]). A pair not learnt is flagged with no
    /// correction.
    #[must_use]
    pub fn correct(&self, m: &UwbTdoa, pos: Option<&[f64; 3]>) -> UwbTdoa {
        if m.header.flags & UwbTdoa::FLAG_CALIBRATED != 0 || !self.fits(m) {
            return *m;
        }
        let mut out = *m;
        out.diff_m -= self.bias(m.anchor_a, m.anchor_b, pos);
        out.header.flags |= UwbTdoa::FLAG_CALIBRATED;
        out
    }

    /// Checks that the anchor survey `other` (id -> position; named
    /// `anchors_origin`) is the constellation this calibration (file
    /// `calib_path`) was learnt for: the same ids, each within
    /// [`ANCHOR_TOLERANCE_M`].
    ///
    /// # Errors
    /// [`AnchorCheckError`] naming both files, the anchor and the distance.
    pub fn check_anchors(
        &self,
        other: &BTreeMap<u32, [f64; 3]>,
        calib_path: &Path,
        anchors_origin: &str,
    ) -> Result<(), AnchorCheckError> {
        for (&id, p) in other {
            let Some(q) = self.anchors.get(&id) else {
                return Err(AnchorCheckError::Missing {
                    calibration: calib_path.to_owned(),
                    anchors: anchors_origin.to_owned(),
                    id,
                    in_calibration: false,
                });
            };
            let d = dist(p, q);
            if d.is_nan() || d > ANCHOR_TOLERANCE_M {
                return Err(AnchorCheckError::Moved {
                    calibration: calib_path.to_owned(),
                    anchors: anchors_origin.to_owned(),
                    id,
                    distance_m: d,
                });
            }
        }
        if let Some(&id) = self.anchors.keys().find(|id| !other.contains_key(id)) {
            return Err(AnchorCheckError::Missing {
                calibration: calib_path.to_owned(),
                anchors: anchors_origin.to_owned(),
                id,
                in_calibration: true,
            });
        }
        Ok(())
    }

    /// The calibration as TOML text.
    ///
    /// # Errors
    /// The serialiser's message (not expected for a learnt calibration).
    pub fn to_toml(&self) -> Result<String, String> {
        let (cell_m, min_count, shrink_count, weight, bilinear) = match &self.family {
            Family::PairConstant => (None, None, None, None, None),
            Family::Grid(g) => (
                Some(g.cell_m),
                Some(g.min_count),
                Some(g.shrink_count),
                Some(g.weight),
                Some(g.bilinear),
            ),
        };
        let file = FileRepr {
            format_version: FORMAT_VERSION,
            site: SiteRepr {
                family: self.family.name().to_owned(),
                cell_m,
                min_count,
                shrink_count,
                weight,
                bilinear,
                anchors: self
                    .anchors
                    .iter()
                    .map(|(&id, &pos_m)| AnchorRepr { id, pos_m })
                    .collect(),
            },
            pairs: self
                .pairs
                .iter()
                .map(|(&(a, b), m)| PairRepr {
                    a,
                    b,
                    bias_m: m.bias_m,
                    noise_m: m.noise_m,
                    samples: m.samples,
                    cells: m
                        .cells
                        .iter()
                        .map(|(&(ix, iy), &(bias_m, n))| CellRepr { ix, iy, bias_m, n })
                        .collect(),
                })
                .collect(),
        };
        toml::to_string(&file).map_err(|e| e.to_string())
    }

    /// Writes the calibration into `path` (TOML).
    ///
    /// # Errors
    /// [`SaveError`] naming the file.
    pub fn save(&self, path: &Path) -> Result<(), SaveError> {
        let text = self.to_toml().map_err(|message| SaveError::Serialize {
            path: path.to_owned(),
            message,
        })?;
        let header = "# insuwb site calibration of the UWB TDOA errors (insuwb calibrate).\n\
                      # Per pair (a < b): bias of the measured |p - b| - |p - a| over the true one.\n";
        std::fs::write(path, format!("{header}{text}")).map_err(|error| SaveError::Write {
            path: path.to_owned(),
            error,
        })
    }

    /// Reads a calibration file.
    ///
    /// # Errors
    /// [`LoadError`] naming the file (and the key at fault).
    pub fn load(path: &Path) -> Result<Self, LoadError> {
        let text = std::fs::read_to_string(path).map_err(|error| LoadError::Read {
            path: path.to_owned(),
            error,
        })?;
        Self::from_toml(&text, &path.display().to_string())
    }

    /// Parses a calibration from TOML text; `origin` names it in errors.
    ///
    /// # Errors
    /// [`LoadError`] naming `origin` (and the key at fault).
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, LoadError> {
        let invalid = |key: String, reason: String| LoadError::Invalid {
            origin: origin.to_owned(),
            key,
            reason,
        };
        // The version first, so that a newer file is named as such.
        #[derive(Deserialize)]
        struct Version {
            format_version: Option<u32>,
        }
        let v: Version = toml::from_str(text).map_err(|e| LoadError::Parse {
            origin: origin.to_owned(),
            message: e.to_string(),
        })?;
        match v.format_version {
            Some(FORMAT_VERSION) => {}
            Some(found) => {
                return Err(LoadError::Version {
                    origin: origin.to_owned(),
                    found,
                })
            }
            None => return Err(invalid("format_version".into(), "missing".into())),
        }
        let f: FileRepr = toml::from_str(text).map_err(|e| LoadError::Parse {
            origin: origin.to_owned(),
            message: e.to_string(),
        })?;
        let s = &f.site;
        let family = match s.family.as_str() {
            "pair_constant" => Family::PairConstant,
            "grid" => {
                let d = GridParams::default();
                Family::Grid(GridParams {
                    cell_m: s
                        .cell_m
                        .ok_or_else(|| invalid("site.cell_m".into(), "missing".into()))?,
                    min_count: s.min_count.unwrap_or(d.min_count),
                    shrink_count: s.shrink_count.unwrap_or(d.shrink_count),
                    // A file without it was learnt with the cells' whole
                    // departure.
                    weight: s.weight.unwrap_or(1.0),
                    bilinear: s.bilinear.unwrap_or(d.bilinear),
                })
            }
            other => {
                return Err(invalid(
                    "site.family".into(),
                    format!("'{other}' is not a family (pair_constant, grid)"),
                ))
            }
        };
        family
            .validate()
            .map_err(|(key, reason)| invalid(format!("site.{key}"), reason))?;
        let mut anchors = BTreeMap::new();
        for (i, a) in s.anchors.iter().enumerate() {
            if !a.pos_m.iter().all(|v| v.is_finite()) {
                return Err(invalid(
                    format!("site.anchors[{i}].pos_m"),
                    "not finite".into(),
                ));
            }
            if anchors.insert(a.id, a.pos_m).is_some() {
                return Err(invalid(
                    format!("site.anchors[{i}].id"),
                    format!("anchor {} given twice", a.id),
                ));
            }
        }
        if anchors.is_empty() {
            return Err(invalid("site.anchors".into(), "no anchor".into()));
        }
        let mut pairs = BTreeMap::new();
        for (i, p) in f.pairs.iter().enumerate() {
            let key = |k: &str| format!("pairs[{i}].{k}");
            for id in [p.a, p.b] {
                if !anchors.contains_key(&id) {
                    return Err(invalid(
                        key(if id == p.a { "a" } else { "b" }),
                        format!("anchor {id} is not in site.anchors"),
                    ));
                }
            }
            if p.a == p.b {
                return Err(invalid(
                    key("b"),
                    format!("pairs anchor {} with itself", p.a),
                ));
            }
            for (k, v) in [("bias_m", p.bias_m), ("noise_m", p.noise_m)] {
                if !v.is_finite() {
                    return Err(invalid(key(k), format!("not finite ({v})")));
                }
            }
            let (k, sign) = key_of(p.a, p.b);
            let mut cells = BTreeMap::new();
            for (j, c) in p.cells.iter().enumerate() {
                if !c.bias_m.is_finite() {
                    return Err(invalid(
                        key(&format!("cells[{j}].bias_m")),
                        format!("not finite ({})", c.bias_m),
                    ));
                }
                cells.insert((c.ix, c.iy), (sign * c.bias_m, c.n));
            }
            let model = PairModel {
                bias_m: sign * p.bias_m,
                noise_m: p.noise_m,
                samples: p.samples,
                cells,
            };
            if pairs.insert(k, model).is_some() {
                return Err(invalid(
                    key("b"),
                    format!("pair ({}, {}) given twice (in either order)", p.a, p.b),
                ));
            }
        }
        Ok(Self {
            anchors,
            family,
            pairs,
        })
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileRepr {
    format_version: u32,
    site: SiteRepr,
    #[serde(default)]
    pairs: Vec<PairRepr>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SiteRepr {
    family: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cell_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    min_count: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shrink_count: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    weight: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    bilinear: Option<bool>,
    anchors: Vec<AnchorRepr>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AnchorRepr {
    id: u32,
    pos_m: [f64; 3],
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PairRepr {
    a: u32,
    b: u32,
    bias_m: f64,
    noise_m: f64,
    #[serde(default)]
    samples: u64,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    cells: Vec<CellRepr>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CellRepr {
    ix: i32,
    iy: i32,
    bias_m: f64,
    n: u32,
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use insuwb_msg::Header;
    use rand::{RngExt as _, SeedableRng as _};
    use rand_xoshiro::Xoshiro256StarStar;

    use super::*;

    fn anchors() -> BTreeMap<u32, [f64; 3]> {
        [
            (0, [-4.0, -4.0, 0.2]),
            (1, [-4.0, 4.0, 3.0]),
            (2, [4.0, 4.0, 0.2]),
            (3, [4.0, -4.0, 3.0]),
        ]
        .into_iter()
        .collect()
    }

    /// The true bias of pair (lo, hi): a constant per pair plus a slope in x.
    fn true_bias(a: u32, b: u32, p: &[f64; 3]) -> f64 {
        let (k, s) = key_of(a, b);
        s * (0.05 * f64::from(k.0 + 1) - 0.03 * f64::from(k.1) + 0.04 * p[0])
    }

    fn samples() -> Vec<Sample> {
        // Seeded uniform noise in [-0.5, 0.5) (xoshiro256**).
        let mut rng = Xoshiro256StarStar::seed_from_u64(1);
        let mut noise = || rng.random::<f64>() - 0.5;
        let mut out = Vec::new();
        let mut i = 0u64;
        for ix in -30..30 {
            for iy in -30..30 {
                let p = [f64::from(ix) * 0.1 + 0.05, f64::from(iy) * 0.1 + 0.05, 1.0];
                for (a, b) in [(0, 1), (2, 1), (2, 3), (3, 0)] {
                    i += 1;
                    // 5 % gross outliers of +2 m.
                    let gross = if i.is_multiple_of(20) { 2.0 } else { 0.0 };
                    out.push(Sample {
                        a,
                        b,
                        pos_m: p,
                        residual_m: true_bias(a, b, &p) + 0.1 * noise() + gross,
                    });
                }
            }
        }
        out
    }

    fn meas(a: u32, b: u32, diff_m: f64) -> UwbTdoa {
        let an = anchors();
        UwbTdoa {
            header: Header::new(0, 0),
            anchor_a: a,
            anchor_b: b,
            diff_m,
            anchor_a_pos_m: an[&a],
            anchor_b_pos_m: an[&b],
        }
    }

    #[test]
    fn a_position_dependent_bias_is_recovered() {
        let s = samples();
        let grid = Family::Grid(GridParams {
            cell_m: 0.5,
            min_count: 5,
            shrink_count: 0.0,
            weight: 1.0,
            bilinear: true,
        });
        let c = SiteCalibration::learn(anchors(), grid, &s).unwrap();
        let k = SiteCalibration::learn(anchors(), Family::PairConstant, &s).unwrap();
        let half = Family::Grid(GridParams {
            cell_m: 0.5,
            min_count: 5,
            shrink_count: 0.0,
            weight: 0.5,
            bilinear: true,
        });
        let h = SiteCalibration::learn(anchors(), half, &s).unwrap();
        assert_eq!(c.pairs().len(), 4);
        for p in [[-2.2, 1.3, 1.0], [0.4, -0.7, 1.0], [2.0, 2.0, 1.0]] {
            for (a, b) in [(0, 1), (1, 2), (2, 3), (0, 3)] {
                let want = true_bias(a, b, &p);
                let got = c.bias(a, b, Some(&p));
                assert!(
                    (got - want).abs() < 0.02,
                    "{a}-{b} at {p:?}: {got} vs {want}"
                );
                // The constant is the median over the area: the bias at x = 0.
                let at0 = true_bias(a, b, &[0.0, 0.0, 0.0]);
                assert!((k.bias(a, b, Some(&p)) - at0).abs() < 0.02);
                assert!((c.bias(a, b, None) - at0).abs() < 0.02);
                // Half the cells' departure from the constant.
                let mid = 0.5 * (c.bias(a, b, Some(&p)) + k.bias(a, b, Some(&p)));
                assert!((h.bias(a, b, Some(&p)) - mid).abs() < 1e-9);
            }
        }
        // Noise: uniform 0.1 m wide, SD 0.029 (robust SD about 0.037).
        let n = c.noise(0, 1).unwrap();
        assert!((0.02..0.05).contains(&n), "{n}");
    }

    #[test]
    fn the_reversed_pair_has_the_opposite_bias() {
        let c = SiteCalibration::learn(anchors(), Family::PairConstant, &samples()).unwrap();
        let p = [1.0, 1.0, 1.0];
        for (a, b) in [(0, 1), (1, 2), (2, 3), (0, 3)] {
            assert_eq!(c.bias(a, b, Some(&p)), -c.bias(b, a, Some(&p)));
            assert_ne!(c.bias(a, b, Some(&p)), 0.0);
        }
        let ab = c.correct(&meas(0, 1, 1.0), Some(&p));
        let ba = c.correct(&meas(1, 0, -1.0), Some(&p));
        assert!((ab.diff_m + ba.diff_m).abs() < 1e-12);
        // A pair never learnt: flagged, not changed.
        let c01 = SiteCalibration::learn(
            anchors(),
            Family::PairConstant,
            &samples()
                .into_iter()
                .filter(|s| s.a == 0 || s.b == 0)
                .collect::<Vec<_>>(),
        )
        .unwrap();
        let m = c01.correct(&meas(1, 2, 0.5), None);
        assert_eq!(m.diff_m, 0.5);
        assert_ne!(m.header.flags & UwbTdoa::FLAG_CALIBRATED, 0);
    }

    #[test]
    fn a_flagged_measurement_is_not_corrected_twice() {
        let c = SiteCalibration::learn(anchors(), Family::PairConstant, &samples()).unwrap();
        let m = meas(0, 1, 1.0);
        let once = c.correct(&m, None);
        assert_ne!(once.diff_m, m.diff_m);
        assert_ne!(once.header.flags & UwbTdoa::FLAG_CALIBRATED, 0);
        assert_eq!(c.correct(&once, None), once);
        // Anchors of another constellation: left alone.
        let mut far = m;
        far.anchor_a_pos_m[0] += 0.2;
        assert_eq!(c.correct(&far, None), far);
    }

    #[test]
    fn the_toml_file_round_trips() {
        let dir = std::env::temp_dir().join(format!("insuwb-calib-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for fam in [
            Family::PairConstant,
            Family::Grid(GridParams {
                bilinear: false,
                ..GridParams::default()
            }),
        ] {
            let c = SiteCalibration::learn(anchors(), fam, &samples()).unwrap();
            let path = dir.join("site.toml");
            c.save(&path).unwrap();
            let back = SiteCalibration::load(&path).unwrap();
            assert_eq!(back, c);
        }
        // The file written with (b, a) is read as (a, b) with the sign flipped.
        let text = "format_version = 1\n[site]\nfamily = \"pair_constant\"\nanchors = [{ id = 0, pos_m = [0, 0, 0] }, { id = 1, pos_m = [1, 0, 0] }]\n[[pairs]]\na = 1\nb = 0\nbias_m = 0.1\nnoise_m = 0.2\n";
        let c = SiteCalibration::from_toml(text, "x.toml").unwrap();
        assert_eq!(c.bias(0, 1, None), -0.1);
        // A grid file without `weight` was learnt with the cells' whole
        // departure.
        let old = text.replace("\"pair_constant\"", "\"grid\"\ncell_m = 1.0");
        let c = SiteCalibration::from_toml(&old, "x.toml").unwrap();
        assert!(matches!(c.family(), Family::Grid(g) if g.weight == 1.0));
        let e = SiteCalibration::from_toml(&text.replace("= 1\n[site]", "= 7\n[site]"), "x.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.toml") && e.contains("format_version"), "{e}");
        let e = SiteCalibration::from_toml(&text.replace("b = 0", "b = 5"), "x.toml")
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "x.toml: key 'pairs[0].b': anchor 5 is not in site.anchors"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn other_anchors_are_refused_naming_both_files() {
        let c = SiteCalibration::learn(anchors(), Family::PairConstant, &samples()).unwrap();
        let path = Path::new("site.toml");
        let mut same = anchors();
        same.get_mut(&2).unwrap()[1] += 0.01;
        c.check_anchors(&same, path, "anchors-b.txt").unwrap();
        let mut moved = anchors();
        moved.get_mut(&2).unwrap()[1] += 0.3;
        let e = c
            .check_anchors(&moved, path, "anchors-b.txt")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("site.toml") && e.contains("anchors-b.txt") && e.contains("anchor 2"),
            "{e}"
        );
        assert!(e.contains("0.300 m"), "{e}");
        let mut fewer = anchors();
        fewer.remove(&3);
        let e = c
            .check_anchors(&fewer, path, "anchors-b.txt")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("anchor 3 is in site.toml but not in anchors-b.txt"),
            "{e}"
        );
        let mut more = anchors();
        more.insert(9, [0.0; 3]);
        let e = c
            .check_anchors(&more, path, "anchors-b.txt")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("anchor 9 is in anchors-b.txt but not in site.toml"),
            "{e}"
        );
    }

    #[test]
    fn bad_settings_are_refused() {
        let d = GridParams::default();
        for (bad, key) in [
            (GridParams { cell_m: 0.0, ..d }, "cell_m"),
            (GridParams { weight: 1.5, ..d }, "weight"),
            (GridParams { weight: -0.1, ..d }, "weight"),
        ] {
            let e = SiteCalibration::learn(anchors(), Family::Grid(bad), &samples()).unwrap_err();
            assert!(
                matches!(e, LearnError::Family { key: k, .. } if k == key),
                "{e}"
            );
        }
        let e = SiteCalibration::learn(anchors(), Family::PairConstant, &[]).unwrap_err();
        assert_eq!(e, LearnError::TooFewSamples { samples: 0 });
    }
}
