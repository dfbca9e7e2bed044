//! Accuracy metrics against ground truth, all solutions at the same epochs.
//!
//! Every solution (UWB-only, INS-only, each filter) is evaluated at the UWB
//! measurement epochs, with ground truth interpolated there, so the numbers
//! of one table are comparable row by row. The metrics are those of the
//! paper's Table 1 (per-axis RMSE, their mean, signed error ranges), plus the
//! horizontal RMS distance error, the maximum distance error, NEES and NIS.

use insuwb_msg::GroundTruth;
use serde::Serialize;

/// One solution's estimate at one epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Epoch (ns, same clock as the truth).
    pub t_ns: u64,
    /// East, north position (m).
    pub pos_en_m: [f64; 2],
    /// Up (m): the solution's height, on the truth's vertical datum.
    pub up_m: f64,
    /// East, north velocity (m/s), when the solution has one.
    pub vel_en_mps: Option<[f64; 2]>,
    /// Covariance of `[pe, pn, ve, vn]`, when the solution has one (for NEES).
    pub cov4: Option<[[f64; 4]; 4]>,
    /// Heading (rad, ENU: 0 east, counter-clockwise), when the solution has one.
    pub yaw_rad: Option<f64>,
}

/// Why metrics could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    /// No estimate lies inside the truth's time span (and the segment).
    #[error(
        "no estimate overlaps the ground truth (estimates: {estimates}, truth samples: {truth})"
    )]
    NoOverlap {
        /// Estimates given.
        estimates: usize,
        /// Truth samples given.
        truth: usize,
    },
    /// An estimate holds a NaN or infinity.
    #[error("estimate at t = {t_ns} ns is not finite")]
    NonFinite {
        /// Its epoch.
        t_ns: u64,
    },
}

/// The metrics of one solution (metres; ranges are signed errors, estimate minus truth).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Metrics {
    /// RMSE of the east error.
    pub rmse_east: f64,
    /// RMSE of the north error.
    pub rmse_north: f64,
    /// Mean of the east and north RMSE (Table 1's "Mean", erratum 18).
    pub rmse_mean: f64,
    /// RMS of the horizontal distance error, sqrt(mean(ex^2 + ey^2)).
    pub rmse_horizontal: f64,
    /// [min, max] of the east error.
    pub range_east: [f64; 2],
    /// [min, max] of the north error.
    pub range_north: [f64; 2],
    /// Largest horizontal distance error.
    pub max_dist: f64,
    /// RMS of the height error (up), over the same epochs.
    pub rmse_up: f64,
    /// Mean NEES over `[pe, pn, ve, vn]`, where the solution has a covariance.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nees_mean: Option<f64>,
    /// Mean NIS of the filter's updates, where it has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nis_mean: Option<f64>,
    /// Times the divergence monitor fired inside the evaluated segment (each
    /// a reset of the filter from the radio), for a filter run; the mean
    /// over runs in [`mean_of`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub divergences: Option<f64>,
    /// Epochs evaluated.
    pub epochs: usize,
}

/// Ground truth, sorted by time, interpolated linearly.
#[derive(Debug, Clone)]
pub struct TruthTrack<'a> {
    truth: &'a [GroundTruth],
    max_gap_ns: u64,
}

impl<'a> TruthTrack<'a> {
    /// Wraps a time-sorted truth stream; interpolation refuses gaps longer than `max_gap_ns`.
    #[must_use]
    pub fn new(truth: &'a [GroundTruth], max_gap_ns: u64) -> Self {
        Self { truth, max_gap_ns }
    }

