//! Tests of the fix builder: epochs, determinism, accounting, velocity.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas
#![allow(clippy::unwrap_used)] // helpers outside #[test] fns

use crate::common;

use common::{dist, err, paper_square, Gauss, CONST3};
use insuwb_msg::{Header, UwbFix, UwbTdoa};
use insuwb_uwb::fix::{FixBuilder, FixConfig, FixConfigError, FixMode, PushError, SkipReason};
use insuwb_uwb::solve::SolveError;

const MS: u64 = 1_000_000;

fn meas(t_ns: u64, anchors: &[[f64; 3]], a: usize, b: usize, p: [f64; 3], noise_m: f64) -> UwbTdoa {
    UwbTdoa {
        header: Header::new(0, t_ns),
        anchor_a: a as u32,
        anchor_b: b as u32,
        diff_m: dist(p, anchors[b]) - dist(p, anchors[a]) + noise_m,
        anchor_a_pos_m: anchors[a],
        anchor_b_pos_m: anchors[b],
    }
}

fn cfg_2d(height_m: f64) -> FixConfig {
    FixConfig {
        mode: FixMode::Mode2d { height_m },
        ..FixConfig::default()
    }
}

/// A tag on a circle, one pair every 20 ms (cycling through six pairs, some
/// reversed), noisy; 2D paper square with anchors at 2 m, tag at 0.3 m.
fn circle_stream(n: usize, seed: u64) -> (Vec<UwbTdoa>, [[f64; 3]; 4]) {
    let anchors = paper_square(2.0);
    let pairs = [(0, 1), (2, 1), (2, 3), (3, 0), (0, 2), (3, 1)];
    let mut g = Gauss::new(seed);
    let mut out = Vec::new();
    for k in 0..n {
        let t_ns = 7 * MS + k as u64 * 20 * MS;
        let th = 0.15 * t_ns as f64 * 1e-9;
        let p = [3.0 * th.cos(), 3.0 * th.sin(), 0.3];
        let (a, b) = pairs[k % pairs.len()];
        out.push(meas(t_ns, &anchors, a, b, p, 0.05 * g.normal()));
    }
    (out, anchors)
}

fn run(
    cfg: &FixConfig,
    stream: &[UwbTdoa],
    flush_before: &[bool],
) -> (Vec<UwbFix>, insuwb_uwb::FixStats) {
    let mut b = FixBuilder::new(cfg.clone()).unwrap();
    let mut fixes = Vec::new();
    for (m, &flush) in stream.iter().zip(flush_before) {
        if flush {
            fixes.extend(b.flush());
        }
        fixes.extend(b.push(m).unwrap());
    }
    fixes.extend(b.flush());
    (fixes, *b.stats())
}

#[test]
fn output_does_not_depend_on_flushes_at_epoch_boundaries() {
    let (stream, _) = circle_stream(600, 11);
    let cfg = cfg_2d(0.3);
    let period = cfg.period_ns();
    let none = vec![false; stream.len()];
    let (reference, ref_stats) = run(&cfg, &stream, &none);
    assert!(reference.len() >= 110, "{} fixes", reference.len());
    // Boundaries: before a measurement whose epoch differs from the previous one.
    let boundary: Vec<bool> = (0..stream.len())
        .map(|i| {
            i > 0
                && stream[i].header.meas_time_ns.div_ceil(period)
                    != stream[i - 1].header.meas_time_ns.div_ceil(period)
        })
        .collect();
    let (all, all_stats) = run(&cfg, &stream, &boundary);
    assert_eq!(all, reference);
    assert_eq!(all_stats, ref_stats);
    let mut g = Gauss::new(3);
    for _ in 0..5 {
        let some: Vec<bool> = boundary.iter().map(|&b| b && g.uniform() < 0.35).collect();
        assert_eq!(run(&cfg, &stream, &some).0, reference);
    }
    // Sequence numbers count fixes; times increase; 2D flag set.
    for (i, f) in reference.iter().enumerate() {
        assert_eq!(f.header.seq, i as u64);
        assert!(f.header.flags & UwbFix::FLAG_2D != 0);
        assert!(f.pos_m.iter().all(|v| v.is_finite()));
    }
    assert!(reference
        .windows(2)
        .all(|w| w[0].header.meas_time_ns < w[1].header.meas_time_ns));
}

