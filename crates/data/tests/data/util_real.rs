//! Real-data checks on the four UTIL logs in `shared/data/util`.
//!
//! The directory comes from `INSUWB_UTIL_DIR`, else `../shared/data/util`
//! relative to the workspace root. Without it the tests print why and pass,
//! unless `CI` is set: then they fail.

// Helpers outside `#[test]` fns unwrap too (tests may unwrap).
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use insuwb_data::segment::DEFAULT_MIN_HEIGHT_M;
use insuwb_data::util::UTIL_LOGS;
use insuwb_data::{
    flight_segment, interpolate_truth, is_cflog, load_util_flight, ImportOptions, ParseOptions,
    UtilFlight, STANDARD_GRAVITY_MPS2, UWB_ANTENNA_LEVER_ARM_M,
};

fn data_dir() -> Option<PathBuf> {
    let dir = match std::env::var_os("INSUWB_UTIL_DIR") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/util"),
    };
    if dir.join(UTIL_LOGS[0].0).is_file() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "UTIL data not found in {} (set INSUWB_UTIL_DIR); CI is set, so this is a failure",
        dir.display()
    );
    eprintln!(
        "SKIPPED: UTIL data not found in {} (set INSUWB_UTIL_DIR to run the real-data tests)",
        dir.display()
    );
    None
}

fn load_all() -> Option<Vec<(&'static str, UtilFlight)>> {
    let dir = data_dir()?;
    Some(
        UTIL_LOGS
            .iter()
            .map(|&(log, anchors)| {
                let bytes = std::fs::read(dir.join(log)).unwrap();
                assert!(is_cflog(&bytes), "{log} not detected as a Crazyflie log");
                let f = load_util_flight(
                    &dir.join(log),
                    &dir.join(anchors),
                    &ParseOptions::default(),
                    &ImportOptions::default(),
                )
                .unwrap();
                (log, f)
            })
            .collect(),
    )
}

fn rate_hz(times: impl Iterator<Item = u64>) -> f64 {
    let t: Vec<u64> = times.collect();
    let (first, last) = (t[0], t[t.len() - 1]);
    (t.len() - 1) as f64 / ((last - first) as f64 * 1e-9)
}

/// Rotates body vector `v` into ENU by `q = [w, x, y, z]`.
fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let [w, x, y, z] = q;
    [
        (1.0 - 2.0 * (y * y + z * z)) * v[0]
            + 2.0 * (x * y - w * z) * v[1]
            + 2.0 * (x * z + w * y) * v[2],
        2.0 * (x * y + w * z) * v[0]
            + (1.0 - 2.0 * (x * x + z * z)) * v[1]
            + 2.0 * (y * z - w * x) * v[2],
        2.0 * (x * z - w * y) * v[0]
            + 2.0 * (y * z + w * x) * v[1]
            + (1.0 - 2.0 * (x * x + y * y)) * v[2],
    ]
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Robust RMS: 1.4826 * median(|r|) (equals sigma for zero-mean Gaussian r).
fn robust_rms(r: &[f64]) -> f64 {
    let mut a: Vec<f64> = r.iter().map(|x| x.abs()).collect();
    1.4826 * median(&mut a)
}

/// TDOA residuals (measured minus predicted from ground truth, UWB antenna
/// via the lever arm) over the flight segment. `swap` exchanges the anchors
/// (the opposite sign convention).
fn tdoa_residuals(f: &UtilFlight, swap: bool) -> Vec<f64> {
    let (t0, t1) = flight_segment(&f.truth, DEFAULT_MIN_HEIGHT_M).unwrap();
    f.tdoa
        .iter()
        .filter(|m| (t0..=t1).contains(&m.header.meas_time_ns))
        .filter_map(|m| {
            let g = interpolate_truth(&f.truth, m.header.meas_time_ns)?;
            let arm = rotate(g.quat, UWB_ANTENNA_LEVER_ARM_M);
            let p = [
                g.pos_m[0] + arm[0],
                g.pos_m[1] + arm[1],
                g.pos_m[2] + arm[2],
            ];
            let (a, b) = if swap {
                (m.anchor_b_pos_m, m.anchor_a_pos_m)
            } else {
                (m.anchor_a_pos_m, m.anchor_b_pos_m)
            };
            Some(m.diff_m - (dist(p, b) - dist(p, a)))
        })
        .collect()
}

