//! End-to-end checks of the simulator against hand-computed answers.

// Test helpers outside #[test] functions unwrap too; axis loops index arrays.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::needless_range_loop
)]

use insuwb_msg::{GroundTruth, UwbTdoa, LAYOUT_VERSION};
use insuwb_sim::{
    builtin, builtin_names, simulate, Anchor, AnchorSet, CirclePath, Dimension, Dropout,
    Figure8Path, ImuErrors, LissajousPath, OutlierBurst, PairMode, Scenario, ScenarioError,
    SimRecord, StaticPose, Trajectory,
};

const G: f64 = 9.81;

fn quiet(mut sc: Scenario) -> Scenario {
    sc.imu = ImuErrors::none();
    sc.uwb.tdoa_sigma_m = 0.0;
    sc.uwb.outliers.clear();
    sc.uwb.random_nlos = None;
    sc
}

fn room_anchors() -> Vec<Anchor> {
    [(0.0, 0.0), (7.0, 0.0), (0.0, 5.0), (7.0, 5.0)]
        .iter()
        .enumerate()
        .map(|(i, &(x, y))| Anchor {
            id: i as u32,
            pos_m: [x, y, 0.0],
            range_bias_m: 0.0,
        })
        .collect()
}

fn static_at(x: f64, y: f64, yaw: f64) -> Scenario {
    let mut sc = Scenario {
        trajectory: Trajectory::Static(StaticPose {
            pos_m: [x, y],
            yaw_rad: yaw,
        }),
        duration_s: 2.0,
        ..Scenario::default()
    };
    sc.uwb.anchors = room_anchors();
    quiet(sc)
}

fn yaw_of(t: &GroundTruth) -> f64 {
    let q = t.quat;
    assert!(q[1].abs() < 1e-15 && q[2].abs() < 1e-15, "no tilt");
    2.0 * q[3].atan2(q[0])
}

fn unwrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

#[test]
fn same_seed_gives_identical_output_and_another_seed_does_not() {
    let sc = Scenario::builtin("paper-3.4").unwrap();
    let a = simulate(&sc, 7).unwrap();
    let b = simulate(&sc, 7).unwrap();
    assert_eq!(a, b);
    let bits = |o: &insuwb_sim::SimOutput| -> Vec<u64> {
        o.imu
            .iter()
            .flat_map(|s| s.accel_mps2.into_iter().chain(s.gyro_rps))
            .chain(o.tdoa.iter().map(|m| m.diff_m))
            .map(f64::to_bits)
            .collect()
    };
    assert_eq!(bits(&a), bits(&b));
    let c = simulate(&sc, 8).unwrap();
    assert_ne!(a.imu, c.imu);
    assert_ne!(a.tdoa, c.tdoa);
    // The truth does not depend on the seed.
    assert_eq!(a.truth, c.truth);
}

#[test]
fn streams_are_sorted_sequenced_and_flagged() {
    let mut sc = Scenario::builtin("nlos-long").unwrap();
    sc.uwb.dropouts.push(Dropout {
        start_s: 20.0,
        duration_s: 1.5,
    });
    let out = simulate(&sc, 3).unwrap();
    assert_eq!(out.imu.len(), 6000);
    assert_eq!(out.truth.len(), 6000);
    for (k, (s, t)) in out.imu.iter().zip(&out.truth).enumerate() {
        assert_eq!(s.header.seq, k as u64);
        assert_eq!(s.header.meas_time_ns, k as u64 * 10_000_000);
        assert_eq!(s.header.layout_version, LAYOUT_VERSION);
        assert_eq!(t.header, {
            let mut h = s.header;
            h.flags = GroundTruth::FLAG_VEL_VALID;
            h
        });
    }
    // 600 epochs minus 15 dropped here and 20 by the file's own dropout, 3 differences each.
    let pairs = 3;
    assert_eq!(out.tdoa.len(), (600 - 15 - 20) * pairs);
    assert_eq!(out.tdoa_truth.len(), out.tdoa.len());
    for (k, m) in out.tdoa.iter().enumerate() {
        assert_eq!(m.header.seq, k as u64);
        assert_eq!(m.header.layout_version, LAYOUT_VERSION);
        let t = m.header.meas_time_ns;
        assert_eq!(t % 100_000_000, 0);
        assert!(
            !(20_000_000_000..21_500_000_000).contains(&t),
            "dropout at {t}"
        );
        let a = sc.uwb.anchors.iter().find(|a| a.id == m.anchor_a).unwrap();
        let b = sc.uwb.anchors.iter().find(|a| a.id == m.anchor_b).unwrap();
        assert_eq!(m.anchor_a_pos_m, a.pos_m);
        assert_eq!(m.anchor_b_pos_m, b.pos_m);
        // Reference mode: anchor_a is the first anchor.
        assert_eq!(m.anchor_a, 0);
        let is_last = k % pairs == pairs - 1;
        assert_eq!(
            m.header.flags & UwbTdoa::FLAG_EPOCH_END != 0,
            is_last,
            "{k}"
        );
        if !is_last {
            assert_eq!(out.tdoa[k + 1].header.meas_time_ns, t);
        } else if let Some(n) = out.tdoa.get(k + 1) {
            assert!(n.header.meas_time_ns > t);
        }
    }
}

