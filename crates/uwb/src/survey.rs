//! A survey check over a flight's TDOA residuals: how far the radio's frame
//! sits from the reference's, then each anchor's offset.
//!
//! From the residuals of a flight with ground truth ([`Sample`]s: measured
//! minus true difference at the antenna position):
//!
//! - [`frame_offset`]: the one translation `t` of the tag that explains the
//!   residuals best. A difference read at `p + t` instead of `p` is off by
//!   `g · t`, `g` the gradient of `|p - b| - |p - a|` at `p`; `t` is the
//!   least-squares solution over every sample, then reweighted (Huber, at
//!   1.5 robust SDs of what it leaves) so that NLOS stretches do not pull
//!   it; each pair's gross outliers are left out first, as
//!   [`crate::calibration`] leaves them out. An anchor survey
//!   whose origin is not the reference's (or a reference frame moved
//!   between flights) shows here, for the whole flight, and no estimator
//!   without the reference can tell it from the position.
//! - [`anchor_offsets`]: each pair's median residual, then by least squares
//!   weighted by the pairs' sample counts one offset per anchor with
//!   `median(a, b) = o_b - o_a`, the offsets' mean zero (differences do
//!   not see an offset common to every anchor). Two anchors read long by
//!   the same amount leave their difference as it was, one anchor read
//!   long (its surveyed position off, its antenna delay changed) shifts
//!   every difference it is in. Taken on the residuals less the frame's
//!   offset ([`remove_frame_offset`]), a whole constellation's shift is not
//!   blamed on the anchors it pulls furthest. The two are fitted in that
//!   order, the simpler explanation first: solved jointly, a translation
//!   and eight offsets trade against each other over one flight's
//!   geometry (on the UTIL flights by up to a metre).
//!
//! [`check`] runs both in that order. Either is a flight's bias that a site
//! calibration learns, and one no filter can tell from the position within
//! the flight.
//!
//! Written here, not with a crate: two weighted least-squares fits (a 3 x 3
//! normal matrix; the anchor graph's Laplacian), a few lines of nalgebra.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use crate::calibration::{gross_gate, median_of, robust_sd, Sample};

/// Fewest samples of a pair for its median to count.
pub const MIN_PAIR_SAMPLES: usize = 20;

/// Why no offsets came out of the samples.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnchorOffsetsError {
    /// No anchor pair holds [`MIN_PAIR_SAMPLES`] finite residuals.
    #[error("no anchor pair has {MIN_PAIR_SAMPLES} residuals")]
    NoPairs,
    /// Two anchors that no chain of measured pairs joins: their offsets
    /// are not related by the differences.
    #[error("anchors {0} and {1} are joined by no chain of measured pairs")]
    NotConnected(u32, u32),
}

/// Why a frame offset could not be solved.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameOffsetError {
    /// No anchor pair holds [`MIN_PAIR_SAMPLES`] finite residuals of
    /// surveyed anchors.
    #[error("no anchor pair has {MIN_PAIR_SAMPLES} residuals of surveyed anchors")]
    NoPairs,
    /// The samples' geometry does not fix a translation in every direction
    /// (the tag and the anchors in one plane, say).
    #[error("the flight's geometry does not fix a translation in every direction")]
    Degenerate,
}

/// A flight's frame offset ([`frame_offset`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameOffset {
    /// Where the radio places the tag less where the reference has it
    /// (ENU, m).
    pub offset_m: [f64; 3],
    /// RMS of the residuals used, before the offset is taken out (m).
    pub rms_before_m: f64,
    /// RMS of the same residuals after (m).
    pub rms_after_m: f64,
    /// Residuals used.
    pub samples: usize,
}

/// Smallest eigenvalue of the normal matrix per sample below which the
/// geometry is taken not to fix a translation (a unit translation along
/// that direction moves the differences by less than 0.05 m RMS).
const MIN_INFORMATION: f64 = 0.0025;

/// Huber threshold of the frame fit, in robust SDs of the residuals.
const HUBER_K: f64 = 1.5;

/// Reweighted rounds of the frame fit after its least-squares start.
const HUBER_ROUNDS: usize = 10;