    /// Position and velocity (ENU) at `t_ns`, or `None` outside the span or across a long gap.
    ///
    /// Velocity is the truth's own when it has one, else the central
    /// difference of the interpolated positions [`TRUTH_VEL_HALF_WINDOW_NS`]
    /// either side (clipped to the span): motion-capture positions are
    /// noisy at the millimetre level, which the slope between two samples
    /// 3-5 ms apart turns into about 0.5 m/s of velocity noise (UTIL logs),
    /// more than the filters' own velocity error. Where the window reaches
    /// across a long gap, the slope between the two samples around `t_ns`.
    #[must_use]
    pub fn at(&self, t_ns: u64) -> Option<([f64; 3], [f64; 3])> {
        let (pos, lo, hi) = self.position(t_ns)?;
        let own = lo.header.flags & hi.header.flags & GroundTruth::FLAG_VEL_VALID != 0;
        if own {
            let w = weight(lo, hi, t_ns);
            return Some((pos, lerp3(lo.vel_mps, hi.vel_mps, w)));
        }
        let (first, last) = self.span()?;
        let a = t_ns.saturating_sub(TRUTH_VEL_HALF_WINDOW_NS).max(first);
        let b = t_ns.saturating_add(TRUTH_VEL_HALF_WINDOW_NS).min(last);
        let windowed = match (self.position(a), self.position(b)) {
            (Some((pa, ..)), Some((pb, ..))) if b > a => {
                let dt = (b - a) as f64 * 1e-9;
                Some([
                    (pb[0] - pa[0]) / dt,
                    (pb[1] - pa[1]) / dt,
                    (pb[2] - pa[2]) / dt,
                ])
            }
            _ => None,
        };
        Some((pos, windowed.unwrap_or_else(|| slope(lo, hi))))
    }

    /// Heading (rad, ENU: 0 east, counter-clockwise) of the truth sample
    /// nearest `t_ns`, where the truth has an attitude (a unit quaternion);
    /// `None` outside the span, across a long gap or without one.
    #[must_use]
    pub fn yaw_at(&self, t_ns: u64) -> Option<f64> {
        let (_, lo, hi) = self.position(t_ns)?;
        let near = if t_ns - lo.header.meas_time_ns.min(t_ns)
            <= hi.header.meas_time_ns.saturating_sub(t_ns)
        {
            lo
        } else {
            hi
        };
        let [w, x, y, z] = near.quat;
        let n2 = w * w + x * x + y * y + z * z;
        if !(0.5..=1.5).contains(&n2) {
            return None;
        }
        Some((2.0 * (w * z + x * y)).atan2(n2 - 2.0 * (y * y + z * z)))
    }

    /// Interpolated position at `t_ns` with the two samples around it.
    fn position(&self, t_ns: u64) -> Option<([f64; 3], &'a GroundTruth, &'a GroundTruth)> {
        let tr = self.truth;
        let idx = tr.partition_point(|g| g.header.meas_time_ns < t_ns);
        let hi = tr.get(idx)?;
        if hi.header.meas_time_ns == t_ns {
            let lo = tr.get(idx.wrapping_sub(1)).unwrap_or(hi);
            return Some((hi.pos_m, lo, hi));
        }
        let lo = tr.get(idx.checked_sub(1)?)?;
        if hi.header.meas_time_ns - lo.header.meas_time_ns > self.max_gap_ns {
            return None;
        }
        Some((lerp3(lo.pos_m, hi.pos_m, weight(lo, hi, t_ns)), lo, hi))
    }

    /// Times of the first and last truth samples.
    #[must_use]
    pub fn span(&self) -> Option<(u64, u64)> {
        Some((
            self.truth.first()?.header.meas_time_ns,
            self.truth.last()?.header.meas_time_ns,
        ))
    }
}

/// Half-width of the window over which a truth velocity is differenced, ns.
pub const TRUTH_VEL_HALF_WINDOW_NS: u64 = 50_000_000;

fn weight(lo: &GroundTruth, hi: &GroundTruth, t_ns: u64) -> f64 {
    let (t0, t1) = (lo.header.meas_time_ns, hi.header.meas_time_ns);
    if t1 > t0 {
        (t_ns.saturating_sub(t0)) as f64 / (t1 - t0) as f64
    } else {
        0.0
    }
}

