//! Known-answer tests of the TDOA solver.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas

use crate::common;

use common::{dist, err, experiment_room, obs, paper_square, ring, star, Gauss, CONST3};
use insuwb_msg::{Header, UwbTdoa};
use insuwb_uwb::solve::{
    solve_2d, solve_2d_weighted, solve_3d, solve_3d_weighted, GeometryCheck, Seed, SolveError,
    SolverConfig, TdoaObs,
};

fn cfg() -> SolverConfig {
    SolverConfig::default()
}

#[test]
fn sign_convention_is_distance_to_b_minus_distance_to_a() {
    // Tag 2 m from A and 8 m from B: diff = |p - b| - |p - a| = 8 - 2 = +6.
    let o = TdoaObs {
        a_m: [0.0; 3],
        b_m: [10.0, 0.0, 0.0],
        diff_m: 6.0,
    };
    assert_eq!(o.predicted_diff_m([2.0, 0.0, 0.0]), 6.0);
    // d/dp (|p-b| - |p-a|) = (p-b)/|p-b| - (p-a)/|p-a| = (-1,0,0) - (1,0,0).
    assert_eq!(o.gradient([2.0, 0.0, 0.0]), [-2.0, 0.0, 0.0]);
    let f = o.flipped();
    assert_eq!((f.a_m, f.b_m, f.diff_m), (o.b_m, o.a_m, -6.0));

    // The message carries the same convention: building observations from
    // UwbTdoa samples recovers the tag, and the opposite sign does not.
    let anchors = experiment_room(2.5);
    let p = [1.5, 1.0, 0.4];
    let msgs: Vec<UwbTdoa> = (1..4)
        .map(|b| UwbTdoa {
            header: Header::new(0, 0),
            anchor_a: 0,
            anchor_b: b as u32,
            diff_m: dist(p, anchors[b]) - dist(p, anchors[0]),
            anchor_a_pos_m: anchors[0],
            anchor_b_pos_m: anchors[b],
        })
        .collect();
    let o: Vec<TdoaObs> = msgs.iter().map(TdoaObs::from_msg).collect();
    let fix = solve_2d(&o, 0.4, None, &cfg()).unwrap();
    assert!(err(fix.pos_m, p) < 1e-9, "{:?}", fix.pos_m);
    let wrong: Vec<TdoaObs> = o
        .iter()
        .map(|x| TdoaObs {
            diff_m: -x.diff_m,
            ..*x
        })
        .collect();
    if let Ok(f) = solve_2d(&wrong, 0.4, None, &cfg()) {
        assert!(
            err(f.pos_m, p) > 0.5,
            "wrong sign still found the tag: {:?}",
            f.pos_m
        );
    }
}

#[test]
fn recovers_3d_position_with_8_anchors_star_and_ring() {
    for p in [
        [0.3, -0.2, 1.5],
        [2.0, 2.5, 0.8],
        [-2.5, -3.0, 2.5],
        [3.5, 0.0, 0.3],
    ] {
        for o in [star(&CONST3, p), ring(&CONST3, p)] {
            let fix = solve_3d(&o, None, &cfg()).unwrap();
            assert!(err(fix.pos_m, p) < 1e-3, "{p:?} -> {:?}", fix.pos_m);
            assert!(err(fix.pos_m, p) < 1e-9, "{p:?} -> {:?}", fix.pos_m);
            assert_eq!(fix.n_obs, o.len());
            assert!(fix.residual_rms_m < 1e-9);
            // The closed form is exact without noise: Gauss-Newton only polishes.
            assert_eq!(fix.seed, Seed::ClosedForm);
            assert!(fix.iterations <= 2, "iterations {}", fix.iterations);
        }
    }
}

#[test]
fn recovers_3d_position_with_4_anchor_subset() {
    // an0, an1, an2, an3: two floor and two ceiling anchors, a tetrahedron.
    let sub = [CONST3[0], CONST3[1], CONST3[2], CONST3[3]];
    for p in [[0.3, -0.2, 1.5], [0.5, 0.5, 1.0], [-1.0, 0.5, 2.0]] {
        let fix = solve_3d(&star(&sub, p), None, &cfg()).unwrap();
        assert!(err(fix.pos_m, p) < 1e-3, "{p:?} -> {:?}", fix.pos_m);
        // With an init near the tag the same solution comes from the init.
        let init = [p[0] + 0.5, p[1] - 0.4, p[2] + 0.3];
        let fix = solve_3d(&ring(&sub, p), Some(init), &cfg()).unwrap();
        assert_eq!(fix.seed, Seed::Init);
        assert!(err(fix.pos_m, p) < 1e-3, "{p:?} -> {:?}", fix.pos_m);
    }
}

