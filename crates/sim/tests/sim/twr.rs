//! UWB two-way ranging (`[sim.uwb] kind = "twr"`): the ranges are the true
//! distances plus the anchor biases and the configured noise, NLOS only
//! lengthens them, every epoch holds one range per anchor with the last
//! flagged, a seed gives the same bits, the TDOA output of the existing
//! scenarios is unchanged, and `twr-3.4` is `paper-3.4` with ranges.

// Axis loops index arrays.
#![allow(clippy::needless_range_loop)]

use insuwb_msg::{GroundTruth, UwbRange, LAYOUT_VERSION};
use insuwb_sim::{
    builtin, builtin_names, simulate, Dropout, RandomNlos, Scenario, SimOutput, SimRecord,
    UwbConfig, UwbKind,
};

/// The TWR variant of the paper's section 3.4 scenario.
fn twr() -> Scenario {
    Scenario::builtin("twr-3.4").unwrap()
}

/// `|p - a|`.
fn dist(p: [f64; 3], a: [f64; 3]) -> f64 {
    let d = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// The true position at `t_ns` (the truth is sampled at the IMU times; the
/// scenarios here have their UWB epochs on IMU samples).
fn truth_at(truth: &[GroundTruth], t_ns: u64) -> [f64; 3] {
    let i = truth
        .binary_search_by_key(&t_ns, |g| g.header.meas_time_ns)
        .unwrap();
    truth[i].pos_m
}

/// Each range minus the true distance to its anchor, per anchor index.
fn residuals(sc: &Scenario, out: &SimOutput) -> Vec<Vec<f64>> {
    let mut r = vec![Vec::new(); sc.uwb.anchors.len()];
    for m in &out.range {
        let j = sc
            .uwb
            .anchors
            .iter()
            .position(|a| a.id == m.anchor)
            .unwrap();
        let p = truth_at(&out.truth, m.header.meas_time_ns);
        r[j].push(m.range_m - dist(p, sc.uwb.anchors[j].pos_m));
    }
    r
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

/// FNV-1a over 64-bit words.
fn fnv(h: &mut u64, x: u64) {
    for b in x.to_le_bytes() {
        *h ^= u64::from(b);
        *h = h.wrapping_mul(0x0100_0000_01b3);
    }
}

/// Hashes of a run's TDOA stream (with its decomposition) and of its IMU
/// samples, bit for bit.
fn fingerprint(out: &SimOutput) -> (usize, u64, u64) {
    let mut h = 0xcbf2_9ce4_8422_2325;
    for m in &out.tdoa {
        fnv(&mut h, m.header.seq);
        fnv(&mut h, m.header.meas_time_ns);
        fnv(&mut h, u64::from(m.header.flags));
        fnv(&mut h, u64::from(m.anchor_a));
        fnv(&mut h, u64::from(m.anchor_b));
        fnv(&mut h, m.diff_m.to_bits());
    }
    for t in &out.tdoa_truth {
        for v in [t.geometric_m, t.anchor_bias_m, t.nlos_m, t.noise_m] {
            fnv(&mut h, v.to_bits());
        }
    }
    let mut hi = 0xcbf2_9ce4_8422_2325;
    for s in &out.imu {
        for v in s.accel_mps2.iter().chain(&s.gyro_rps) {
            fnv(&mut hi, v.to_bits());
        }
    }
    (out.tdoa.len(), h, hi)
}

#[test]
fn twr_ranges_equal_the_true_distances_within_the_noise() {
    let mut sc = twr();
    sc.uwb.outliers.clear();
    let biases = [0.0, 0.1, -0.05, 0.2];
    for (a, b) in sc.uwb.anchors.iter_mut().zip(biases) {
        a.range_bias_m = b;
    }
    for (sigma, seed) in [(0.05, 3), (0.1, 4)] {
        sc.uwb.range_sigma_m = sigma;
        let out = simulate(&sc, seed).unwrap();
        assert!(out.tdoa.is_empty() && out.tdoa_truth.is_empty());
        assert_eq!(out.range.len(), 1500 * 4);
        assert_eq!(out.range_truth.len(), out.range.len());
        for (j, r) in residuals(&sc, &out).iter().enumerate() {
            assert_eq!(r.len(), 1500);
            let (m, sd) = mean_sd(r);
            // Standard errors: sigma / sqrt(1500) = 0.026 sigma for the
            // mean, sigma / sqrt(3000) = 0.018 sigma for the SD.
            assert!((m - biases[j]).abs() < 0.12 * sigma, "{j}: mean {m}");
            assert!((sd / sigma - 1.0).abs() < 0.08, "{j}: sd {sd}");
        }
        // The decomposition adds up, and its parts are what they say.
        for (m, t) in out.range.iter().zip(&out.range_truth) {
            let j = m.anchor as usize;
            assert_eq!(
                m.range_m,
                t.geometric_m + t.anchor_bias_m + t.nlos_m + t.noise_m
            );
            assert_eq!(t.anchor_bias_m, biases[j]);
            assert_eq!(t.nlos_m, 0.0);
            let p = truth_at(&out.truth, m.header.meas_time_ns);
            assert!((t.geometric_m - dist(p, sc.uwb.anchors[j].pos_m)).abs() < 1e-12);
        }
    }
    // Without noise a range is the distance plus the bias.
    sc.uwb.range_sigma_m = 0.0;
    let out = simulate(&sc, 3).unwrap();
    for (j, r) in residuals(&sc, &out).iter().enumerate() {
        for x in r {
            assert!((x - biases[j]).abs() < 1e-12, "{j}: {x}");
        }
    }
}

#[test]
fn nlos_bursts_only_lengthen_ranges() {
    let mut sc = twr();
    // (first epoch, anchors blocked, bias range) of the file's 10-epoch
    // bursts; the epochs are 10 ms apart.
    let windows: [(u64, &[u32], [f64; 2]); 4] = [
        (900, &[0], [0.8, 1.7]),
        (1100, &[2], [0.6, 1.4]),
        (1300, &[0], [0.8, 1.7]),
        (1300, &[3], [0.5, 1.2]),
    ];
    let blocked = |k: u64, id: u32| {
        windows
            .iter()
            .find(|(s, ids, _)| (*s..*s + 10).contains(&k) && ids.contains(&id))
            .map(|w| w.2)
    };
    let epoch = |m: &UwbRange| m.header.meas_time_ns / 10_000_000;
    let mut hits = 0;
    for seed in 1..=5 {
        let out = simulate(&sc, seed).unwrap();
        for (m, t) in out.range.iter().zip(&out.range_truth) {
            let k = epoch(m);
            assert!(t.nlos_m >= 0.0, "{k}: {}", t.nlos_m);
            match blocked(k, m.anchor) {
                Some([lo, hi]) if t.nlos_m != 0.0 => {
                    assert!((lo..hi).contains(&t.nlos_m), "{k}: {}", t.nlos_m);
                    hits += 1;
                }
                Some(_) => {}
                None => assert_eq!(t.nlos_m, 0.0, "{k} anchor {}", m.anchor),
            }
            assert_eq!(
                m.range_m,
                t.geometric_m + t.anchor_bias_m + t.nlos_m + t.noise_m
            );
        }
        // The excess of each anchor is the one paper-3.4's differences
        // carry with the same seed: there `excess_b - excess_a`.
        let tdoa = simulate(&Scenario::builtin("paper-3.4").unwrap(), seed).unwrap();
        for (e, d) in out.range_truth.chunks(4).zip(tdoa.tdoa_truth.chunks(3)) {
            for b in 1..4 {
                assert_eq!(d[b - 1].nlos_m, e[b].nlos_m - e[0].nlos_m);
            }
        }
    }
    // 5 seeds x 40 blocked (epoch, anchor) slots, each hit with
    // probability 0.5: 100 +- 7 expected.
    assert!((70..=130).contains(&hits), "{hits}");

    // Without noise the ranges themselves show it: never shorter than the
    // distance plus the bias, longer only in the bursts.
    sc.uwb.range_sigma_m = 0.0;
    let out = simulate(&sc, 2).unwrap();
    let res = residuals(&sc, &out);
    let mut longer = 0;
    for (j, r) in res.iter().enumerate() {
        let id = sc.uwb.anchors[j].id;
        // No dropouts: residual k is epoch k's.
        for (k, x) in (0u64..).zip(r) {
            assert!(*x > -1e-12, "{k} anchor {id}: {x}");
            if *x > 1e-9 {
                assert!(blocked(k, id).is_some(), "{k} anchor {id}: {x}");
                longer += 1;
            }
        }
    }
    assert!(longer > 0);

    // Random NLOS lengthens too: nlos-long's events on ranges.
    let mut long = Scenario::builtin("nlos-long").unwrap();
    long.uwb.kind = UwbKind::Twr;
    let r = long.uwb.random_nlos.clone().unwrap();
    let mut any = false;
    for seed in [2, 3] {
        let out = simulate(&long, seed).unwrap();
        for t in &out.range_truth {
            assert!(t.nlos_m >= 0.0);
            // A sum of events, each in [0.3, 1.0].
            assert!(t.nlos_m == 0.0 || t.nlos_m >= r.bias_m[0], "{}", t.nlos_m);
            assert!(t.nlos_m <= 4.0 * r.bias_m[1]);
            any |= t.nlos_m != 0.0;
        }
    }
    assert!(any);
    // All anchors blocked at once, all the time, by a constant excess.
    long.uwb.random_nlos = Some(RandomNlos {
        rate_per_s: 100.0,
        mean_duration_s: 1000.0,
        bias_m: [0.4, 0.4],
        start_s: 0.0,
        ..RandomNlos::default()
    });
    long.duration_s = 5.0;
    let out = simulate(&long, 1).unwrap();
    for t in out.range_truth.iter().skip(4) {
        assert!(t.nlos_m >= 0.4, "{}", t.nlos_m);
    }
}

#[test]
fn every_epoch_has_one_range_per_anchor_with_the_last_flagged() {
    let mut sc = twr();
    sc.uwb.dropouts.push(Dropout {
        start_s: 5.0,
        duration_s: 0.5,
    });
    let out = simulate(&sc, 1).unwrap();
    let na = sc.uwb.anchors.len();
    assert_eq!(na, 4);
    // 1500 epochs minus the 50 dropped.
    assert_eq!(out.range.len(), (1500 - 50) * na);
    for (k, m) in out.range.iter().enumerate() {
        assert_eq!(m.header.seq, k as u64);
        assert_eq!(m.header.layout_version, LAYOUT_VERSION);
        assert_eq!(m.header.source_id, 0);
        assert_eq!(m.header.pub_time_ns, 0);
        assert_eq!(m.quality, 0);
        assert_eq!(m.header.flags & UwbRange::FLAG_QUALITY, 0);
        let a = &sc.uwb.anchors[k % na];
        assert_eq!(m.anchor, a.id);
        assert_eq!(m.anchor_pos_m, a.pos_m);
        let t = m.header.meas_time_ns;
        assert_eq!(t % 10_000_000, 0);
        assert!(
            !(5_000_000_000..5_500_000_000).contains(&t),
            "dropout at {t}"
        );
        let is_last = k % na == na - 1;
        assert_eq!(
            m.header.flags,
            if is_last { UwbRange::FLAG_EPOCH_END } else { 0 },
            "{k}"
        );
        if !is_last {
            assert_eq!(out.range[k + 1].header.meas_time_ns, t);
        } else if let Some(n) = out.range.get(k + 1) {
            assert!(n.header.meas_time_ns > t);
        }
    }

    // The merged stream: truth, IMU, then the epoch's ranges.
    let m = out.merged();
    assert_eq!(m.len(), out.imu.len() + out.truth.len() + out.range.len());
    assert!(matches!(m[0], SimRecord::Truth(_)));
    assert!(matches!(m[1], SimRecord::Imu(_)));
    assert!(matches!(m[2], SimRecord::Range(r) if r.anchor == 0));
    assert!(matches!(m[5], SimRecord::Range(r) if r.header.flags & UwbRange::FLAG_EPOCH_END != 0));
    assert!(matches!(m[6], SimRecord::Truth(t) if t.header.seq == 1));
    for w in m.windows(2) {
        assert!(w[0].time_ns() <= w[1].time_ns());
    }
    assert!(!m.iter().any(|r| matches!(r, SimRecord::Tdoa(_))));
    let ranges: Vec<UwbRange> = m
        .iter()
        .filter_map(|r| match r {
            SimRecord::Range(s) => Some(*s),
            _ => None,
        })
        .collect();
    assert_eq!(ranges, out.range);
    assert_eq!(m[2].time_ns(), 0);
}

#[test]
fn the_same_seed_gives_identical_ranges() {
    let sc = twr();
    let a = simulate(&sc, 7).unwrap();
    let b = simulate(&sc, 7).unwrap();
    assert_eq!(a, b);
    let bits = |o: &SimOutput| -> Vec<u64> {
        o.range
            .iter()
            .map(|m| m.range_m.to_bits())
            .chain(o.range_truth.iter().map(|t| t.noise_m.to_bits()))
            .collect()
    };
    assert_eq!(bits(&a), bits(&b));
    let c = simulate(&sc, 8).unwrap();
    assert_ne!(a.range, c.range);
    assert_eq!(a.truth, c.truth);
    // The UWB kind leaves the other streams alone: the IMU of paper-3.4
    // with the same seed.
    let paper = simulate(&Scenario::builtin("paper-3.4").unwrap(), 7).unwrap();
    assert_eq!(a.imu, paper.imu);
    assert_eq!(a.truth, paper.truth);
    assert_eq!(a.imu_errors, paper.imu_errors);
}

#[test]
fn tdoa_output_is_unchanged_by_twr() {
    // Hashes of the TDOA and IMU streams taken before the simulator could
    // range, with `fingerprint` as it is here.
    let pinned = [
        (
            "paper-3.4",
            1,
            4500,
            0xd213_b07b_eeac_87fd,
            0xaac3_9ee8_0dc9_2fa3,
        ),
        (
            "paper-3.4",
            7,
            4500,
            0x6f76_ff33_7365_fa67,
            0x1900_d1ab_4c20_8578,
        ),
        (
            "nlos-long",
            1,
            1740,
            0x028c_5210_c6f9_6988,
            0x610b_faf7_fe12_ca76,
        ),
        (
            "nlos-long",
            7,
            1740,
            0x6fcd_1762_27d1_4a52,
            0x6e18_8200_e7cd_146b,
        ),
    ];
    for (name, seed, n, h, hi) in pinned {
        let out = simulate(&Scenario::builtin(name).unwrap(), seed).unwrap();
        assert_eq!(fingerprint(&out), (n, h, hi), "{name} seed {seed}");
        assert!(out.range.is_empty() && out.range_truth.is_empty());
    }
    // `kind` absent and `kind = "tdoa"` are the same scenario and output.
    let text = builtin("paper-3.4").unwrap();
    assert!(!text.contains("kind = \"tdoa\""));
    let explicit = text.replacen("[sim.uwb]\n", "[sim.uwb]\nkind = \"tdoa\"\n", 1);
    assert_ne!(explicit, text);
    let a = Scenario::builtin("paper-3.4").unwrap();
    let b = Scenario::from_toml_str(&explicit, "explicit.toml").unwrap();
    assert_eq!(a.uwb.kind, UwbKind::Tdoa);
    assert_eq!(a, b);
    assert_eq!(simulate(&a, 3).unwrap(), simulate(&b, 3).unwrap());
}

#[test]
fn the_twr_keys_have_defaults_and_are_checked() {
    let d = UwbConfig::default();
    assert_eq!(d.kind, UwbKind::Tdoa);
    assert_eq!(d.range_sigma_m, 0.05);
    let base = "[sim]\nname = \"t\"\n[sim.uwb]\n";
    let err = |extra: &str| {
        Scenario::from_toml_str(&format!("{base}{extra}\n"), "bad.toml")
            .unwrap_err()
            .to_string()
    };
    let e = err("kind = \"rssi\"");
    assert!(e.starts_with("bad.toml: at `sim.uwb.kind`"), "{e}");
    assert!(e.contains("tdoa") && e.contains("twr"), "{e}");
    assert_eq!(
        err("kind = \"twr\"\nrange_sigma_m = -0.1"),
        "bad.toml: sim.uwb.range_sigma_m must be >= 0, got -0.1"
    );
    assert_eq!(
        err("range_sigma_m = nan"),
        "bad.toml: sim.uwb.range_sigma_m must be finite, got NaN"
    );
    let sc = Scenario::from_toml_str(&format!("{base}kind = \"twr\"\n"), "ok.toml").unwrap();
    assert_eq!(sc.uwb.kind, UwbKind::Twr);
    assert_eq!(sc.uwb.range_sigma_m, 0.05);
    // The default scenario's 15 s at 10 Hz, 4 anchors.
    let out = simulate(&sc, 1).unwrap();
    assert_eq!(out.range.len(), 150 * 4);
}

#[test]
fn twr_3_4_is_paper_3_4_with_ranges() {
    assert!(builtin_names().contains(&"twr-3.4"));
    let text = builtin("twr-3.4").unwrap();
    let paper_text = builtin("paper-3.4").unwrap();
    let twr = twr();
    let paper = Scenario::builtin("paper-3.4").unwrap();
    assert_eq!(twr.name, "twr-3.4");
    assert!(twr.description.contains("two-way ranges"));
    assert_eq!(twr.uwb.kind, UwbKind::Twr);
    assert_eq!(twr.uwb.range_sigma_m, 0.05);
    // Everything else of [sim] is paper-3.4's (the TDOA-only keys aside).
    let mut same = twr.clone();
    same.name = paper.name.clone();
    same.description = paper.description.clone();
    same.uwb.kind = paper.uwb.kind;
    same.uwb.range_sigma_m = paper.uwb.range_sigma_m;
    same.uwb.tdoa_sigma_m = paper.uwb.tdoa_sigma_m;
    same.uwb.noise_model = paper.uwb.noise_model;
    same.uwb.pairs = paper.uwb.pairs;
    assert_eq!(same, paper);
    assert_eq!(twr.uwb.outliers.len(), 4);
    // Every other table (the fusion settings) is identical, but for the
    // range noise the fix and the tight filter are told.
    let mut t: toml::Table = toml::from_str(text).unwrap();
    let fusion = t.get_mut("fusion").and_then(|f| f.as_table_mut()).unwrap();
    let eskf = fusion.remove("eskf").unwrap();
    assert_eq!(eskf["range_sigma_m"].as_float(), Some(0.05));
    let solver = fusion["fix"]["solver"].as_table().unwrap().clone();
    let mut solver = solver;
    assert_eq!(
        solver.remove("range_sigma_m").and_then(|v| v.as_float()),
        Some(0.05)
    );
    fusion
        .get_mut("fix")
        .and_then(|f| f.as_table_mut())
        .unwrap()
        .insert("solver".into(), toml::Value::Table(solver));
    let p: toml::Table = toml::from_str(paper_text).unwrap();
    let others = |t: &toml::Table| {
        t.iter()
            .filter(|(k, _)| k.as_str() != "sim")
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect::<Vec<_>>()
    };
    assert!(!others(&p).is_empty());
    assert_eq!(others(&t), others(&p));
}
