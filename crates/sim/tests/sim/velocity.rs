//! The wheel odometry and optical flow of a scenario (`[sim.odometry]`,
//! `[sim.flow]`) against hand-computed answers: body-frame velocities of
//! the path with the configured scale and noise (and the flow's range, the
//! height plus its noise), at the configured times,
//! bit-identical for a seed, and nothing else of the run changed by them.

use insuwb_msg::{BodyVelocity, Height};
use insuwb_sim::{
    simulate, CirclePath, Dropout, FlowConfig, ImuErrors, OdometryConfig, Scenario,
    ScenarioConfigError, SimRecord, Trajectory,
};

/// A counter-clockwise circle of radius 2 m at 0.5 m/s for 20 s: the body
/// x axis along the path, the yaw turning through the whole run.
fn circle() -> Scenario {
    Scenario {
        duration_s: 20.0,
        trajectory: Trajectory::Circle(CirclePath {
            radius_m: 2.0,
            speed_mps: 0.5,
            ..CirclePath::default()
        }),
        imu: ImuErrors::none(),
        ..Scenario::default()
    }
}

fn odometry(scale: f64, sigma: f64, lateral: f64) -> OdometryConfig {
    OdometryConfig {
        rate_hz: 50.0,
        offset_s: 0.0,
        scale,
        sigma_mps: sigma,
        lateral_sigma_mps: lateral,
        dropouts: Vec::new(),
    }
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

#[test]
fn without_the_tables_there_is_no_velocity_and_with_them_nothing_else_changes() {
    let plain = circle();
    let a = simulate(&plain, 4).unwrap();
    assert!(a.velocity.is_empty());
    assert!(a
        .merged()
        .iter()
        .all(|r| !matches!(r, SimRecord::Velocity(_))));
    let mut aided = circle();
    aided.odometry = Some(odometry(1.05, 0.02, 0.05));
    aided.flow = Some(FlowConfig {
        offset_s: 0.01,
        ..FlowConfig::default()
    });
    let b = simulate(&aided, 4).unwrap();
    assert_eq!(a.imu, b.imu);
    assert_eq!(a.tdoa, b.tdoa);
    assert_eq!(a.truth, b.truth);
    assert_eq!(aided.initial_ins_state(4), plain.initial_ins_state(4));
    // 50 Hz each for 20 s; the same seed gives the same bits, another does not.
    assert_eq!(b.velocity.len(), 2000);
    assert_eq!(aided.velocity_sample_counts(), [1000, 1000]);
    assert_eq!(simulate(&aided, 4).unwrap().velocity, b.velocity);
    assert_ne!(simulate(&aided, 5).unwrap().velocity, b.velocity);
}

#[test]
fn odometry_reads_the_forward_speed_scaled_and_a_noisy_lateral_zero() {
    let mut sc = circle();
    sc.odometry = Some(odometry(1.05, 0.02, 0.05));
    let out = simulate(&sc, 7).unwrap();
    let v = &out.velocity;
    assert_eq!(v.len(), 1000);
    for (k, m) in v.iter().enumerate() {
        assert_eq!(m.header.seq, k as u64);
        assert_eq!(m.header.meas_time_ns, k as u64 * 20_000_000);
        assert_eq!(m.source, BodyVelocity::SOURCE_ODOMETRY);
        assert_eq!(m.sigma_mps, [0.02, 0.05, 0.0]);
        assert_eq!(m.vel_mps[2], 0.0);
        assert!(insuwb_msg::check::velocity_values(m).is_ok());
    }
    // Forward: 1.05 x 0.5 m/s, noise 0.02; lateral: 0 with 0.05 of slip.
    let fwd: Vec<f64> = v.iter().map(|m| m.vel_mps[0]).collect();
    let lat: Vec<f64> = v.iter().map(|m| m.vel_mps[1]).collect();
    let (m, sd) = mean_sd(&fwd);
    // Standard error of the mean: 0.02 / sqrt(1000) = 6e-4.
    assert!((m - 0.525).abs() < 2.5e-3, "{m}");
    assert!((sd - 0.02).abs() < 2.5e-3, "{sd}");
    let (m, sd) = mean_sd(&lat);
    assert!(m.abs() < 6e-3, "{m}");
    assert!((sd - 0.05).abs() < 5e-3, "{sd}");
    // Without noise the forward reading is exactly the scaled speed.
    sc.odometry = Some(odometry(0.9, 1e-12, 0.0));
    let out = simulate(&sc, 7).unwrap();
    for m in &out.velocity {
        assert!((m.vel_mps[0] - 0.45).abs() < 1e-9, "{m:?}");
        assert_eq!(m.vel_mps[1], 0.0);
        assert_eq!(m.sigma_mps[1], 0.0);
    }
}

/// The flow measures the body velocity: a path along east read while the
/// body faces north-east has forward and rightward (negative y) parts.
#[test]
fn flow_reads_the_body_frame_velocity_in_the_turn() {
    let mut sc = circle();
    // Flown at 1.2 m: the range finder reads the height.
    sc.height_m = 1.2;
    sc.flow = Some(FlowConfig {
        rate_hz: 25.0,
        offset_s: 0.0,
        scale: 0.8,
        sigma_mps: 1e-12,
        range_sigma_m: 0.02,
        dropouts: Vec::new(),
    });
    let out = simulate(&sc, 1).unwrap();
    assert_eq!(out.velocity.len(), 500);
    let mut range_err = Vec::new();
    for m in &out.velocity {
        assert_eq!(m.source, BodyVelocity::SOURCE_FLOW);
        assert_eq!(m.sigma_mps, [1e-12, 1e-12, 0.0]);
        // The truth at the sample time, rotated into the body by hand.
        let k = out
            .truth
            .iter()
            .position(|g| g.header.meas_time_ns == m.header.meas_time_ns)
            .unwrap();
        let g = &out.truth[k];
        let yaw = 2.0 * g.quat[3].atan2(g.quat[0]);
        let (s, c) = yaw.sin_cos();
        let [ve, vn, _] = g.vel_mps;
        let body = [c * ve + s * vn, -s * ve + c * vn];
        assert!((m.vel_mps[0] - 0.8 * body[0]).abs() < 1e-9);
        assert!((m.vel_mps[1] - 0.8 * body[1]).abs() < 1e-9);
        // The path's tangent is the body x axis.
        assert!((m.vel_mps[0] - 0.4).abs() < 1e-6 && m.vel_mps[1].abs() < 1e-6);
        // The range (mm): the height plus the range finder's noise.
        range_err.push(f64::from(m.range_mm) * 1e-3 - g.pos_m[2]);
    }
    let n = range_err.len() as f64;
    let mean = range_err.iter().sum::<f64>() / n;
    let sd = (range_err.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
    assert!(
        mean.abs() < 0.005 && (0.015..0.025).contains(&sd),
        "{mean} {sd}"
    );
    // The range finder's heights: one per flow sample, at its time, the
    // range it carries.
    assert_eq!(out.height.len(), out.velocity.len());
    for (k, (h, m)) in out.height.iter().zip(&out.velocity).enumerate() {
        assert_eq!(h.header.seq, k as u64);
        assert_eq!(h.header.meas_time_ns, m.header.meas_time_ns);
        assert_eq!(h.source, Height::SOURCE_RANGE_FINDER);
        assert_eq!(Some(h.range_m), m.range_m());
    }
}

#[test]
fn dropouts_offsets_and_the_merged_order() {
    let mut sc = circle();
    sc.duration_s = 2.0;
    let mut o = odometry(1.0, 0.01, 0.0);
    o.rate_hz = 10.0;
    o.dropouts = vec![Dropout {
        start_s: 0.5,
        duration_s: 0.5,
    }];
    sc.odometry = Some(o);
    sc.flow = Some(FlowConfig {
        rate_hz: 5.0,
        offset_s: 0.05,
        ..FlowConfig::default()
    });
    let out = simulate(&sc, 2).unwrap();
    let times: Vec<(u64, u32)> = out
        .velocity
        .iter()
        .map(|m| (m.header.meas_time_ns / 1_000_000, m.source))
        .collect();
    let (o, f) = (BodyVelocity::SOURCE_ODOMETRY, BodyVelocity::SOURCE_FLOW);
    assert_eq!(
        times,
        [
            (0, o),
            (50, f),
            (100, o),
            (200, o),
            (250, f),
            (300, o),
            (400, o),
            (450, f),
            (650, f),
            (850, f),
            (1000, o),
            (1050, f),
            (1100, o),
            (1200, o),
            (1250, f),
            (1300, o),
            (1400, o),
            (1450, f),
            (1500, o),
            (1600, o),
            (1650, f),
            (1700, o),
            (1800, o),
            (1850, f),
            (1900, o),
        ]
    );
    // In the merged stream a velocity follows the other samples of its time.
    let merged = out.merged();
    let i = merged
        .iter()
        .position(|r| matches!(r, SimRecord::Velocity(v) if v.header.meas_time_ns == 100_000_000))
        .unwrap();
    assert!(matches!(merged[i - 1], SimRecord::Tdoa(t) if t.header.meas_time_ns == 100_000_000));
}

#[test]
fn bad_velocity_settings_are_refused_with_the_key_named() {
    let err = |sc: &Scenario| sc.validate().unwrap_err().to_string();
    let mut sc = circle();
    sc.odometry = Some(odometry(1.0, 0.0, 0.05));
    assert_eq!(err(&sc), "sim.odometry.sigma_mps must be > 0, got 0");
    sc.odometry = Some(odometry(-1.0, 0.02, 0.05));
    assert_eq!(err(&sc), "sim.odometry.scale must be > 0, got -1");
    sc.odometry = Some(odometry(1.0, 0.02, -0.1));
    assert_eq!(
        err(&sc),
        "sim.odometry.lateral_sigma_mps must be >= 0, got -0.1"
    );
    let mut o = odometry(1.0, 0.02, 0.05);
    o.dropouts = vec![Dropout {
        start_s: 1.0,
        duration_s: 0.0,
    }];
    sc.odometry = Some(o);
    assert_eq!(
        err(&sc),
        "sim.odometry.dropouts[0].duration_s must be > 0, got 0"
    );
    sc.odometry = Some(odometry(1.0, 0.02, 0.05));
    sc.flow = Some(FlowConfig {
        rate_hz: f64::NAN,
        ..FlowConfig::default()
    });
    assert_eq!(err(&sc), "sim.flow.rate_hz must be finite, got NaN");
    // Odometry at 50 Hz and flow at 20 Hz from 0 meet at 0, 0.1 s, ...
    sc.flow = Some(FlowConfig {
        rate_hz: 20.0,
        ..FlowConfig::default()
    });
    assert!(matches!(
        sc.validate(),
        Err(ScenarioConfigError::VelocityTimeShared { ref key, time_s }) if key == "sim.flow.offset_s" && time_s == 0.0
    ));
    // ... and from 0.005 s never: 50 Hz is 0, 0.02, ...; 20 Hz 0.005, 0.055, ...
    sc.flow = Some(FlowConfig {
        rate_hz: 20.0,
        offset_s: 0.005,
        ..FlowConfig::default()
    });
    assert!(sc.validate().is_ok());
    // The TOML form refuses unknown keys.
    let text = "[sim]\n[sim.odometry]\nrate_hz = 20.0\nscale = 1.05\nslip = 0.1\n";
    let e = Scenario::from_toml_str(text, "o.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("o.toml") && e.contains("slip"), "{e}");
    let text = "[sim]\n[sim.odometry]\nrate_hz = 20.0\nscale = 1.05\n";
    let sc = Scenario::from_toml_str(text, "o.toml").unwrap();
    assert_eq!(
        sc.odometry,
        Some(OdometryConfig {
            rate_hz: 20.0,
            scale: 1.05,
            ..OdometryConfig::default()
        })
    );
}
