//! Ground-truth helpers: the flight segment of a recording and interpolation
//! of the ground truth at any instant.
//!
//! Both expect `truth` sorted by strictly increasing `header.meas_time_ns`,
//! as [`crate::util::UtilFlight`] produces it (deduplicated).

use insuwb_msg::{GroundTruth, Header};

/// Height above which the vehicle counts as flying (the UTIL reference
/// accuracy is given over the segment where the ground-truth height exceeds
/// 0.3 m; dataset README).
pub const DEFAULT_MIN_HEIGHT_M: f64 = 0.3;

/// Longest ground-truth gap [`interpolate_truth`] interpolates across: 50 ms,
/// just above the largest gap in the UTIL logs (46 ms, dataset README).
pub const DEFAULT_MAX_TRUTH_GAP_NS: u64 = 50_000_000;

/// First and last instant (ns) at which the ground-truth height `pos_m[2]`
/// exceeds `min_height_m`, i.e. the times of the first and last samples
/// above it. `None` when no sample is above it (or `min_height_m` is NaN).
#[must_use]
pub fn flight_segment(truth: &[GroundTruth], min_height_m: f64) -> Option<(u64, u64)> {
    let above = |g: &&GroundTruth| g.pos_m[2] > min_height_m;
    let first = truth.iter().find(above)?;
    let last = truth.iter().rev().find(above)?;
    Some((first.header.meas_time_ns, last.header.meas_time_ns))
}

/// Ground truth at `t_ns`, interpolated between the two samples around it,
/// across gaps of at most [`DEFAULT_MAX_TRUTH_GAP_NS`]. See
/// [`interpolate_truth_within`].
#[must_use]
pub fn interpolate_truth(truth: &[GroundTruth], t_ns: u64) -> Option<GroundTruth> {
    interpolate_truth_within(truth, t_ns, DEFAULT_MAX_TRUTH_GAP_NS)
}

/// Ground truth at `t_ns`: linear in position (and velocity, valid only when
/// both samples have it), spherical-linear (slerp, shortest arc) in attitude.
///
/// Returns a sample exactly when `t_ns` hits one; `None` before the first or
/// after the last sample, or when the two samples around `t_ns` are more than
/// `max_gap_ns` apart. The result's header carries `t_ns`, the sequence
/// number of the earlier sample and the common flags of both.
#[must_use]
pub fn interpolate_truth_within(
    truth: &[GroundTruth],
    t_ns: u64,
    max_gap_ns: u64,
) -> Option<GroundTruth> {
    // First index with time > t_ns.
    let j = truth.partition_point(|g| g.header.meas_time_ns <= t_ns);
    let lo = truth.get(j.checked_sub(1)?)?;
    if lo.header.meas_time_ns == t_ns {
        return Some(*lo);
    }
    let hi = truth.get(j)?;
    let span = hi.header.meas_time_ns.checked_sub(lo.header.meas_time_ns)?;
    if span == 0 || span > max_gap_ns {
        return None;
    }
    let w = (t_ns - lo.header.meas_time_ns) as f64 / span as f64;
    let lerp = |a: [f64; 3], b: [f64; 3]| {
        [
            a[0] + w * (b[0] - a[0]),
            a[1] + w * (b[1] - a[1]),
            a[2] + w * (b[2] - a[2]),
        ]
    };
    let flags = lo.header.flags & hi.header.flags;
    let vel_mps = if flags & GroundTruth::FLAG_VEL_VALID != 0 {
        lerp(lo.vel_mps, hi.vel_mps)
    } else {
        [0.0; 3]
    };
    let mut header = Header::new(lo.header.seq, t_ns);
    header.flags = flags;
    header.source_id = lo.header.source_id;
    header.generation = lo.header.generation;
    Some(GroundTruth {
        header,
        pos_m: lerp(lo.pos_m, hi.pos_m),
        vel_mps,
        quat: slerp(lo.quat, hi.quat, w),
    })
}