#[test]
fn recovers_2d_position_paper_square_and_experiment_room() {
    // Anchors above the tag: the height terms of the 2D closed form matter.
    for (anchors, points) in [
        (
            paper_square(2.0),
            [[0.0, 0.0], [3.0, -4.0], [-4.5, 4.5], [1.2, 0.7]],
        ),
        (
            experiment_room(2.4),
            [[3.5, 2.5], [0.5, 0.5], [6.5, 4.0], [2.0, 4.8]],
        ),
        (
            experiment_room(0.0),
            [[3.5, 2.5], [0.5, 4.5], [6.9, 0.1], [1.0, 1.0]],
        ),
    ] {
        for xy in points {
            let p = [xy[0], xy[1], 0.3];
            for o in [star(&anchors, p), ring(&anchors, p)] {
                let fix = solve_2d(&o, 0.3, None, &cfg()).unwrap();
                assert!(err(fix.pos_m, p) < 1e-3, "{p:?} -> {:?}", fix.pos_m);
                assert!(err(fix.pos_m, p) < 1e-9, "{p:?} -> {:?}", fix.pos_m);
                assert_eq!(fix.pos_m[2], 0.3);
                // The closed form (height terms included) is exact without noise.
                assert_eq!(fix.seed, Seed::ClosedForm);
                assert!(fix.iterations <= 2, "{p:?}: {} iterations", fix.iterations);
            }
        }
    }
}

#[test]
fn recovers_2d_position_with_anchors_at_mixed_heights() {
    // const3 anchors sit at 0.2 m and 3 m: the closed form's height terms
    // 2 (a_kz - a_rz) h do not vanish.
    for p in [[0.5, -0.5, 1.0], [2.5, 3.0, 0.3], [-2.0, -3.5, 1.8]] {
        for o in [star(&CONST3, p), ring(&CONST3, p), star(&CONST3[..4], p)] {
            let fix = solve_2d(&o, p[2], None, &cfg()).unwrap();
            assert!(err(fix.pos_m, p) < 1e-9, "{p:?} -> {:?}", fix.pos_m);
            assert_eq!(fix.seed, Seed::ClosedForm);
            assert!(fix.iterations <= 2, "{p:?}: {} iterations", fix.iterations);
        }
    }
}

#[test]
fn dop_covariance_matches_hand_computation() {
    // Tag at the centre of the paper square, in the anchors' plane, pairs
    // (0,1), (0,2), (0,3). Unit vectors from the anchors: u0 = (1,1)/r2,
    // u1 = (-1,1)/r2, u2 = (1,-1)/r2, u3 = (-1,-1)/r2; rows u_b - u_a:
    // (-r2, 0), (0, -r2), (-r2, -r2). J^T J = [[4, 2], [2, 4]],
    // inverse = [[1/3, -1/6], [-1/6, 1/3]], GDOP = sqrt(2/3).
    let anchors = paper_square(0.0);
    let c = SolverConfig {
        tdoa_sigma_m: 0.2,
        fixed_height_sigma_m: 0.05,
        ..cfg()
    };
    let fix = solve_2d(&star(&anchors, [0.0; 3]), 0.0, Some([0.3, -0.2, 0.0]), &c).unwrap();
    let s2 = 0.04;
    let expect = [
        [s2 / 3.0, -s2 / 6.0, 0.0],
        [-s2 / 6.0, s2 / 3.0, 0.0],
        [0.0, 0.0, 0.0025],
    ];
    for (r, e) in fix.cov_m2.iter().zip(expect) {
        for (x, y) in r.iter().zip(e) {
            assert!((x - y).abs() < 1e-12, "{:?}", fix.cov_m2);
        }
    }
    assert!(
        (fix.gdop - (2.0f64 / 3.0).sqrt()).abs() < 1e-12,
        "{}",
        fix.gdop
    );

    // Per-observation sigmas: all equal to 0.2 gives the same covariance;
    // all doubled gives four times it.
    let o = star(&anchors, [0.0; 3]);
    let w = solve_2d_weighted(&o, &[0.2; 3], 0.0, None, &c).unwrap();
    assert!((w.cov_m2[0][0] - s2 / 3.0).abs() < 1e-12);
    let w = solve_2d_weighted(&o, &[0.4; 3], 0.0, None, &c).unwrap();
    assert!((w.cov_m2[0][1] + 4.0 * s2 / 6.0).abs() < 1e-12);
    assert!(
        (w.gdop - (2.0f64 / 3.0).sqrt()).abs() < 1e-12,
        "GDOP is geometry only"
    );
}