#[test]
fn a_replay_from_any_epoch_gives_the_recordings_fixes_once_aligned() {
    // One pair every 20 ms from 7 ms: the epoch windows (100 ms) hold five
    // measurements each. Replayed from an epoch 15 ms after a whole second
    // (more than the 13 ms from the last measurement of a window to its
    // end, so unaligned windows would group them otherwise), every time
    // moves by that epoch.
    let (stream, _) = circle_stream(600, 5);
    let cfg = cfg_2d(0.3);
    let none = vec![false; stream.len()];
    let (reference, ref_stats) = run(&cfg, &stream, &none);
    assert!(reference.len() >= 110, "{} fixes", reference.len());
    let epoch = 7_015 * MS;
    let shifted: Vec<UwbTdoa> = stream
        .iter()
        .map(|m| {
            let mut m = *m;
            m.header.meas_time_ns += epoch;
            m
        })
        .collect();
    let replay = |align: bool| {
        let mut b = FixBuilder::new(cfg.clone()).unwrap();
        if align {
            b.align_to(epoch);
        }
        let mut fixes: Vec<UwbFix> = shifted.iter().filter_map(|m| b.push(m).unwrap()).collect();
        fixes.extend(b.flush());
        (fixes, *b.stats())
    };
    let (aligned, aligned_stats) = replay(true);
    assert_eq!(aligned_stats, ref_stats);
    assert_eq!(aligned.len(), reference.len());
    for (a, r) in aligned.iter().zip(&reference) {
        assert_eq!(a.header.meas_time_ns, r.header.meas_time_ns + epoch);
        assert_eq!(a.n_meas, r.n_meas);
        assert_eq!(a.pos_m, r.pos_m);
    }
    // Not aligned, the windows cut the stream 2.5 ms later: other groups.
    let (unaligned, _) = replay(false);
    let moved = unaligned
        .iter()
        .zip(&reference)
        .any(|(u, r)| u.header.meas_time_ns != r.header.meas_time_ns + epoch || u.pos_m != r.pos_m);
    assert!(moved || unaligned.len() != reference.len());
}

#[test]
fn epoch_is_closed_on_the_right_and_stamped_with_the_latest_measurement() {
    let anchors = paper_square(2.0);
    let p = [1.0, -2.0, 0.0];
    let mut b = FixBuilder::new(cfg_2d(0.0)).unwrap();
    // Epoch 1 is (0, 100 ms]: 40, 70 and exactly 100 ms belong to it.
    assert_eq!(
        b.push(&meas(40 * MS, &anchors, 0, 1, p, 0.0)).unwrap(),
        None
    );
    assert_eq!(
        b.push(&meas(70 * MS, &anchors, 0, 2, p, 0.0)).unwrap(),
        None
    );
    assert_eq!(
        b.push(&meas(100 * MS, &anchors, 0, 3, p, 0.0)).unwrap(),
        None
    );
    assert_eq!(b.pending_pairs(), 3);
    // 100 ms + 1 ns is epoch 2: it closes epoch 1.
    let f = b
        .push(&meas(100 * MS + 1, &anchors, 1, 2, p, 0.0))
        .unwrap()
        .unwrap();
    assert_eq!(f.header.meas_time_ns, 100 * MS);
    assert_eq!((f.header.seq, f.n_meas), (0, 3));
    assert!(err(f.pos_m, p) < 1e-9);
    assert_eq!(b.pending_pairs(), 1);
    // Epoch 0 is (-100 ms, 0]: a measurement at t = 0 is alone in it.
    let mut b = FixBuilder::new(cfg_2d(0.0)).unwrap();
    b.push(&meas(0, &anchors, 0, 1, p, 0.0)).unwrap();
    assert_eq!(b.push(&meas(1, &anchors, 0, 2, p, 0.0)).unwrap(), None);
    assert_eq!(b.stats().skipped_too_few_pairs, 1);
}