/// The gradient of `|p - b| - |p - a|` at `p` (`None` at an anchor).
fn gradient(p: &[f64; 3], a: &[f64; 3], b: &[f64; 3]) -> Option<Vector3<f64>> {
    let p = Vector3::from(*p);
    let (da, db) = (p - Vector3::from(*a), p - Vector3::from(*b));
    let (na, nb) = (da.norm(), db.norm());
    (na > 1e-9 && nb > 1e-9).then(|| db / nb - da / na)
}

/// The translation of the tag that explains the residuals `samples` best
/// (anchor positions `anchors`; samples of other anchors are left out).
///
/// # Errors
/// [`FrameOffsetError`] when no pair has enough residuals or the geometry
/// does not fix a translation.
pub fn frame_offset(
    samples: &[Sample],
    anchors: &BTreeMap<u32, [f64; 3]>,
) -> Result<FrameOffset, FrameOffsetError> {
    // The gross outliers of each pair, as the calibration leaves them out.
    let mut by_pair: BTreeMap<(u32, u32), Vec<f64>> = BTreeMap::new();
    let usable = |s: &&Sample| {
        s.a != s.b
            && s.residual_m.is_finite()
            && s.pos_m.iter().all(|v| v.is_finite())
            && anchors.contains_key(&s.a)
            && anchors.contains_key(&s.b)
    };
    for s in samples.iter().filter(usable) {
        let (key, r) = oriented(s);
        by_pair.entry(key).or_default().push(r);
    }
    let mut gates = BTreeMap::new();
    for (key, mut v) in by_pair {
        if v.len() < MIN_PAIR_SAMPLES {
            continue;
        }
        if let Some(gate) = gross_gate(&mut v) {
            gates.insert(key, gate);
        }
    }
    let mut used = Vec::new();
    for s in samples.iter().filter(usable) {
        let (key, r) = oriented(s);
        let Some((centre, gate)) = gates.get(&key) else {
            continue;
        };
        if (r - centre).abs() > *gate {
            continue;
        }
        let (Some(pa), Some(pb)) = (anchors.get(&s.a), anchors.get(&s.b)) else {
            continue;
        };
        if let Some(g) = gradient(&s.pos_m, pa, pb) {
            used.push((g, s.residual_m));
        }
    }
    if used.is_empty() {
        return Err(FrameOffsetError::NoPairs);
    }
    #[allow(clippy::cast_precision_loss)]
    let n = used.len() as f64;
    // Least squares, then Huber weights at HUBER_K robust SDs of the
    // residuals left: a flight's NLOS stretches do not pull the frame.
    let mut t = Vector3::<f64>::zeros();
    for round in 0..=HUBER_ROUNDS {
        let scale = if round == 0 {
            f64::INFINITY
        } else {
            let after: Vec<f64> = used.iter().map(|(g, r)| r - g.dot(&t)).collect();
            HUBER_K * robust_sd(&after, 0.0)
        };
        let mut info = Matrix3::<f64>::zeros();
        let mut rhs = Vector3::<f64>::zeros();
        for (g, r) in &used {
            let e = (r - g.dot(&t)).abs();
            let w = if e > scale { scale / e } else { 1.0 };
            info += g * g.transpose() * w;
            rhs += g * (r * w);
        }
        if round == 0 {
            let smallest = info.symmetric_eigenvalues().min() / n;
            if smallest.is_nan() || smallest <= MIN_INFORMATION {
                return Err(FrameOffsetError::Degenerate);
            }
        }
        t = info
            .cholesky()
            .map(|c| c.solve(&rhs))
            .ok_or(FrameOffsetError::Degenerate)?;
    }
    let (mut before, mut after) = (0.0, 0.0);
    for (g, r) in &used {
        before += r * r;
        after += (r - g.dot(&t)).powi(2);
    }
    Ok(FrameOffset {
        offset_m: [t.x, t.y, t.z],
        rms_before_m: (before / n).sqrt(),
        rms_after_m: (after / n).sqrt(),
        samples: used.len(),
    })
}

/// The residuals `samples` less what the frame offset `offset_m` explains
/// of each (`g · t`); samples of anchors not in `anchors` (or at an anchor)
/// are kept as they are.
#[must_use]
pub fn remove_frame_offset(
    samples: &[Sample],
    anchors: &BTreeMap<u32, [f64; 3]>,
    offset_m: &[f64; 3],
) -> Vec<Sample> {
    let t = Vector3::from(*offset_m);
    samples
        .iter()
        .map(|s| {
            let g = anchors
                .get(&s.a)
                .zip(anchors.get(&s.b))
                .and_then(|(pa, pb)| gradient(&s.pos_m, pa, pb));
            Sample {
                residual_m: s.residual_m - g.map_or(0.0, |g| g.dot(&t)),
                ..*s
            }
        })
        .collect()
}