#[test]
fn gdop_is_lower_at_the_centre_than_near_a_corner() {
    let anchors = paper_square(0.0);
    let all_pairs = |p: [f64; 3]| {
        let mut v = Vec::new();
        for i in 0..4 {
            for j in i + 1..4 {
                v.push(obs(anchors[i], anchors[j], p));
            }
        }
        v
    };
    let centre = solve_2d(&all_pairs([0.0, 0.0, 0.0]), 0.0, None, &cfg()).unwrap();
    let corner = solve_2d(&all_pairs([4.0, 4.2, 0.0]), 0.0, None, &cfg()).unwrap();
    assert!(
        centre.gdop < corner.gdop,
        "centre {} corner {}",
        centre.gdop,
        corner.gdop
    );
    assert!(centre.cov_m2[0][0] < corner.cov_m2[0][0]);
}

fn check_scatter(
    label: &str,
    fixes: &[[f64; 3]],
    truth: [f64; 3],
    predicted: [[f64; 3]; 3],
    dims: usize,
) {
    let n = fixes.len() as f64;
    let mut mean = [0.0; 3];
    for f in fixes {
        for k in 0..3 {
            mean[k] += f[k] / n;
        }
    }
    for k in 0..dims {
        assert!(
            (mean[k] - truth[k]).abs() < 0.1 * predicted[k][k].sqrt(),
            "{label}: bias {mean:?}"
        );
    }
    for i in 0..dims {
        for j in 0..dims {
            let emp: f64 = fixes
                .iter()
                .map(|f| (f[i] - mean[i]) * (f[j] - mean[j]))
                .sum::<f64>()
                / (n - 1.0);
            let pred = predicted[i][j];
            let scale = (predicted[i][i] * predicted[j][j]).sqrt();
            if i == j {
                assert!(
                    (emp / pred - 1.0).abs() < 0.15,
                    "{label}: var[{i}] empirical {emp} predicted {pred}"
                );
            } else {
                assert!(
                    (emp - pred).abs() < 0.15 * scale,
                    "{label}: cov[{i}][{j}] empirical {emp} predicted {pred}"
                );
            }
        }
    }
}

#[test]
fn covariance_matches_the_scatter_of_2000_noisy_solves() {
    let c = SolverConfig {
        tdoa_sigma_m: 0.1,
        ..cfg()
    };
    let mut g = Gauss::new(0x5eed_0001);

    // 3D, the 8 const3 anchors, pairs against an0.
    let p = [0.5, -0.3, 1.2];
    let clean = star(&CONST3, p);
    let predicted = solve_3d(&clean, None, &c).unwrap().cov_m2;
    let mut fixes = Vec::new();
    for _ in 0..2000 {
        let noisy: Vec<TdoaObs> = clean
            .iter()
            .map(|o| TdoaObs {
                diff_m: o.diff_m + 0.1 * g.normal(),
                ..*o
            })
            .collect();
        fixes.push(solve_3d(&noisy, None, &c).unwrap().pos_m);
    }
    check_scatter("3d", &fixes, p, predicted, 3);

    // 2D, the paper square, all six pairs.
    let anchors = paper_square(2.0);
    let p = [1.5, -2.0, 0.2];
    let mut clean = Vec::new();
    for i in 0..4 {
        for j in i + 1..4 {
            clean.push(obs(anchors[i], anchors[j], p));
        }
    }
    let predicted = solve_2d(&clean, 0.2, None, &c).unwrap().cov_m2;
    let mut fixes = Vec::new();
    for _ in 0..2000 {
        let noisy: Vec<TdoaObs> = clean
            .iter()
            .map(|o| TdoaObs {
                diff_m: o.diff_m + 0.1 * g.normal(),
                ..*o
            })
            .collect();
        fixes.push(solve_2d(&noisy, 0.2, None, &c).unwrap().pos_m);
    }
    check_scatter("2d", &fixes, p, predicted, 2);
}