#[test]
fn latest_measurement_per_unordered_pair_wins_with_the_sign_flipped() {
    let anchors = paper_square(2.0);
    let p = [-1.5, 2.5, 0.0];
    let mut b = FixBuilder::new(cfg_2d(0.0)).unwrap();
    b.push(&meas(10 * MS, &anchors, 0, 1, p, 0.8)).unwrap(); // bad, superseded below
    b.push(&meas(20 * MS, &anchors, 0, 2, p, 0.0)).unwrap();
    b.push(&meas(30 * MS, &anchors, 0, 3, p, 0.0)).unwrap();
    // (1, 0) is the pair (0, 1): its diff is |p - a0| - |p - a1|.
    b.push(&meas(40 * MS, &anchors, 1, 0, p, 0.0)).unwrap();
    let f = b.flush().unwrap();
    assert_eq!(f.n_meas, 3);
    assert!(err(f.pos_m, p) < 1e-9, "{:?}", f.pos_m);
    assert_eq!(f.header.meas_time_ns, 40 * MS);
    assert_eq!((b.stats().accepted, b.stats().superseded), (4, 1));
}

#[test]
fn epoch_end_flag_closes_the_group_at_once() {
    let anchors = CONST3;
    let cfg = FixConfig {
        mode: FixMode::Mode3d,
        ..FixConfig::default()
    };
    let mut b = FixBuilder::new(cfg).unwrap();
    // Simultaneous groups every 25 ms (faster than the 100 ms period): each
    // flagged group gives its own fix.
    let mut fixes = Vec::new();
    for g in 0..8u64 {
        let t = 5 * MS + g * 25 * MS;
        let p = [0.2 + 0.01 * g as f64, -0.5, 1.2];
        for k in 1..8 {
            let mut m = meas(t, &anchors, 0, k, p, 0.0);
            if k == 7 {
                m.header.flags |= UwbTdoa::FLAG_EPOCH_END;
            }
            let out = b.push(&m).unwrap();
            assert_eq!(out.is_some(), k == 7);
            if let Some(f) = out {
                assert!(err(f.pos_m, p) < 1e-9);
                assert_eq!(f.header.meas_time_ns, t);
                assert_eq!(f.header.flags & UwbFix::FLAG_2D, 0);
                fixes.push(f);
            }
        }
    }
    assert_eq!(fixes.len(), 8);
    assert_eq!(b.flush(), None);
    // A flagged measurement of a later epoch closes the open epoch (a fix)
    // and then its own group of one pair (skipped).
    let p = [0.0, 0.0, 1.0];
    b.push(&meas(310 * MS, &anchors, 0, 1, p, 0.0)).unwrap();
    b.push(&meas(320 * MS, &anchors, 0, 2, p, 0.0)).unwrap();
    b.push(&meas(330 * MS, &anchors, 0, 3, p, 0.0)).unwrap();
    let skipped = b.stats().skipped_too_few_pairs;
    let mut m = meas(450 * MS, &anchors, 0, 4, p, 0.0);
    m.header.flags = UwbTdoa::FLAG_EPOCH_END;
    let f = b.push(&m).unwrap().unwrap();
    assert_eq!((f.header.meas_time_ns, f.n_meas), (330 * MS, 3));
    assert_eq!(b.stats().skipped_too_few_pairs, skipped + 1);
    assert_eq!(b.pending_pairs(), 0);
}

#[test]
fn skipped_epochs_are_counted_per_reason() {
    let anchors = paper_square(2.0);
    let p = [0.5, 0.5, 0.0];
    let mut b = FixBuilder::new(cfg_2d(0.0)).unwrap();
    // Two pairs: fewer than min_pairs = 3.
    b.push(&meas(10 * MS, &anchors, 0, 1, p, 0.0)).unwrap();
    b.push(&meas(20 * MS, &anchors, 0, 2, p, 0.0)).unwrap();
    assert_eq!(b.flush(), None);
    assert_eq!(b.stats().skipped_too_few_pairs, 1);
    assert_eq!(
        b.last_skip(),
        Some(&SkipReason::TooFewPairs { count: 2, min: 3 })
    );
    // Collinear anchors 10, 11, 12, 13.
    let line = [
        [0.0, 0.0, 2.0],
        [3.0, 0.0, 2.0],
        [6.0, 0.0, 2.0],
        [9.0, 0.0, 2.0],
    ];
    for (i, k) in [1usize, 2, 3].into_iter().enumerate() {
        let mut m = meas(120 * MS + i as u64, &line, 0, k, [4.0, 3.0, 0.0], 0.0);
        m.anchor_a += 10;
        m.anchor_b += 10;
        b.push(&m).unwrap();
    }
    assert_eq!(b.flush(), None);
    assert_eq!(b.stats().skipped_degenerate, 1);
    assert!(matches!(
        b.last_skip(),
        Some(SkipReason::Solve(SolveError::DegenerateGeometry { .. }))
    ));
    // A tag 30 m away from the anchors: runaway.
    for k in 1..4 {
        b.push(&meas(
            220 * MS + k as u64,
            &anchors,
            0,
            k,
            [30.0, 1.0, 0.0],
            0.0,
        ))
        .unwrap();
    }
    assert_eq!(b.flush(), None);
    assert_eq!(b.stats().skipped_runaway, 1);
    // Every closed epoch is accounted for.
    let s = b.stats();
    assert_eq!(s.epochs, 3);
    assert_eq!(s.fixes, 0);
}