/// A flight's survey check: its frame offset, then each anchor's offset
/// on what the frame leaves (on the residuals themselves where no frame
/// could be solved).
#[derive(Debug, Clone, PartialEq)]
pub struct SurveyCheck {
    /// The frame offset ([`frame_offset`]).
    pub frame: Result<FrameOffset, FrameOffsetError>,
    /// Each anchor's offset ([`anchor_offsets`]) after the frame's.
    pub anchors: Result<BTreeMap<u32, f64>, AnchorOffsetsError>,
}

/// The survey check of one flight's residuals `samples` (anchor positions
/// `anchors`): the frame first, the simpler explanation, then the anchors.
#[must_use]
pub fn check(samples: &[Sample], anchors: &BTreeMap<u32, [f64; 3]>) -> SurveyCheck {
    let frame = frame_offset(samples, anchors);
    let anchors = match &frame {
        Ok(f) => anchor_offsets(&remove_frame_offset(samples, anchors, &f.offset_m)),
        Err(_) => anchor_offsets(samples),
    };
    SurveyCheck { frame, anchors }
}

/// A sample's pair key (lower id first) and its residual in that order.
fn oriented(s: &Sample) -> ((u32, u32), f64) {
    if s.a < s.b {
        ((s.a, s.b), s.residual_m)
    } else {
        ((s.b, s.a), -s.residual_m)
    }
}

/// Each anchor's offset (m, positive: its ranges read long) over the
/// residuals `samples`, the offsets' mean zero; only anchors of pairs with
/// at least [`MIN_PAIR_SAMPLES`] finite residuals appear.
///
/// # Errors
/// [`AnchorOffsetsError`] when no pair has enough residuals or the measured
/// pairs do not join every anchor.
pub fn anchor_offsets(samples: &[Sample]) -> Result<BTreeMap<u32, f64>, AnchorOffsetsError> {
    // Residuals per pair, oriented from the lower id to the higher.
    let mut pairs: BTreeMap<(u32, u32), Vec<f64>> = BTreeMap::new();
    for s in samples {
        if s.a == s.b || !s.residual_m.is_finite() {
            continue;
        }
        let (key, r) = oriented(s);
        pairs.entry(key).or_default().push(r);
    }
    let medians: Vec<((u32, u32), f64, f64)> = pairs
        .into_iter()
        .filter(|(_, v)| v.len() >= MIN_PAIR_SAMPLES)
        .filter_map(|(k, mut v)| {
            #[allow(clippy::cast_precision_loss)]
            let n = v.len() as f64;
            median_of(&mut v).map(|m| (k, m, n))
        })
        .collect();
    if medians.is_empty() {
        return Err(AnchorOffsetsError::NoPairs);
    }
    let ids: Vec<u32> = medians
        .iter()
        .flat_map(|((a, b), _, _)| [*a, *b])
        .collect::<std::collections::BTreeSet<u32>>()
        .into_iter()
        .collect();
    let index = |id: u32| ids.binary_search(&id).unwrap_or(0);
    check_connected(&ids, &medians, index)?;
    let k = ids.len();
    let mut lap = DMatrix::<f64>::zeros(k, k);
    let mut rhs = DVector::<f64>::zeros(k);
    let mut total = 0.0;
    for ((a, b), m, w) in &medians {
        let (i, j) = (index(*a), index(*b));
        lap[(i, i)] += w;
        lap[(j, j)] += w;
        lap[(i, j)] -= w;
        lap[(j, i)] -= w;
        rhs[j] += w * m;
        rhs[i] -= w * m;
        total += w;
    }
    // The offsets' mean is free: pin it to zero with a rank-one term (the
    // right-hand side sums to zero, so the solution does too).
    #[allow(clippy::cast_precision_loss)]
    let pin = total / k as f64;
    lap.add_scalar_mut(pin);
    let o = lap
        .cholesky()
        .map(|c| c.solve(&rhs))
        .ok_or(AnchorOffsetsError::NoPairs)?;
    Ok(ids.iter().zip(o.iter()).map(|(id, v)| (*id, *v)).collect())
}