#[test]
fn merged_stream_is_time_ordered_with_truth_then_imu_then_uwb() {
    let sc = Scenario::builtin("paper-4.4-dynamic").unwrap();
    let out = simulate(&sc, 1).unwrap();
    let m = out.merged();
    assert_eq!(m.len(), out.imu.len() + out.truth.len() + out.tdoa.len());
    let rank = |r: &SimRecord| match r {
        SimRecord::Truth(_) => 0,
        SimRecord::Imu(_) => 1,
        SimRecord::Tdoa(_) | SimRecord::Range(_) => 2,
        SimRecord::Velocity(_) => 3,
        SimRecord::Height(_) => 4,
    };
    for w in m.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        assert!(a.time_ns() < b.time_ns() || (a.time_ns() == b.time_ns() && rank(a) <= rank(b)));
    }
    assert!(matches!(m[0], SimRecord::Truth(_)));
    assert!(matches!(m[1], SimRecord::Imu(_)));
    assert!(matches!(m[2], SimRecord::Tdoa(_)));
    assert!(matches!(m[4], SimRecord::Tdoa(t) if t.header.flags & UwbTdoa::FLAG_EPOCH_END != 0));
    assert!(matches!(m[5], SimRecord::Truth(t) if t.header.seq == 1));
    // Each stream keeps its own order.
    let tdoa: Vec<UwbTdoa> = m
        .iter()
        .filter_map(|r| {
            if let SimRecord::Tdoa(t) = r {
                Some(*t)
            } else {
                None
            }
        })
        .collect();
    assert_eq!(tdoa, out.tdoa);
}

#[test]
fn static_imu_reads_the_biases_and_integrates_to_their_drift() {
    let yaw0 = 0.7_f64;
    let mut sc = static_at(3.0, 2.0, yaw0);
    sc.duration_s = 60.0;
    sc.imu = ImuErrors {
        gyro_bias_deg_per_h: 0.5,
        accel_bias_g: 1e-3,
        ..ImuErrors::none()
    };
    let out = simulate(&sc, 11).unwrap();
    let bg = out.imu_errors.gyro_bias_rps;
    let ba = out.imu_errors.accel_bias_mps2;
    for a in 0..3 {
        // 0.5 deg/h = 0.5 * pi / 180 / 3600 rad/s; 1e-3 g = 9.81e-3 m/s^2.
        assert!(
            (bg[a].abs() - 2.424_068_405_547_075e-6).abs() < 1e-18,
            "{}",
            bg[a]
        );
        assert!((ba[a].abs() - 9.81e-3).abs() < 1e-15);
    }
    for s in &out.imu {
        assert_eq!(s.gyro_rps, bg);
        assert_eq!(s.accel_mps2, [ba[0], ba[1], G + ba[2]]);
    }
    // In-test strapdown (trapezoidal): yaw, then nav-frame acceleration, velocity, position.
    let dt = 0.01;
    let (mut yaw, mut v, mut p) = (yaw0, [0.0; 3], [0.0; 3]);
    let mut a_prev: Option<[f64; 3]> = None;
    for s in &out.imu {
        let (sn, cs) = yaw.sin_cos();
        let f = s.accel_mps2;
        let a = [cs * f[0] - sn * f[1], sn * f[0] + cs * f[1], f[2] - G];
        if let Some(ap) = a_prev {
            for k in 0..3 {
                let vn = v[k] + 0.5 * (a[k] + ap[k]) * dt;
                p[k] += 0.5 * (v[k] + vn) * dt;
                v[k] = vn;
            }
            yaw += s.gyro_rps[2] * dt;
        }
        a_prev = Some(a);
    }
    let t = (out.imu.len() - 1) as f64 * dt;
    // Yaw drift b_gz * t: 1.43e-4 rad over 59.99 s.
    assert!((yaw - yaw0 - bg[2] * t).abs() < 1e-12);
    let (sn, cs) = yaw0.sin_cos();
    let want = [
        0.5 * (cs * ba[0] - sn * ba[1]) * t * t,
        0.5 * (sn * ba[0] + cs * ba[1]) * t * t,
        0.5 * ba[2] * t * t,
    ];
    for k in 0..3 {
        // The tiny yaw drift rotates the bias: relative effect ~1e-4.
        assert!(
            (p[k] - want[k]).abs() < 2e-3 * 17.7,
            "{k}: {} vs {}",
            p[k],
            want[k]
        );
    }
    // Different seeds give different sign patterns somewhere.
    let signs = |seed| {
        let o = simulate(&sc, seed).unwrap();
        o.imu_errors.accel_bias_mps2.map(f64::signum)
    };
    assert!((1..20).any(|s| signs(s) != signs(11)));
}

