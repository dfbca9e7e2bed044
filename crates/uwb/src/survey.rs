//! Each anchor's offset over a flight's TDOA residuals: a survey check.
//!
//! Two anchors read too long by the same amount leave a difference
//! `|p - b| - |p - a|` as it was, but one anchor read long (its surveyed
//! position off, its antenna delay changed, the tag's frame shifted against
//! the survey's) shifts every difference it is in. From the residuals of a
//! flight with ground truth ([`Sample`]s: measured minus true difference),
//! [`anchor_offsets`] takes each pair's median residual and solves, by least
//! squares weighted by the pairs' sample counts, for one offset per anchor
//! with `median(a, b) = o_b - o_a`, the offsets' mean zero (differences do
//! not see an offset common to every anchor). An anchor far from the others
//! over a whole flight is one a site calibration learns as that flight's
//! bias, and one no filter can tell from the position within the flight.
//!
//! Written here, not with a crate: a weighted least-squares fit on the
//! anchor graph's Laplacian, a few lines of nalgebra.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};

use crate::calibration::{median_of, Sample};

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
        let (key, r) = if s.a < s.b {
            ((s.a, s.b), s.residual_m)
        } else {
            ((s.b, s.a), -s.residual_m)
        };
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