/// Every anchor joined to the first by a chain of pairs (union-find).
fn check_connected(
    ids: &[u32],
    pairs: &[((u32, u32), f64, f64)],
    index: impl Fn(u32) -> usize,
) -> Result<(), AnchorOffsetsError> {
    let mut parent: Vec<usize> = (0..ids.len()).collect();
    fn root(parent: &[usize], mut i: usize) -> usize {
        while let Some(&p) = parent.get(i) {
            if p == i {
                break;
            }
            i = p;
        }
        i
    }
    for ((a, b), _, _) in pairs {
        let (ra, rb) = (root(&parent, index(*a)), root(&parent, index(*b)));
        if let Some(p) = parent.get_mut(ra) {
            *p = rb;
        }
    }
    let first = root(&parent, 0);
    for (i, id) in ids.iter().enumerate() {
        if root(&parent, i) != first {
            return Err(AnchorOffsetsError::NotConnected(
                ids.first().copied().unwrap_or(0),
                *id,
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(a: u32, b: u32, r: f64) -> Sample {
        Sample {
            a,
            b,
            pos_m: [0.0; 3],
            residual_m: r,
        }
    }

    /// Six anchors on a ring with two chords, anchor 3 reading 0.4 m long
    /// and anchor 5 0.1 m short, each pair's residuals spread about their
    /// true value (some given in the other orientation): the offsets come
    /// back, less their mean.
    #[test]
    fn a_long_anchor_is_found() {
        let truth = [0.0, 0.0, 0.0, 0.4, 0.0, -0.1];
        let mut s = Vec::new();
        for (a, b) in [
            (0, 1),
            (1, 2),
            (2, 3),
            (3, 4),
            (4, 5),
            (5, 0),
            (0, 3),
            (1, 4),
        ] {
            for k in 0..41 {
                let noise = (f64::from(k) - 20.0) * 0.01;
                let r = truth[b as usize] - truth[a as usize] + noise;
                s.push(if k % 3 == 0 {
                    sample(b, a, -r)
                } else {
                    sample(a, b, r)
                });
            }
        }
        // Gross outliers on both sides do not move a median.
        s.extend((0..6).map(|k| sample(0, 1, if k % 2 == 0 { 5.0 } else { -5.0 })));
        let o = anchor_offsets(&s).unwrap();
        let mean = truth.iter().sum::<f64>() / 6.0;
        assert_eq!(o.len(), 6);
        for (id, v) in &o {
            assert!(
                (v - (truth[*id as usize] - mean)).abs() < 1e-9,
                "anchor {id}: {v}"
            );
        }
        assert!(o.values().sum::<f64>().abs() < 1e-12);
    }

    /// Eight anchors at two heights, as a UTIL constellation.
    fn constellation(z_low: f64, z_high: f64) -> BTreeMap<u32, [f64; 3]> {
        let corners = [(-3.0, -4.0), (-3.2, 3.7), (3.7, 3.7), (4.1, -4.2)];
        let mut a = BTreeMap::new();
        for (i, (x, y)) in corners.iter().enumerate() {
            a.insert(2 * i as u32, [*x, *y, z_low]);
            a.insert(2 * i as u32 + 1, [x * 0.95, y * 0.95, z_high]);
        }
        a
    }

    /// A flight over a lawnmower path at 1-2 m whose radio places the tag
    /// at `t` from where it is, plus `extra(a, b)` per pair, with seeded
    /// noise and one NLOS stretch of +1.5 m on one pair.
    fn translated_flight(
        anchors: &BTreeMap<u32, [f64; 3]>,
        t: [f64; 3],
        extra: impl Fn(u32, u32) -> f64,
    ) -> Vec<Sample> {
        use crate::calibration::true_difference;
        let mut out = Vec::new();
        let mut k = 0u32;
        for step in 0..600 {
            let s = f64::from(step) * 0.01;
            let p = [
                -2.0 + 4.0 * (s * 0.7).sin(),
                -2.0 + 0.7 * s,
                1.5 + 0.5 * (s * 1.3).sin(),
            ];
            let moved = [p[0] + t[0], p[1] + t[1], p[2] + t[2]];
            for a in 0..8u32 {
                let b = (a + 1) % 8;
                k += 1;
                let noise = f64::from(k.wrapping_mul(2_654_435_761) % 1000) / 1000.0 - 0.5;
                let nlos = if a == 3 && (200..260).contains(&step) {
                    1.5
                } else {
                    0.0
                };
                let r = true_difference(&moved, &anchors[&a], &anchors[&b])
                    - true_difference(&p, &anchors[&a], &anchors[&b])
                    + extra(a, b)
                    + 0.2 * noise
                    + nlos;
                out.push(Sample {
                    a,
                    b,
                    pos_m: p,
                    residual_m: r,
                });
            }
        }
        out
    }

    /// A translation of the whole frame comes back to a centimetre
    /// through noise and an NLOS stretch; taken out, what is left of the
    /// residuals is the noise, and no anchor is blamed for it.
    #[test]
    fn a_moved_frame_is_found_and_not_blamed_on_anchors() {
        let anchors = constellation(0.2, 3.0);
        let t = [0.15, 0.08, -0.65];
        let s = translated_flight(&anchors, t, |_, _| 0.0);
        let f = frame_offset(&s, &anchors).unwrap();
        for (got, want) in f.offset_m.iter().zip(t) {
            assert!((got - want).abs() < 0.01, "{:?}", f.offset_m);
        }
        assert!(f.rms_after_m < 0.5 * f.rms_before_m, "{f:?}");
        // The anchors would read up to tenths of a metre off without it.
        let blamed = anchor_offsets(&s).unwrap();
        assert!(blamed.values().any(|v| v.abs() > 0.2), "{blamed:?}");
        let rest = remove_frame_offset(&s, &anchors, &f.offset_m);
        let o = anchor_offsets(&rest).unwrap();
        assert!(o.values().all(|v| v.abs() < 0.02), "{o:?}");
    }

    /// One anchor read long on top of a moved frame is still the anchor
    /// furthest off once the frame is taken out (the frame takes up part
    /// of it: the simpler explanation is fitted first).
    #[test]
    fn an_anchor_off_in_a_moved_frame_is_still_found() {
        let anchors = constellation(0.2, 3.0);
        let offset = |id: u32| if id == 5 { 0.4 } else { 0.0 };
        let s = translated_flight(&anchors, [0.0, 0.1, -0.3], |a, b| offset(b) - offset(a));
        let o = check(&s, &anchors).anchors.unwrap();
        let (worst, v) = o
            .iter()
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
            .unwrap();
        assert_eq!(*worst, 5, "{o:?}");
        assert!((0.2..0.45).contains(v), "{o:?}");
    }

    /// The tag and every anchor in one plane: no translation out of it.
    #[test]
    fn a_flat_geometry_is_refused() {
        let anchors = constellation(1.5, 1.5);
        let flat: Vec<Sample> = translated_flight(&anchors, [0.1, 0.0, 0.0], |_, _| 0.0)
            .into_iter()
            .map(|s| Sample {
                pos_m: [s.pos_m[0], s.pos_m[1], 1.5],
                ..s
            })
            .collect();
        assert_eq!(
            frame_offset(&flat, &anchors),
            Err(FrameOffsetError::Degenerate)
        );
        assert_eq!(
            frame_offset(&flat, &BTreeMap::new()),
            Err(FrameOffsetError::NoPairs)
        );
        assert_eq!(frame_offset(&[], &anchors), Err(FrameOffsetError::NoPairs));
    }

    #[test]
    fn pairs_that_join_nothing_and_empty_input_are_refused() {
        let mut s: Vec<Sample> = (0..30).map(|_| sample(0, 1, 0.1)).collect();
        s.extend((0..30).map(|_| sample(2, 3, 0.1)));
        assert_eq!(
            anchor_offsets(&s),
            Err(AnchorOffsetsError::NotConnected(0, 2))
        );
        assert_eq!(anchor_offsets(&[]), Err(AnchorOffsetsError::NoPairs));
        let few: Vec<Sample> = (0..5).map(|_| sample(0, 1, 0.1)).collect();
        assert_eq!(anchor_offsets(&few), Err(AnchorOffsetsError::NoPairs));
        let nan: Vec<Sample> = (0..30).map(|_| sample(0, 1, f64::NAN)).collect();
        assert_eq!(anchor_offsets(&nan), Err(AnchorOffsetsError::NoPairs));
    }
}