#[test]
fn counts_rates_and_durations() {
    let Some(flights) = load_all() else { return };
    let expected_s = [51.0, 53.0, 56.0, 57.0]; // dataset README table
    for ((log, f), want_s) in flights.iter().zip(expected_s) {
        let imu_hz = rate_hz(f.imu.iter().map(|s| s.header.meas_time_ns));
        let tdoa_hz = rate_hz(f.tdoa.iter().map(|s| s.header.meas_time_ns));
        let truth_hz = rate_hz(f.truth.iter().map(|s| s.header.meas_time_ns));
        let dur_s = f.duration_ns() as f64 * 1e-9;
        eprintln!(
            "{log}: {} IMU {imu_hz:.1} Hz, {} TDOA {tdoa_hz:.1} Hz, {} truth {truth_hz:.1} Hz, {dur_s:.2} s; {:?}",
            f.imu.len(),
            f.tdoa.len(),
            f.truth.len(),
            f.stats
        );
        assert!((950.0..1050.0).contains(&imu_hz), "{log}: IMU {imu_hz} Hz");
        // about 430 Hz in three logs; 0426-traj5 (TDOA3) logs 210 Hz.
        assert!(
            (150.0..500.0).contains(&tdoa_hz),
            "{log}: TDOA {tdoa_hz} Hz"
        );
        assert!(
            (200.0..310.0).contains(&truth_hz),
            "{log}: truth {truth_hz} Hz"
        );
        assert!(
            (dur_s - want_s).abs() < 1.0,
            "{log}: {dur_s} s, README {want_s} s"
        );
        let s = f.stats;
        assert_eq!(
            s.time_backwards + s.time_repeated + s.non_finite,
            0,
            "{log}"
        );
        assert_eq!(
            s.unknown_anchor + s.same_anchor + s.bad_quaternion,
            0,
            "{log}"
        );
        assert!(s.accel_unpaired <= 2, "{log}: {s:?}");
        // Accel and gyro counts may differ by a few (README).
        assert!(
            s.accel_records.abs_diff(s.gyro_records) <= 10,
            "{log}: {s:?}"
        );
        // Near-duplicate truth stamps exist in every log and are few.
        assert!(
            s.truth_duplicates > 0 && s.truth_duplicates < 100,
            "{log}: {s:?}"
        );
        for (k, w) in f.imu.windows(2).enumerate() {
            assert!(w[0].header.meas_time_ns < w[1].header.meas_time_ns);
            assert_eq!(w[0].header.seq, k as u64);
        }
        assert!(f
            .truth
            .windows(2)
            .all(|w| w[1].header.meas_time_ns - w[0].header.meas_time_ns >= 100_000));
        assert!(f
            .tdoa
            .windows(2)
            .all(|w| w[0].header.meas_time_ns <= w[1].header.meas_time_ns));
        let mut ids: Vec<u32> = f
            .tdoa
            .iter()
            .flat_map(|m| [m.anchor_a, m.anchor_b])
            .collect();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids, (0..8).collect::<Vec<u32>>(), "{log}");
    }
}

#[test]
fn static_accelerometer_reads_plus_one_g_on_body_z() {
    let Some(flights) = load_all() else { return };
    for (log, f) in &flights {
        // First 0.15 s: static in every log (motors spin from 0.17 s in 0426).
        let rest: Vec<_> = f
            .imu
            .iter()
            .filter(|s| s.header.meas_time_ns < 150_000_000)
            .collect();
        let n = rest.len() as f64;
        let mean = |k: usize| rest.iter().map(|s| s.accel_mps2[k]).sum::<f64>() / n;
        let norm = rest
            .iter()
            .map(|s| s.accel_mps2.iter().map(|a| a * a).sum::<f64>().sqrt())
            .sum::<f64>()
            / n;
        let gyro_max = rest
            .iter()
            .flat_map(|s| s.gyro_rps)
            .fold(0.0f64, |m, g| m.max(g.abs()));
        eprintln!(
            "{log}: static {} samples, mean acc [{:.4}, {:.4}, {:.4}] m/s^2, norm {norm:.4} m/s^2, max |gyro| {gyro_max:.4} rad/s",
            rest.len(),
            mean(0),
            mean(1),
            mean(2)
        );
        assert!(rest.len() > 100);
        assert!((norm - STANDARD_GRAVITY_MPS2).abs() < 0.05, "{log}: {norm}");
        // FLU: +1 g on z at rest, x and y small.
        assert!(mean(2) > 9.7, "{log}");
        assert!(mean(0).abs() < 0.3 && mean(1).abs() < 0.3, "{log}");
        assert!(gyro_max < 0.1, "{log}: {gyro_max}");
    }
}