#[test]
fn bad_measurements_are_dropped_and_counted() {
    let anchors = paper_square(2.0);
    let p = [0.5, 0.5, 0.0];
    let cfg = FixConfig {
        max_pairs: 3,
        ..cfg_2d(0.0)
    };
    let mut b = FixBuilder::new(cfg).unwrap();
    b.push(&meas(50 * MS, &anchors, 0, 1, p, 0.0)).unwrap();
    let e = b.push(&meas(49 * MS, &anchors, 0, 2, p, 0.0)).unwrap_err();
    assert_eq!(
        e,
        PushError::TimeBackwards {
            time_ns: 49 * MS,
            last_ns: 50 * MS
        }
    );
    let mut m = meas(51 * MS, &anchors, 0, 2, p, 0.0);
    m.diff_m = f64::NAN;
    assert!(matches!(
        b.push(&m),
        Err(PushError::NonFinite {
            field: "diff_m",
            ..
        })
    ));
    let mut m = meas(51 * MS, &anchors, 0, 2, p, 0.0);
    m.anchor_b_pos_m[1] = f64::INFINITY;
    assert!(matches!(
        b.push(&m),
        Err(PushError::NonFinite {
            field: "anchor_b_pos_m",
            ..
        })
    ));
    let m = meas(51 * MS, &anchors, 2, 2, p, 0.0);
    assert_eq!(b.push(&m), Err(PushError::SameAnchor { id: 2 }));
    // A difference longer than the baseline between its anchors cannot be.
    let m = meas(51 * MS, &anchors, 0, 1, p, 100.0);
    assert!(matches!(
        b.push(&m),
        Err(PushError::Impossible { a: 0, b: 1, .. })
    ));
    b.push(&meas(52 * MS, &anchors, 0, 2, p, 0.0)).unwrap();
    b.push(&meas(53 * MS, &anchors, 0, 3, p, 0.0)).unwrap();
    // The table holds 3 pairs: a 4th is dropped, a known pair is not.
    assert_eq!(
        b.push(&meas(54 * MS, &anchors, 1, 2, p, 0.0)),
        Err(PushError::PairCapacity { max: 3, a: 1, b: 2 })
    );
    b.push(&meas(55 * MS, &anchors, 3, 0, p, 0.0)).unwrap();
    let s = *b.stats();
    assert_eq!(
        (
            s.dropped_time_backwards,
            s.dropped_non_finite,
            s.dropped_same_anchor,
            s.dropped_capacity,
            s.dropped_impossible,
            s.accepted
        ),
        (1, 2, 1, 1, 1, 4)
    );
    // The builder is still usable: the epoch gives its fix.
    let f = b.flush().unwrap();
    assert!(err(f.pos_m, p) < 1e-9);
    assert_eq!(f.header.meas_time_ns, 55 * MS);
}