#[test]
fn collinear_and_coplanar_anchors_are_refused() {
    let line: Vec<[f64; 3]> = (0..5).map(|k| [2.0 * k as f64, 1.0, 2.0]).collect();
    let p = [3.0, 4.0, 0.5];
    match solve_2d(&star(&line, p), 0.5, None, &cfg()) {
        Err(SolveError::DegenerateGeometry {
            check: GeometryCheck::AnchorSpread,
            condition,
            max,
        }) => {
            assert!(condition > max, "{condition}");
        }
        other => panic!("expected degenerate geometry, got {other:?}"),
    }
    match solve_3d(&star(&line, p), None, &cfg()) {
        Err(SolveError::DegenerateGeometry {
            check: GeometryCheck::AnchorSpread,
            ..
        }) => {}
        other => panic!("expected degenerate geometry, got {other:?}"),
    }
    // Coplanar anchors leave a mirror ambiguity in 3D.
    match solve_3d(&star(&paper_square(2.0), [1.0, 1.0, 0.5]), None, &cfg()) {
        Err(
            e @ SolveError::DegenerateGeometry {
                check: GeometryCheck::AnchorSpread,
                ..
            },
        ) => {
            assert!(e.to_string().contains("degenerate geometry"), "{e}");
        }
        other => panic!("expected degenerate geometry, got {other:?}"),
    }
}

#[test]
fn ill_conditioned_jacobian_is_refused() {
    // Far outside a small square the TDOA directions become nearly parallel.
    let anchors = paper_square(0.0).map(|a| [a[0] * 0.01, a[1] * 0.01, 0.0]);
    let p = [1.5, 0.2, 0.0];
    let c = SolverConfig {
        max_distance_from_anchors_m: 10.0,
        max_condition_number: 1e3,
        ..cfg()
    };
    match solve_2d(&star(&anchors, p), 0.0, Some(p), &c) {
        Err(SolveError::DegenerateGeometry {
            check: GeometryCheck::Jacobian,
            condition,
            max,
        }) => {
            assert!(condition > max);
        }
        other => panic!("expected an ill-conditioned J^T J, got {other:?}"),
    }
}

#[test]
fn too_few_anchors_or_pairs_are_refused() {
    let p = [0.5, 0.5, 1.0];
    let a = CONST3;
    // 3D: three anchors.
    let three = [obs(a[0], a[1], p), obs(a[1], a[2], p), obs(a[0], a[2], p)];
    assert_eq!(
        solve_3d(&three, None, &cfg()),
        Err(SolveError::TooFewAnchors {
            count: 3,
            required: 4
        })
    );
    // 3D: four anchors but two disjoint pairs hold two independent differences.
    let disjoint = [obs(a[0], a[1], p), obs(a[2], a[3], p), obs(a[1], a[0], p)];
    assert_eq!(
        solve_3d(&disjoint, None, &cfg()),
        Err(SolveError::TooFewPairs {
            count: 2,
            required: 3
        })
    );
    // 2D: one pair.
    let sq = paper_square(0.0);
    assert_eq!(
        solve_2d(&[obs(sq[0], sq[1], p)], 1.0, None, &cfg()),
        Err(SolveError::TooFewAnchors {
            count: 2,
            required: 3
        })
    );
    // 2D: four anchors, two disjoint pairs: 2 independent differences suffice.
    let fix = solve_2d(
        &[obs(sq[0], sq[1], p), obs(sq[2], sq[3], p)],
        1.0,
        Some([0.0, 0.0, 1.0]),
        &cfg(),
    )
    .unwrap();
    assert!(err(fix.pos_m, p) < 1e-6, "{:?}", fix.pos_m);
    assert_eq!(fix.seed, Seed::Init);
    // Empty input.
    assert_eq!(
        solve_2d(&[], 0.0, None, &cfg()),
        Err(SolveError::TooFewAnchors {
            count: 0,
            required: 3
        })
    );
}