/// 3 x 3 correlation matrix between the mean gyro and the body rate
/// differentiated from the ground-truth attitude, over windows of `dt_ns`:
/// `c[i][j]` = corr(gyro axis i, truth axis j).
fn gyro_truth_correlation(f: &UtilFlight, dt_ns: u64) -> [[f64; 3]; 3] {
    let mut sxy = [[0.0f64; 3]; 3];
    let mut sxx = [0.0f64; 3];
    let mut syy = [0.0f64; 3];
    let mut t = f.truth[0].header.meas_time_ns;
    let end = f.truth[f.truth.len() - 1].header.meas_time_ns;
    let mut imu_from = 0usize;
    while t + dt_ns <= end {
        let (Some(g0), Some(g1)) = (
            interpolate_truth(&f.truth, t),
            interpolate_truth(&f.truth, t + dt_ns),
        ) else {
            t += dt_ns;
            continue;
        };
        // Body rate from d = q0^-1 q1: 2 vec(d) / dt.
        let [aw, ax, ay, az] = g0.quat;
        let (ax, ay, az) = (-ax, -ay, -az);
        let [bw, bx, by, bz] = g1.quat;
        let dw = aw * bw - ax * bx - ay * by - az * bz;
        let dv = [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ];
        let sign = if dw < 0.0 { -1.0 } else { 1.0 };
        let w_truth = dv.map(|v| 2.0 * sign * v / (dt_ns as f64 * 1e-9));
        while f
            .imu
            .get(imu_from)
            .is_some_and(|s| s.header.meas_time_ns < t)
        {
            imu_from += 1;
        }
        let win: Vec<_> = f.imu[imu_from..]
            .iter()
            .take_while(|s| s.header.meas_time_ns < t + dt_ns)
            .collect();
        if win.len() as u64 > dt_ns / 2_000_000 {
            let gm: Vec<f64> = (0..3)
                .map(|k| win.iter().map(|s| s.gyro_rps[k]).sum::<f64>() / win.len() as f64)
                .collect();
            for i in 0..3 {
                sxx[i] += gm[i] * gm[i];
                syy[i] += w_truth[i] * w_truth[i];
                for j in 0..3 {
                    sxy[i][j] += gm[i] * w_truth[j];
                }
            }
        }
        t += dt_ns;
    }
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = sxy[i][j] / (sxx[i] * syy[j]).sqrt();
        }
    }
    c
}

#[test]
fn gyro_axes_agree_with_ground_truth_body_rates() {
    let Some(flights) = load_all() else { return };
    for (log, f) in &flights {
        let c = gyro_truth_correlation(f, 200_000_000);
        eprintln!("{log}: corr(gyro_i, truth body rate_j), 200 ms windows: {c:.3?}");
        // FLU on both sides: each gyro axis matches the same truth axis with
        // the same sign (FRD would flip y and z), and not the others. The
        // 0426 flights turn little (and the quantised truth quaternions are
        // noisy), so their correlations are lower (0.58-0.80 against
        // 0.92-0.98 in the const3 flights) but still diagonal.
        for i in 0..3 {
            assert!(c[i][i] > 0.5, "{log}: {c:?}");
            for j in (0..3).filter(|&j| j != i) {
                assert!(c[i][j].abs() < c[i][i] / 2.0, "{log}: {c:?}");
                assert!(c[j][i].abs() < c[i][i] / 2.0, "{log}: {c:?}");
            }
        }
    }
}

#[test]
fn tdoa_residuals_against_ground_truth() {
    let Some(flights) = load_all() else { return };
    for (log, f) in &flights {
        let r = tdoa_residuals(f, false);
        let robust = robust_rms(&r);
        let mut c = r.clone();
        let med = median(&mut c);
        let over = r.iter().filter(|x| x.abs() > 0.3).count() as f64 / r.len() as f64;
        let mut dev: Vec<f64> = r.iter().map(|x| (x - med).abs()).collect();
        let mad_sd = 1.4826 * median(&mut dev);
        let swapped = robust_rms(&tdoa_residuals(f, true));
        eprintln!(
            "{log}: {} TDOA in flight, residual robust RMS {robust:.3} m (1.4826 MAD {mad_sd:.3} m), median {med:.3} m, {:.1} % > 0.3 m; swapped anchors: {swapped:.3} m",
            r.len(),
            100.0 * over
        );
        assert!(r.len() > 5_000, "{log}");
        assert!((0.12..0.21).contains(&robust), "{log}: {robust}");
        assert!(swapped > 3.0 * robust, "{log}: {swapped} vs {robust}");
    }
}