#[test]
fn imu_white_noise_has_the_configured_densities() {
    let mut sc = static_at(0.0, 0.0, 0.0);
    sc.duration_s = 300.0;
    sc.imu = ImuErrors {
        gyro_arw_deg_per_sqrt_h: 0.05,
        accel_vrw_g_sqrt_s: 1e-4,
        ..ImuErrors::none()
    };
    let out = simulate(&sc, 5).unwrap();
    let n = out.imu.len() as f64;
    // 0.05 deg/sqrt(h) = 0.05/60 deg/sqrt(s) -> * sqrt(100 Hz).
    let gyro_sigma = 0.05 / 60.0 * std::f64::consts::PI / 180.0 * 10.0;
    let accel_sigma = 1e-4 * G * 10.0;
    for a in 0..3 {
        let g: Vec<f64> = out.imu.iter().map(|s| s.gyro_rps[a]).collect();
        let f: Vec<f64> = out
            .imu
            .iter()
            .map(|s| s.accel_mps2[a] - if a == 2 { G } else { 0.0 })
            .collect();
        for (x, sigma) in [(g, gyro_sigma), (f, accel_sigma)] {
            let mean = x.iter().sum::<f64>() / n;
            let sd = (x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n).sqrt();
            assert!(mean.abs() < 5.0 * sigma / n.sqrt(), "mean {mean}");
            // Standard error of sd: sigma / sqrt(2n) = 0.3 %.
            assert!((sd / sigma - 1.0).abs() < 0.015, "sd {sd} vs {sigma}");
        }
    }
}

#[test]
fn bias_random_walk_spreads_as_configured() {
    let mut sc = static_at(0.0, 0.0, 0.0);
    sc.duration_s = 25.0;
    sc.imu = ImuErrors {
        accel_bias_walk_g_per_sqrt_s: 1e-3,
        ..ImuErrors::none()
    };
    let mut sq = 0.0;
    let mut n = 0.0;
    for seed in 0..40 {
        let out = simulate(&sc, seed).unwrap();
        let (first, last) = (out.imu.first().unwrap(), out.imu.last().unwrap());
        for a in 0..2 {
            let d = last.accel_mps2[a] - first.accel_mps2[a];
            sq += d * d;
            n += 1.0;
        }
    }
    // Variance after t = 24.99 s: (1e-3 g)^2 * t.
    let want = (1e-3 * G).powi(2) * 24.99;
    let got = sq / n;
    assert!((got / want - 1.0).abs() < 0.35, "{got} vs {want}");
}