#[test]
fn regression_velocity_is_exact_for_noise_free_constant_velocity() {
    let anchors = CONST3;
    let v = [0.6, -0.25, 0.1];
    let cfg = FixConfig {
        mode: FixMode::Mode3d,
        ..FixConfig::default()
    };
    let mut b = FixBuilder::new(cfg).unwrap();
    let mut fixes = Vec::new();
    // TDOA2-style ring pairs, 8 per epoch, spread over the epoch: all pairs of
    // an epoch are measured at its last instant here so the fix is exact.
    for e in 1..=15u64 {
        let t = e * 100 * MS - 3 * MS;
        let s = t as f64 * 1e-9;
        let p = [-1.0 + v[0] * s, 1.0 + v[1] * s, 0.8 + v[2] * s];
        for k in 0..8 {
            fixes.extend(b.push(&meas(t, &anchors, k, (k + 1) % 8, p, 0.0)).unwrap());
        }
    }
    fixes.extend(b.flush());
    assert_eq!(fixes.len(), 15);
    assert_eq!(b.stats().reseeded, 0);
    for (i, f) in fixes.iter().enumerate() {
        let valid = f.header.flags & UwbFix::FLAG_VEL_VALID != 0;
        // Default: 4 fixes spanning 0.3 s.
        assert_eq!(valid, i >= 3, "fix {i}");
        if valid {
            for k in 0..3 {
                assert!(
                    (f.vel_mps[k] - v[k]).abs() < 1e-8,
                    "fix {i}: {:?}",
                    f.vel_mps
                );
            }
            assert!(f.vel_cov[0][0] > 0.0 && f.vel_cov[0][0] < f.pos_cov_m2[0][0] * 100.0);
        } else {
            assert_eq!(f.vel_mps, [0.0; 3]);
        }
    }
}

#[test]
fn config_parses_and_errors_name_the_key() {
    let cfg: FixConfig = toml::from_str(
        r#"
        period_s = 0.05
        mode = { kind = "3d" }
        [solver]
        tdoa_sigma_m = 0.12
        [velocity]
        window_len = 6
        "#,
    )
    .unwrap();
    assert_eq!(cfg.mode, FixMode::Mode3d);
    assert_eq!(
        (
            cfg.period_s,
            cfg.solver.tdoa_sigma_m,
            cfg.velocity.window_len
        ),
        (0.05, 0.12, 6)
    );
    assert_eq!(cfg.min_pairs, 3);
    cfg.validate().unwrap();
    let cfg: FixConfig = toml::from_str("mode = { kind = \"2d\", height_m = 0.25 }").unwrap();
    assert_eq!(cfg.mode, FixMode::Mode2d { height_m: 0.25 });
    assert!(toml::from_str::<FixConfig>("perod_s = 0.1").is_err());
    assert!(toml::from_str::<FixConfig>("[solver]\ntdoa_sigma = 0.1").is_err());
    assert!(toml::from_str::<FixConfig>("mode = { kind = \"2d\", height = 0.25 }").is_err());
    assert_eq!(FixConfig::default(), toml::from_str("").unwrap());

    let e = FixConfig {
        period_s: -1.0,
        ..FixConfig::default()
    }
    .validate()
    .unwrap_err();
    assert_eq!(e.to_string(), "period_s must be in [0.001, 60], got -1");
    let e = FixConfig {
        mode: FixMode::Mode3d,
        min_pairs: 2,
        ..FixConfig::default()
    }
    .validate()
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "min_pairs must be >= 3 (3D) and <= max_pairs, got 2"
    );
    let mut c = FixConfig::default();
    c.solver.max_step_m = 0.0;
    assert_eq!(
        c.validate().unwrap_err().to_string(),
        "solver.max_step_m must be finite and > 0, got 0"
    );
    let e = FixConfig {
        mode: FixMode::Mode2d { height_m: f64::NAN },
        ..FixConfig::default()
    }
    .validate();
    assert!(matches!(
        e,
        Err(FixConfigError::OutOfRange {
            key: "mode.height_m",
            ..
        })
    ));
    assert!(FixBuilder::new(FixConfig {
        max_pairs: 0,
        ..FixConfig::default()
    })
    .is_err());
}