#[test]
fn runaway_start_is_retried_from_the_closed_form() {
    let p = [0.5, -1.0, 1.4];
    let o = star(&CONST3, p);
    let fix = solve_3d(&o, Some([80.0, 0.0, 0.0]), &cfg()).unwrap();
    assert_eq!(fix.seed, Seed::ClosedForm);
    assert!(err(fix.pos_m, p) < 1e-9);

    // A tag far outside the box is reported as a runaway, whatever the seed.
    let far = [40.0, 0.0, 1.0];
    match solve_3d(&star(&CONST3, far), Some(far), &cfg()) {
        Err(SolveError::Runaway { distance_m, max_m }) => {
            assert!(distance_m > max_m && max_m == 2.0, "{distance_m}");
        }
        other => panic!("expected runaway, got {other:?}"),
    }
    let c = SolverConfig {
        max_distance_from_anchors_m: 50.0,
        ..cfg()
    };
    let fix = solve_3d(&star(&CONST3, far), Some([30.0, 1.0, 1.0]), &c).unwrap();
    assert!(err(fix.pos_m, far) < 1e-6, "{:?}", fix.pos_m);
}

#[test]
fn noisy_solves_from_a_poor_start_converge() {
    // Gross pair errors (NLOS-like) and a start on the far side of the room.
    let mut g = Gauss::new(7);
    let mut ok = 0;
    for k in 0..200 {
        let p = [-2.0 + 0.02 * k as f64, 1.0, 1.5];
        let o: Vec<TdoaObs> = ring(&CONST3, p)
            .into_iter()
            .map(|o| TdoaObs {
                diff_m: o.diff_m + 0.15 * g.normal(),
                ..o
            })
            .collect();
        let fix = solve_3d(&o, Some([3.5, -3.5, 0.5]), &cfg()).unwrap();
        assert!(fix.pos_m.iter().all(|v| v.is_finite()));
        if err(fix.pos_m, p) < 1.0 {
            ok += 1;
        }
    }
    assert_eq!(ok, 200);
}

#[test]
fn invalid_input_is_named() {
    let p = [0.5, 0.5, 1.0];
    let mut o = star(&CONST3, p);
    o[2].diff_m = f64::NAN;
    assert!(matches!(
        solve_3d(&o, None, &cfg()),
        Err(SolveError::NonFiniteObs {
            index: 2,
            field: "diff_m",
            ..
        })
    ));
    let mut o = star(&CONST3, p);
    o[1].b_m[2] = f64::INFINITY;
    assert!(matches!(
        solve_3d(&o, None, &cfg()),
        Err(SolveError::NonFiniteObs {
            index: 1,
            field: "b_m",
            ..
        })
    ));
    let mut o = star(&CONST3, p);
    o[3].b_m = o[3].a_m;
    assert!(matches!(
        solve_3d(&o, None, &cfg()),
        Err(SolveError::SameAnchor { index: 3, .. })
    ));
    let o = star(&CONST3, p);
    assert!(matches!(
        solve_3d(&o, Some([f64::NAN, 0.0, 0.0]), &cfg()),
        Err(SolveError::NonFiniteArg { name: "init", .. })
    ));
    assert!(matches!(
        solve_2d(&o, f64::NAN, None, &cfg()),
        Err(SolveError::NonFiniteArg {
            name: "height_m",
            ..
        })
    ));
    assert_eq!(
        solve_3d_weighted(&o, &[0.1; 3], None, &cfg()),
        Err(SolveError::SigmaCount {
            got: 3,
            expected: 7
        })
    );
    let mut s = [0.1; 7];
    s[4] = 0.0;
    assert_eq!(
        solve_3d_weighted(&o, &s, None, &cfg()),
        Err(SolveError::InvalidSigma {
            index: 4,
            value: 0.0
        })
    );
    let bad = SolverConfig {
        tdoa_sigma_m: -1.0,
        ..cfg()
    };
    let e = solve_3d(&o, None, &bad).unwrap_err();
    assert_eq!(
        e.to_string(),
        "invalid solver configuration: solver.tdoa_sigma_m must be finite and > 0, got -1"
    );
}