#[test]
fn circle_specific_force_is_centripetal() {
    for clockwise in [false, true] {
        let mut sc = static_at(0.0, 0.0, 0.0);
        sc.trajectory = Trajectory::Circle(CirclePath {
            centre_m: [1.0, -1.0],
            radius_m: 2.0,
            speed_mps: 0.8,
            start_angle_rad: 0.3,
            clockwise,
        });
        sc.duration_s = 20.0;
        let out = simulate(&sc, 1).unwrap();
        let dir = if clockwise { -1.0 } else { 1.0 };
        for (s, t) in out.imu.iter().zip(&out.truth) {
            // v^2 / r = 0.32 m/s^2 towards the centre: body +y (left) when counter-clockwise.
            assert!(s.accel_mps2[0].abs() < 1e-6);
            assert!(
                (s.accel_mps2[1] - dir * 0.32).abs() < 1e-6,
                "{}",
                s.accel_mps2[1]
            );
            assert!((s.accel_mps2[2] - G).abs() < 1e-12);
            assert!((s.gyro_rps[2] - dir * 0.4).abs() < 1e-12);
            let r = (t.pos_m[0] - 1.0).hypot(t.pos_m[1] + 1.0);
            assert!((r - 2.0).abs() < 1e-12);
            assert!((t.vel_mps[0].hypot(t.vel_mps[1]) - 0.8).abs() < 1e-12);
        }
    }
}

/// Ideal IMU against numerical derivatives of the truth, on every curved path kind.
#[test]
fn imu_and_truth_agree_on_smooth_paths() {
    let mut cases: Vec<Scenario> = ["paper-3.4", "paper-4.4-dynamic", "nlos-long"]
        .iter()
        .map(|n| quiet(Scenario::builtin(n).unwrap()))
        .collect();
    let mut l = static_at(0.0, 0.0, 0.0);
    l.duration_s = 30.0;
    l.trajectory = Trajectory::Lissajous(LissajousPath {
        phase_rad: [0.4, 0.0],
        ..LissajousPath::default()
    });
    cases.push(l.clone());
    l.trajectory = Trajectory::Figure8(Figure8Path::default());
    cases.push(l);
    for sc in &mut cases {
        // 1 kHz: central differences are then accurate to ~1e-4 even across the
        // jerk steps at spline knots (a C2 spline's third derivative jumps).
        sc.imu_rate_hz = 1000.0;
        let out = simulate(sc, 1).unwrap();
        let dt = 1.0 / sc.imu_rate_hz;
        let tr = &out.truth;
        let (mut worst_a, mut worst_v, mut worst_w) = (0.0_f64, 0.0_f64, 0.0_f64);
        for k in 1..tr.len() - 1 {
            let yaw = yaw_of(&tr[k]);
            let (sn, cs) = yaw.sin_cos();
            let f = out.imu[k].accel_mps2;
            let a_nav = [cs * f[0] - sn * f[1], sn * f[0] + cs * f[1], f[2] - G];
            for c in 0..3 {
                let a_fd = (tr[k + 1].vel_mps[c] - tr[k - 1].vel_mps[c]) / (2.0 * dt);
                worst_a = worst_a.max((a_nav[c] - a_fd).abs());
                let v_fd = (tr[k + 1].pos_m[c] - tr[k - 1].pos_m[c]) / (2.0 * dt);
                worst_v = worst_v.max((tr[k].vel_mps[c] - v_fd).abs());
            }
            let w_fd = unwrap(yaw_of(&tr[k + 1]) - yaw_of(&tr[k - 1])) / (2.0 * dt);
            worst_w = worst_w.max((out.imu[k].gyro_rps[2] - w_fd).abs());
        }
        // Far below the sensor noise at 1 kHz (3e-2 m/s^2, 4.6e-4 rad/s per sample).
        println!(
            "{}: worst accel {worst_a:.2e} vel {worst_v:.2e} yaw rate {worst_w:.2e}",
            sc.name
        );
        assert!(worst_a < 5e-4, "{}: accel {worst_a}", sc.name);
        assert!(worst_v < 1e-5, "{}: vel {worst_v}", sc.name);
        assert!(worst_w < 5e-4, "{}: yaw rate {worst_w}", sc.name);
    }
}