/// `average_pairs`: the pair's differences in one epoch are averaged and
/// the pair weighs as many measurements as it has (the least-squares fix of
/// every difference); without it the last difference counts.
#[test]
fn averaged_pairs_use_every_difference_of_the_epoch() {
    let anchors = paper_square(2.0);
    let p = [0.5, -0.4, 0.3];
    // Epoch (0, 100 ms]: pair (0, 1) four times with errors +0.1, -0.1,
    // -0.1 and +0.4 (mean +0.075); the other pairs once each, exact.
    let mut stream = vec![
        meas(10 * MS, &anchors, 0, 1, p, 0.1),
        meas(20 * MS, &anchors, 0, 1, p, -0.1),
        meas(30 * MS, &anchors, 0, 1, p, -0.1),
        meas(40 * MS, &anchors, 0, 1, p, 0.4),
    ];
    stream.push(meas(50 * MS, &anchors, 1, 2, p, 0.0));
    stream.push(meas(60 * MS, &anchors, 2, 3, p, 0.0));
    stream.push(meas(70 * MS, &anchors, 3, 0, p, 0.0));
    let solve = |average_pairs: bool| {
        let cfg = FixConfig {
            average_pairs,
            ..cfg_2d(0.3)
        };
        let (fixes, stats) = run(&cfg, &stream, &vec![false; stream.len()]);
        assert_eq!(fixes.len(), 1);
        assert_eq!(stats.superseded, 3);
        fixes[0]
    };
    let averaged = solve(true);
    let last = solve(false);
    let e = |q: [f64; 3]| ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt();
    assert!(
        e(averaged.pos_m) < 0.5 * e(last.pos_m),
        "{averaged:?} {last:?}"
    );
    // Four measurements of one pair weigh four times one: the averaged fix
    // is more certain along that pair's gradient than with its last one.
    let tr = |f: &insuwb_msg::UwbFix| f.pos_cov_m2[0][0] + f.pos_cov_m2[1][1];
    assert!(tr(&averaged) < tr(&last), "{averaged:?} {last:?}");
}

/// With a site calibration, the builder corrects each measurement by its
/// pair's bias (the constant before the first fix, then at the previous
/// fix) and flags it; [`FixBuilder::calibrate`] gives the same measurement
/// as `push` uses, and a flagged one is not corrected again: the fix of
/// biased measurements lands where the unbiased ones put it.
#[test]
fn a_calibration_removes_the_pair_biases_once() {
    use insuwb_uwb::calibration::{Family, Sample, SiteCalibration};
    use std::collections::BTreeMap;
    use std::sync::Arc;
    let (stream, anchors) = circle_stream(600, 3);
    let bias = |a: u32, b: u32| {
        let s = if a < b { 1.0 } else { -1.0 };
        s * 0.1 * f64::from(a.min(b) + 2 * a.max(b)) / 7.0
    };
    let biased: Vec<UwbTdoa> = stream
        .iter()
        .map(|m| UwbTdoa {
            diff_m: m.diff_m + bias(m.anchor_a, m.anchor_b),
            ..*m
        })
        .collect();
    let samples: Vec<Sample> = biased
        .iter()
        .zip(&stream)
        .map(|(b, m)| Sample {
            a: b.anchor_a,
            b: b.anchor_b,
            pos_m: [0.0, 0.0, 0.3],
            residual_m: b.diff_m - m.diff_m,
        })
        .collect();
    let an: BTreeMap<u32, [f64; 3]> = (0u32..).zip(anchors).collect();
    let calib = Arc::new(SiteCalibration::learn(an, Family::PairConstant, &samples).unwrap());
    let cfg = cfg_2d(0.3);
    let mut plain = FixBuilder::new(cfg.clone()).unwrap();
    let mut cal = FixBuilder::new(cfg.clone())
        .unwrap()
        .with_calibration(Some(calib.clone()));
    let mut twice = FixBuilder::new(cfg).unwrap().with_calibration(Some(calib));
    let (mut fp, mut fc, mut ft) = (Vec::new(), Vec::new(), Vec::new());
    for (m, b) in stream.iter().zip(&biased) {
        fp.extend(plain.push(m).unwrap());
        let c = cal.calibrate(b);
        assert_ne!(c.header.flags & UwbTdoa::FLAG_CALIBRATED, 0);
        assert!((c.diff_m - m.diff_m).abs() < 1e-9);
        assert_eq!(cal.calibrate(&c), c);
        fc.extend(cal.push(b).unwrap());
        ft.extend(twice.push(&c).unwrap());
    }
    assert_eq!(fp.len(), fc.len());
    assert!(!fp.is_empty());
    for ((p, c), t) in fp.iter().zip(&fc).zip(&ft) {
        assert!(dist(p.pos_m, c.pos_m) < 1e-6, "{:?} {:?}", p.pos_m, c.pos_m);
        assert_eq!(c.pos_m, t.pos_m);
    }
}