/// Spherical linear interpolation of unit quaternions `[w, x, y, z]` along
/// the shorter arc; the result is normalised.
#[must_use]
pub fn slerp(a: [f64; 4], b: [f64; 4], t: f64) -> [f64; 4] {
    let mut dot: f64 = a.iter().zip(b.iter()).map(|(x, y)| x * y).sum();
    let mut b = b;
    if dot < 0.0 {
        dot = -dot;
        b = b.map(|v| -v);
    }
    let (ka, kb) = if dot > 0.9995 {
        // Nearly parallel: normalised linear interpolation is exact enough.
        (1.0 - t, t)
    } else {
        let theta = dot.clamp(-1.0, 1.0).acos();
        let s = theta.sin();
        (((1.0 - t) * theta).sin() / s, (t * theta).sin() / s)
    };
    let q = [
        ka * a[0] + kb * b[0],
        ka * a[1] + kb * b[1],
        ka * a[2] + kb * b[2],
        ka * a[3] + kb * b[3],
    ];
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if n > 0.0 && n.is_finite() {
        q.map(|v| v / n)
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gt(t_ns: u64, seq: u64, pos: [f64; 3], yaw: f64) -> GroundTruth {
        GroundTruth {
            header: Header::new(seq, t_ns),
            pos_m: pos,
            vel_mps: [0.0; 3],
            quat: [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()],
        }
    }

    #[test]
    fn flight_segment_first_to_last_above() {
        let t = [
            gt(0, 0, [0.0, 0.0, 0.1], 0.0),
            gt(10, 1, [0.0, 0.0, 0.3], 0.0),
            gt(20, 2, [0.0, 0.0, 0.31], 0.0),
            gt(30, 3, [0.0, 0.0, 0.2], 0.0),
            gt(40, 4, [0.0, 0.0, 1.0], 0.0),
            gt(50, 5, [0.0, 0.0, 0.05], 0.0),
        ];
        assert_eq!(flight_segment(&t, DEFAULT_MIN_HEIGHT_M), Some((20, 40)));
        assert_eq!(flight_segment(&t, 2.0), None);
        assert_eq!(flight_segment(&t, f64::NAN), None);
        assert_eq!(flight_segment(&[], 0.3), None);
    }

    #[test]
    fn interpolates_position_and_attitude() {
        let t = [
            gt(1_000, 4, [0.0, 1.0, 2.0], 0.0),
            gt(5_000, 5, [4.0, -1.0, 2.0], std::f64::consts::FRAC_PI_2),
            gt(200_000_000, 6, [0.0, 0.0, 0.0], 0.0),
        ];
        let g = interpolate_truth(&t, 2_000).unwrap();
        assert_eq!(g.header.meas_time_ns, 2_000);
        assert_eq!(g.header.seq, 4);
        assert!((g.pos_m[0] - 1.0).abs() < 1e-12);
        assert!((g.pos_m[1] - 0.5).abs() < 1e-12);
        // A quarter of the way from yaw 0 to yaw 90 deg: yaw 22.5 deg.
        let yaw = 2.0 * g.quat[3].atan2(g.quat[0]);
        assert!((yaw - 22.5f64.to_radians()).abs() < 1e-12, "{yaw}");
        assert_eq!(interpolate_truth(&t, 1_000), Some(t[0]));
        assert_eq!(interpolate_truth(&t, 5_000), Some(t[1]));
        assert_eq!(interpolate_truth(&t, 999), None);
        assert_eq!(interpolate_truth(&t, 200_000_001), None);
        // Across the 200 ms gap: refused by default, allowed with a larger max.
        assert_eq!(interpolate_truth(&t, 100_000_000), None);
        assert!(interpolate_truth_within(&t, 100_000_000, 300_000_000).is_some());
        assert_eq!(interpolate_truth(&[], 0), None);
    }

    #[test]
    fn slerp_takes_the_short_arc() {
        let a = [1.0, 0.0, 0.0, 0.0];
        // yaw 170 deg expressed with negative w (same rotation as +q).
        let h = 85f64.to_radians();
        let b = [-h.cos(), 0.0, 0.0, -h.sin()];
        let m = slerp(a, b, 0.5);
        let yaw = 2.0 * m[3].atan2(m[0]);
        assert!((yaw - 85f64.to_radians()).abs() < 1e-12, "{yaw}");
        let n: f64 = m.iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-12);
    }
}