#[test]
fn waypoint_paths_start_at_rest_and_pass_through_their_points() {
    let sc = quiet(Scenario::builtin("paper-4.4-dynamic").unwrap());
    let out = simulate(&sc, 1).unwrap();
    let Trajectory::Waypoints(w) = &sc.trajectory else {
        panic!("4.4 is a waypoint path")
    };
    let first = &out.truth[0];
    assert_eq!(&first.pos_m[..2], &[3.0, 4.0]);
    assert_eq!(first.vel_mps, [0.0; 3]);
    assert_eq!(out.imu[0].accel_mps2, [0.0, 0.0, G]);
    let last = out.truth.last().unwrap();
    assert!((last.pos_m[0] - 5.0).abs() < 1e-9 && (last.pos_m[1] - 3.0).abs() < 1e-9);
    assert_eq!(last.vel_mps, [0.0; 3]);
    for p in &w.points {
        let d = out
            .truth
            .iter()
            .map(|t| (t.pos_m[0] - p[0]).hypot(t.pos_m[1] - p[1]))
            .fold(f64::INFINITY, f64::min);
        // Samples every 5 mm at 0.5 m/s.
        assert!(d < 3e-3, "{p:?}: {d}");
    }
}

#[test]
fn tdoa_differences_equal_the_geometry_with_the_right_sign() {
    let r0 = 13f64.sqrt();
    let (r1, r2, r3) = (20f64.sqrt(), 18f64.sqrt(), 5.0);
    let mut sc = static_at(3.0, 2.0, 0.0);
    let out = simulate(&sc, 1).unwrap();
    let epoch: Vec<(u32, u32, f64)> = out.tdoa[..3]
        .iter()
        .map(|m| (m.anchor_a, m.anchor_b, m.diff_m))
        .collect();
    // |p - b| - |p - a| with a = anchor 0 (3.606 m away): all positive, the tag is nearest anchor 0.
    assert_eq!(
        epoch,
        vec![(0, 1, r1 - r0), (0, 2, r2 - r0), (0, 3, r3 - r0)]
    );
    assert!((epoch[0].2 - 0.866_584_6).abs() < 1e-6);

    // Near anchor 3 the difference to it is negative.
    let mut near = static_at(6.0, 4.0, 0.0);
    near.uwb.pairs = PairMode::Consecutive;
    let out = simulate(&near, 1).unwrap();
    let d: Vec<(u32, u32, f64)> = out.tdoa[..3]
        .iter()
        .map(|m| (m.anchor_a, m.anchor_b, m.diff_m))
        .collect();
    let (q0, q1, q2, q3) = (52f64.sqrt(), 17f64.sqrt(), 37f64.sqrt(), 2f64.sqrt());
    assert_eq!(d, vec![(0, 1, q1 - q0), (1, 2, q2 - q1), (2, 3, q3 - q2)]);
    assert!(d[2].2 < 0.0);

    // Anchor range bias and anchor height; reference anchor 2.
    sc.uwb.anchors[1].range_bias_m = 0.1;
    for a in &mut sc.uwb.anchors {
        a.pos_m[2] = 2.5;
    }
    sc.height_m = 0.5;
    sc.uwb.reference_id = Some(2);
    let out = simulate(&sc, 1).unwrap();
    let (h0, h1, h2, h3) = (17f64.sqrt(), 24f64.sqrt(), 22f64.sqrt(), 29f64.sqrt());
    let d: Vec<(u32, u32, f64)> = out.tdoa[..3]
        .iter()
        .map(|m| (m.anchor_a, m.anchor_b, m.diff_m))
        .collect();
    let want = [(2, 0, h0 - h2), (2, 1, h1 + 0.1 - h2), (2, 3, h3 - h2)];
    for (g, w) in d.iter().zip(want) {
        assert_eq!((g.0, g.1), (w.0, w.1));
        assert!((g.2 - w.2).abs() < 1e-15, "{g:?} {w:?}");
    }
    assert_eq!(out.tdoa_truth[1].anchor_bias_m, 0.1);
}

#[test]
fn tdoa_noise_has_the_configured_sigma_and_correlation() {
    let mut sc = static_at(3.0, 2.0, 0.0);
    sc.duration_s = 500.0;
    sc.uwb.tdoa_sigma_m = 0.05;
    let out = simulate(&sc, 2).unwrap();
    let noise: Vec<f64> = out.tdoa_truth.iter().map(|t| t.noise_m).collect();
    let n = noise.len() as f64;
    let var = noise.iter().map(|x| x * x).sum::<f64>() / n;
    assert!((var.sqrt() / 0.05 - 1.0).abs() < 0.03, "{}", var.sqrt());
    // Differences sharing the reference anchor correlate with coefficient 0.5.
    let cov = noise.chunks(3).map(|c| c[0] * c[1]).sum::<f64>() / (n / 3.0);
    assert!((cov / var - 0.5).abs() < 0.05, "{}", cov / var);
    for (m, t) in out.tdoa.iter().zip(&out.tdoa_truth) {
        assert!((m.diff_m - (t.geometric_m + t.noise_m)).abs() < 1e-12);
    }
}