fn lerp3(a: [f64; 3], b: [f64; 3], w: f64) -> [f64; 3] {
    [
        a[0] + w * (b[0] - a[0]),
        a[1] + w * (b[1] - a[1]),
        a[2] + w * (b[2] - a[2]),
    ]
}

/// The slope between two samples (zero when they share a time).
fn slope(a: &GroundTruth, b: &GroundTruth) -> [f64; 3] {
    if b.header.meas_time_ns > a.header.meas_time_ns {
        let dt = (b.header.meas_time_ns - a.header.meas_time_ns) as f64 * 1e-9;
        [
            (b.pos_m[0] - a.pos_m[0]) / dt,
            (b.pos_m[1] - a.pos_m[1]) / dt,
            (b.pos_m[2] - a.pos_m[2]) / dt,
        ]
    } else {
        [0.0; 3]
    }
}

/// Computes the metrics of `estimates` against `truth`, keeping only epochs
/// inside `segment` (inclusive, ns) when given. `nis` are the filter's NIS
/// values, averaged as they are.
///
/// # Errors
/// [`MetricsError::NonFinite`] for a non-finite estimate, [`MetricsError::NoOverlap`]
/// when no epoch can be evaluated.
pub fn compute(
    estimates: &[Estimate],
    truth: &TruthTrack<'_>,
    segment: Option<(u64, u64)>,
    nis: &[f64],
) -> Result<Metrics, MetricsError> {
    let mut n = 0usize;
    let (mut se, mut sn, mut su) = (0.0, 0.0, 0.0);
    let mut re = [f64::INFINITY, f64::NEG_INFINITY];
    let mut rn = [f64::INFINITY, f64::NEG_INFINITY];
    let mut max_dist: f64 = 0.0;
    let (mut nees_sum, mut nees_n) = (0.0, 0usize);
    for e in estimates {
        if let Some((a, b)) = segment {
            if e.t_ns < a || e.t_ns > b {
                continue;
            }
        }
        if !(e.pos_en_m.iter().all(|v| v.is_finite()) && e.up_m.is_finite()) {
            return Err(MetricsError::NonFinite { t_ns: e.t_ns });
        }
        let Some((tp, tv)) = truth.at(e.t_ns) else {
            continue;
        };
        let ex = e.pos_en_m[0] - tp[0];
        let ey = e.pos_en_m[1] - tp[1];
        let eu = e.up_m - tp[2];
        n += 1;
        se += ex * ex;
        sn += ey * ey;
        su += eu * eu;
        re = [re[0].min(ex), re[1].max(ex)];
        rn = [rn[0].min(ey), rn[1].max(ey)];
        max_dist = max_dist.max(ex.hypot(ey));
        if let (Some(v), Some(cov)) = (e.vel_en_mps, e.cov4) {
            let err = [ex, ey, v[0] - tv[0], v[1] - tv[1]];
            if let Some(q) = quad_form_inv4(&cov, &err) {
                nees_sum += q;
                nees_n += 1;
            }
        }
    }
    if n == 0 {
        return Err(MetricsError::NoOverlap {
            estimates: estimates.len(),
            truth: truth.truth.len(),
        });
    }
    let nf = n as f64;
    let rmse_east = (se / nf).sqrt();
    let rmse_north = (sn / nf).sqrt();
    let nis_f: Vec<f64> = nis.iter().copied().filter(|v| v.is_finite()).collect();
    Ok(Metrics {
        rmse_east,
        rmse_north,
        rmse_mean: 0.5 * (rmse_east + rmse_north),
        rmse_horizontal: ((se + sn) / nf).sqrt(),
        range_east: re,
        range_north: rn,
        max_dist,
        rmse_up: (su / nf).sqrt(),
        nees_mean: (nees_n > 0).then(|| nees_sum / nees_n as f64),
        nis_mean: (!nis_f.is_empty()).then(|| nis_f.iter().sum::<f64>() / nis_f.len() as f64),
        divergences: None,
        epochs: n,
    })
}