#[test]
fn outliers_appear_only_in_their_windows() {
    let mut sc = static_at(3.0, 2.0, 0.0);
    sc.duration_s = 10.0;
    sc.uwb.outliers = vec![
        OutlierBurst {
            start_s: 2.0,
            duration_s: 0.5,
            anchors: AnchorSet::Ids(vec![2]),
            bias_m: [0.3, 0.6],
            probability: 1.0,
        },
        OutlierBurst {
            start_s: 6.0,
            duration_s: 1.0,
            anchors: AnchorSet::Ids(vec![0]),
            bias_m: [0.5, 0.5],
            probability: 1.0,
        },
    ];
    let out = simulate(&sc, 4).unwrap();
    for (m, t) in out.tdoa.iter().zip(&out.tdoa_truth) {
        let ts = m.header.meas_time_ns as f64 * 1e-9;
        let in1 = (2.0..2.5).contains(&ts);
        let in2 = (6.0..7.0).contains(&ts);
        if in1 && m.anchor_b == 2 {
            // Blocked anchor 2 is anchor_b: positive excess.
            assert!((0.3..0.6).contains(&t.nlos_m), "{ts}: {}", t.nlos_m);
        } else if in2 {
            // The reference anchor 0 blocked: every difference is biased by -0.5.
            assert_eq!(t.nlos_m, -0.5);
        } else {
            assert_eq!(t.nlos_m, 0.0, "{ts} {}-{}", m.anchor_a, m.anchor_b);
        }
        assert!((m.diff_m - t.geometric_m - t.nlos_m).abs() < 1e-12);
    }
    // 5 + 10 epochs at 10 Hz.
    assert_eq!(
        out.tdoa_truth.iter().filter(|t| t.nlos_m != 0.0).count(),
        5 + 10 * 3
    );

    // With probability 0.5 about half the epochs are hit.
    sc.duration_s = 100.0;
    sc.uwb.outliers = vec![OutlierBurst {
        start_s: 0.0,
        duration_s: 100.0,
        anchors: AnchorSet::All,
        bias_m: [0.2, 0.2],
        probability: 0.5,
    }];
    let out = simulate(&sc, 4).unwrap();
    // Pair (0, 1) carries +0.2 exactly when anchor 1 is hit and anchor 0 is not.
    let hits = out
        .tdoa
        .iter()
        .zip(&out.tdoa_truth)
        .filter(|(m, t)| m.anchor_b == 1 && (t.nlos_m - 0.2).abs() < 1e-12)
        .count();
    let frac = hits as f64 / 1000.0;
    // P(anchor 1 hit and anchor 0 not) = 0.25.
    assert!((frac - 0.25).abs() < 0.05, "{frac}");
}

#[test]
fn random_nlos_is_seeded_and_only_adds_excess() {
    let sc = Scenario::builtin("nlos-long").unwrap();
    // Seeds 2 and 3: 4 events each (seed 1 draws 2, both inside the UWB
    // dropout from 40 s to 42 s, so no difference carries them).
    let a = simulate(&sc, 2).unwrap();
    let b = simulate(&sc, 3).unwrap();
    let hits = |o: &insuwb_sim::SimOutput| {
        o.tdoa_truth
            .iter()
            .map(|t| t.nlos_m != 0.0)
            .collect::<Vec<_>>()
    };
    assert!(hits(&a).iter().any(|&h| h));
    assert_ne!(hits(&a), hits(&b));
    let r = sc.uwb.random_nlos.clone().unwrap();
    for t in &a.tdoa_truth {
        // excess_b - excess_a with each excess a sum of events in [0.3, 1.0].
        assert!(t.nlos_m.abs() <= 4.0 * r.bias_m[1]);
    }
}

#[test]
fn builtins_parse_validate_and_run() {
    assert_eq!(
        builtin_names(),
        &[
            "paper-3.4",
            "paper-4.3-static",
            "paper-4.4-dynamic",
            "nlos-long",
            "nlos-long-twr",
            "ground-outage",
            "twr-3.4"
        ]
    );
    for name in builtin_names() {
        let text = builtin(name).unwrap();
        let disk = std::fs::read_to_string(format!(
            "{}/../../config/scenarios/{name}.toml",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap();
        assert_eq!(text, disk);
        let sc = Scenario::builtin(name).unwrap();
        assert_eq!(sc.name, *name);
        sc.validate().unwrap();
        let out = simulate(&sc, sc.seed).unwrap();
        assert!(!out.imu.is_empty() && (!out.tdoa.is_empty() || !out.range.is_empty()));
        sc.initial_ins_state(sc.seed).unwrap();
    }
    assert_eq!(builtin("nope"), None);
    assert!(matches!(
        Scenario::builtin("nope"),
        Err(ScenarioError::UnknownBuiltin { .. })
    ));
}

#[test]
fn other_top_level_tables_are_ignored_and_the_format_round_trips() {
    let text = format!(
        "{}\n[filter]\nkind = \"iakf\"\n",
        builtin("paper-3.4").unwrap()
    );
    let sc = Scenario::from_toml_str(&text, "x.toml").unwrap();
    assert_eq!(sc, Scenario::builtin("paper-3.4").unwrap());

    #[derive(serde::Serialize)]
    struct Doc<'a> {
        sim: &'a Scenario,
    }
    for name in builtin_names() {
        let sc = Scenario::builtin(name).unwrap();
        let s = toml::to_string(&Doc { sim: &sc }).unwrap();
        assert_eq!(
            Scenario::from_toml_str(&s, "round-trip").unwrap(),
            sc,
            "{s}"
        );
    }
}

fn load_err(text: &str) -> String {
    Scenario::from_toml_str(text, "bad.toml")
        .unwrap_err()
        .to_string()
}

const MINIMAL: &str = r#"
[sim]
name = "t"
[[sim.uwb.anchors]]
id = 0
pos_m = [0.0, 0.0, 0.0]
[[sim.uwb.anchors]]
id = 1
pos_m = [7.0, 0.0, 0.0]
[[sim.uwb.anchors]]
id = 2
pos_m = [0.0, 5.0, 0.0]
"#;

#[test]
fn bad_scenarios_are_refused_with_the_key_named() {
    assert!(Scenario::from_toml_str(MINIMAL, "ok.toml").is_ok());
    // Two anchors.
    let two = MINIMAL.rsplit_once("[[sim.uwb.anchors]]").unwrap().0;
    assert_eq!(
        load_err(two),
        "bad.toml: sim.uwb.anchors needs at least 3 anchors for a 2d fix, got 2"
    );
    // Three anchors are too few in 3-D.
    let e = load_err(&MINIMAL.replace(
        "name = \"t\"",
        "name = \"t\"\n[sim.uwb]\ndimension = \"3d\"",
    ));
    assert!(
        e.contains("sim.uwb.anchors needs at least 4 anchors for a 3d fix, got 3"),
        "{e}"
    );
    // Negative rate.
    let e = load_err(&MINIMAL.replace("name = \"t\"", "imu_rate_hz = -100.0"));
    assert_eq!(e, "bad.toml: sim.imu_rate_hz must be > 0, got -100");
    // NaN and infinity.
    let e = load_err(&MINIMAL.replace("name = \"t\"", "duration_s = nan"));
    assert_eq!(e, "bad.toml: sim.duration_s must be finite, got NaN");
    let e = load_err(&MINIMAL.replace("[7.0, 0.0, 0.0]", "[inf, 0.0, 0.0]"));
    assert_eq!(
        e,
        "bad.toml: sim.uwb.anchors[1].pos_m[0] must be finite, got inf"
    );
    // Collinear anchors.
    let e = load_err(&MINIMAL.replace("[0.0, 5.0, 0.0]", "[3.0, 0.0, 1.0]"));
    assert!(
        e.contains("sim.uwb.anchors: the anchors are collinear"),
        "{e}"
    );
    // Unknown key and wrong type: a parse error naming the path.
    let e = load_err(&MINIMAL.replace("name = \"t\"", "[sim.uwb]\ntdoa_sigma = 0.1"));
    assert!(
        e.starts_with("bad.toml: at `sim.uwb") && e.contains("tdoa_sigma"),
        "{e}"
    );
    let e = load_err(&MINIMAL.replace("id = 2", "id = \"two\""));
    assert!(e.starts_with("bad.toml: at `sim.uwb.anchors[2].id`"), "{e}");
    assert!(e.ends_with("(line 11)"), "{e}");
    // Outlier settings.
    let burst = |extra: &str| {
        format!("{MINIMAL}[[sim.uwb.outliers]]\nstart_s = 1.0\nduration_s = 0.5\n{extra}\n")
    };
    let e = load_err(&burst("bias_m = [0.1, 0.5]\nprobability = 1.5"));
    assert_eq!(
        e,
        "bad.toml: sim.uwb.outliers[0].probability must be in [0, 1], got 1.5"
    );
    let e = load_err(&burst("bias_m = [-0.1, 0.5]"));
    assert_eq!(
        e,
        "bad.toml: sim.uwb.outliers[0].bias_m[0] must be >= 0, got -0.1"
    );
    let e = load_err(&burst("bias_m = [0.1, 0.5]\nanchors = [7]"));
    assert_eq!(
        e,
        "bad.toml: sim.uwb.outliers[0].anchors: no anchor has id 7"
    );
    let e = load_err(&burst("bias_m = [0.1, 0.5]\nanchors = \"some\""));
    assert!(
        e.contains("sim.uwb.outliers[0].anchors") && e.contains("\"all\""),
        "{e}"
    );
    // Trajectory.
    let e = load_err(&format!(
        "{MINIMAL}[sim.trajectory.waypoints]\npoints = [[0.0, 0.0], [0.0, 0.0]]\nspeed_mps = 0.5\n"
    ));
    assert!(e.contains("sim.trajectory: point 1 coincides"), "{e}");
    let e = load_err(&format!(
        "{MINIMAL}[sim.trajectory.circle]\nradius_m = 0.0\n"
    ));
    assert_eq!(
        e,
        "bad.toml: sim.trajectory.circle.radius_m must be > 0, got 0"
    );
    // Too many samples.
    let e = load_err(&MINIMAL.replace("name = \"t\"", "duration_s = 1e6"));
    assert!(
        e.contains("sim.imu_rate_hz: duration_s * rate gives"),
        "{e}"
    );
    // Programmatic validation names the key too.
    let mut sc = Scenario::builtin("paper-3.4").unwrap();
    sc.uwb.anchors.push(Anchor {
        id: 3,
        pos_m: [0.0, 0.0, 0.0],
        range_bias_m: 0.0,
    });
    assert_eq!(
        sc.validate().unwrap_err().to_string(),
        "sim.uwb.anchors[4].id: anchor id 3 is used twice"
    );
    sc.uwb.anchors.pop();
    sc.uwb.dimension = Dimension::ThreeD;
    assert!(sc.validate().unwrap_err().to_string().contains("coplanar"));
}

#[test]
fn initial_state_is_deterministic_with_the_configured_spread() {
    let sc = Scenario::builtin("paper-3.4").unwrap();
    let a = sc.initial_ins_state(5).unwrap();
    assert_eq!(a, sc.initial_ins_state(5).unwrap());
    assert_ne!(a, sc.initial_ins_state(6).unwrap());
    let n = 4000;
    let (mut sp, mut sv) = ([0.0; 2], [0.0; 2]);
    for seed in 0..n {
        let s = sc.initial_ins_state(seed).unwrap();
        // Truth at t = 0: (0, 0), at rest, heading of the path tangent.
        assert_eq!(s.pos_m[2], sc.height_m);
        assert_eq!(s.yaw_rad, a.yaw_rad, "zero yaw sigma");
        for k in 0..2 {
            sp[k] += s.pos_m[k] * s.pos_m[k];
            sv[k] += s.vel_mps[k] * s.vel_mps[k];
        }
    }
    for k in 0..2 {
        // 1 m and 1 m/s per axis (standard error of the RMS 1.1 %).
        assert!(((sp[k] / n as f64).sqrt() - 1.0).abs() < 0.05);
        assert!(((sv[k] / n as f64).sqrt() - 1.0).abs() < 0.05);
    }
}

#[test]
fn toml_syntax_errors_name_the_origin() {
    let e = load_err("[sim]\nname = \n");
    assert!(e.starts_with("bad.toml: at `.`: "), "{e}");
    println!("{e}");
    let e = load_err("[other]\nx = 1\n");
    assert!(e.contains("sim"), "{e}");
    println!("{e}");
}