/// `e^T C^-1 e` for a 4 x 4 symmetric positive definite `C` (None if it is not).
#[must_use]
pub fn quad_form_inv4(c: &[[f64; 4]; 4], e: &[f64; 4]) -> Option<f64> {
    let m = nalgebra::Matrix4::from_fn(|i, j| c[i][j]);
    let chol = nalgebra::Cholesky::new(m)?;
    let v = nalgebra::Vector4::from_column_slice(e);
    let q = v.dot(&chol.solve(&v));
    q.is_finite().then_some(q)
}

/// Averages metrics over Monte-Carlo runs (field by field; ranges are the mean of the per-run extremes).
#[must_use]
pub fn mean_of(runs: &[Metrics]) -> Option<Metrics> {
    let n = runs.len() as f64;
    let first = runs.first()?;
    let avg = |f: &dyn Fn(&Metrics) -> f64| runs.iter().map(f).sum::<f64>() / n;
    let avg_opt = |f: &dyn Fn(&Metrics) -> Option<f64>| {
        let v: Vec<f64> = runs.iter().filter_map(f).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    let _ = first;
    Some(Metrics {
        rmse_east: avg(&|m| m.rmse_east),
        rmse_north: avg(&|m| m.rmse_north),
        rmse_mean: avg(&|m| m.rmse_mean),
        rmse_horizontal: avg(&|m| m.rmse_horizontal),
        range_east: [avg(&|m| m.range_east[0]), avg(&|m| m.range_east[1])],
        range_north: [avg(&|m| m.range_north[0]), avg(&|m| m.range_north[1])],
        max_dist: avg(&|m| m.max_dist),
        rmse_up: avg(&|m| m.rmse_up),
        nees_mean: avg_opt(&|m| m.nees_mean),
        nis_mean: avg_opt(&|m| m.nis_mean),
        divergences: avg_opt(&|m| m.divergences),
        epochs: runs.iter().map(|m| m.epochs).sum(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::Header;

    fn truth_line() -> Vec<GroundTruth> {
        // Moving east at 1 m/s, sampled every 10 ms for 1 s.
        (0..=100)
            .map(|i| GroundTruth {
                header: Header::new(i, i * 10_000_000),
                pos_m: [i as f64 * 0.01, 2.0, 0.0],
                vel_mps: [1.0, 0.0, 0.0],
                ..GroundTruth::default()
            })
            .collect()
    }

    #[test]
    fn hand_computed_rmse_ranges_and_max() {
        let t = truth_line();
        let track = TruthTrack::new(&t, 50_000_000);
        // Errors (east, north): (+0.3, 0), (-0.1, +0.4), (0, -0.2) at interpolated epochs.
        let est = [
            (105_000_000u64, [0.105 + 0.3, 2.0]),
            (205_000_000, [0.205 - 0.1, 2.4]),
            (305_000_000, [0.305, 1.8]),
        ]
        .map(|(t_ns, p)| Estimate {
            t_ns,
            pos_en_m: p,
            up_m: 0.0,
            vel_en_mps: None,
            cov4: None,
            yaw_rad: None,
        });
        let m = compute(&est, &track, None, &[]).unwrap();
        let re = ((0.09 + 0.01) / 3.0f64).sqrt();
        let rn = ((0.16 + 0.04) / 3.0f64).sqrt();
        assert!((m.rmse_east - re).abs() < 1e-12);
        assert!((m.rmse_north - rn).abs() < 1e-12);
        assert!((m.rmse_mean - 0.5 * (re + rn)).abs() < 1e-12);
        assert!((m.rmse_horizontal - ((0.09 + 0.01 + 0.16 + 0.04) / 3.0f64).sqrt()).abs() < 1e-12);
        assert!((m.range_east[0] + 0.1).abs() < 1e-12 && (m.range_east[1] - 0.3).abs() < 1e-12);
        assert!((m.range_north[0] + 0.2).abs() < 1e-12 && (m.range_north[1] - 0.4).abs() < 1e-12);
        assert!((m.max_dist - (0.01f64 + 0.16).sqrt()).abs() < 1e-12);
        assert_eq!(m.epochs, 3);
        assert!(m.nees_mean.is_none() && m.nis_mean.is_none());
    }

    #[test]
    fn segment_and_span_limit_the_epochs() {
        let t = truth_line();
        let track = TruthTrack::new(&t, 50_000_000);
        let est: Vec<Estimate> = [0u64, 500_000_000, 2_000_000_000]
            .iter()
            .map(|&t_ns| Estimate {
                t_ns,
                pos_en_m: [0.0, 2.0],
                up_m: 0.0,
                vel_en_mps: None,
                cov4: None,
                yaw_rad: None,
            })
            .collect();
        let m = compute(&est, &track, Some((400_000_000, 3_000_000_000)), &[]).unwrap();
        assert_eq!(m.epochs, 1); // 2 s is past the truth's end
        assert!((m.rmse_east - 0.5).abs() < 1e-12);
        assert!(compute(&est[..1], &track, Some((1, 2)), &[]).is_err());
    }

    #[test]
    fn nees_of_a_known_error() {
        let t = truth_line();
        let track = TruthTrack::new(&t, 50_000_000);
        let mut cov = [[0.0; 4]; 4];
        for (i, row) in cov.iter_mut().enumerate() {
            row[i] = 0.25;
        }
        let est = [Estimate {
            t_ns: 100_000_000,
            pos_en_m: [0.1 + 0.5, 2.0],
            up_m: 0.0,
            vel_en_mps: Some([1.0, 0.5]),
            cov4: Some(cov),
            yaw_rad: None,
        }];
        let m = compute(&est, &track, None, &[1.0, 3.0, f64::NAN]).unwrap();
        // (0.5^2 + 0.5^2) / 0.25 = 2
        assert!((m.nees_mean.unwrap() - 2.0).abs() < 1e-9);
        assert!((m.nis_mean.unwrap() - 2.0).abs() < 1e-12);
    }

    #[test]
    fn non_finite_estimate_is_an_error() {
        let t = truth_line();
        let track = TruthTrack::new(&t, 50_000_000);
        let est = [Estimate {
            t_ns: 0,
            pos_en_m: [f64::NAN, 0.0],
            up_m: 0.0,
            vel_en_mps: None,
            cov4: None,
            yaw_rad: None,
        }];
        assert_eq!(
            compute(&est, &track, None, &[]),
            Err(MetricsError::NonFinite { t_ns: 0 })
        );
    }

    /// Positions without velocities, with millimetre noise on every other
    /// sample: the velocity is differenced over the window, not between
    /// neighbours, and stays within 0.05 m/s of the true 1 m/s.
    #[test]
    fn truth_velocity_is_differenced_over_the_window() {
        let truth: Vec<GroundTruth> = (0..=300u64)
            .map(|k| GroundTruth {
                header: Header::new(k, k * 4_000_000),
                pos_m: [
                    k as f64 * 0.004 + if k % 2 == 0 { 0.001 } else { -0.001 },
                    0.0,
                    1.0,
                ],
                ..GroundTruth::default()
            })
            .collect();
        let track = TruthTrack::new(&truth, 100_000_000);
        for t in [2_000_000u64, 500_000_000, 602_000_000, 1_198_000_000] {
            let (_, v) = track.at(t).unwrap();
            assert!((v[0] - 1.0).abs() < 0.05, "{t}: {v:?}");
        }
        // Neighbours alone would give 1 +- 0.5 m/s here.
        let (a, b) = (&truth[100], &truth[101]);
        assert!((slope(a, b)[0] - 1.0).abs() > 0.4);
    }
}
