//! Calibration of the built-in scenarios against the paper's UWB-only figures.
//!
//! A plain Gauss-Newton 2-D TDOA solver (here, in the test only; the real
//! solver is `insuwb-uwb`) turns each epoch into a fix; the per-axis RMSE
//! and error ranges over 20 seeds are printed and must stay in bands around
//! the paper's values (Table 1 for section 3.4, section 4.3 and 4.4 text).
//!
//! Run: `cargo test -p insuwb-sim --release --test sim -- calibration:: --nocapture`

// Test helpers outside #[test] functions unwrap too; axis loops index arrays.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::needless_range_loop
)]

use insuwb_msg::UwbTdoa;
use insuwb_sim::{simulate, Scenario};

/// Unweighted Gauss-Newton fix from one epoch's differences, height known.
fn solve_2d(epoch: &[UwbTdoa], z: f64, start: [f64; 2]) -> [f64; 2] {
    let mut p = start;
    for _ in 0..20 {
        // Normal equations J^T J dp = J^T r.
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for m in epoch {
            let da = [
                p[0] - m.anchor_a_pos_m[0],
                p[1] - m.anchor_a_pos_m[1],
                z - m.anchor_a_pos_m[2],
            ];
            let db = [
                p[0] - m.anchor_b_pos_m[0],
                p[1] - m.anchor_b_pos_m[1],
                z - m.anchor_b_pos_m[2],
            ];
            let ra = (da[0] * da[0] + da[1] * da[1] + da[2] * da[2]).sqrt();
            let rb = (db[0] * db[0] + db[1] * db[1] + db[2] * db[2]).sqrt();
            let j = [db[0] / rb - da[0] / ra, db[1] / rb - da[1] / ra];
            let r = m.diff_m - (rb - ra);
            a11 += j[0] * j[0];
            a12 += j[0] * j[1];
            a22 += j[1] * j[1];
            b1 += j[0] * r;
            b2 += j[1] * r;
        }
        let det = a11 * a22 - a12 * a12;
        let dx = (a22 * b1 - a12 * b2) / det;
        let dy = (a11 * b2 - a12 * b1) / det;
        p = [p[0] + dx, p[1] + dy];
        if dx.abs() + dy.abs() < 1e-10 {
            break;
        }
    }
    p
}

#[derive(Debug, Default)]
struct Stats {
    n: usize,
    sum_sq: [f64; 2],
    min: [f64; 2],
    max: [f64; 2],
    /// Per-seed minima and maxima, averaged.
    mean_min: [f64; 2],
    mean_max: [f64; 2],
    mean_err: [f64; 2],
}

impl Stats {
    fn rmse(&self) -> [f64; 2] {
        [
            (self.sum_sq[0] / self.n as f64).sqrt(),
            (self.sum_sq[1] / self.n as f64).sqrt(),
        ]
    }
}

/// UWB-only errors (fix minus truth, east and north) over `seeds`.
fn uwb_only(name: &str, seeds: std::ops::Range<u64>) -> Stats {
    uwb_only_sc(&Scenario::builtin(name).unwrap(), seeds)
}

fn uwb_only_sc(sc: &Scenario, seeds: std::ops::Range<u64>) -> Stats {
    let name = &sc.name;
    let mut st = Stats {
        min: [f64::INFINITY; 2],
        max: [f64::NEG_INFINITY; 2],
        ..Stats::default()
    };
    let nseeds = seeds.end - seeds.start;
    for seed in seeds {
        let out = simulate(sc, seed).unwrap();
        let (mut smin, mut smax) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        // Start the first solve at the anchors' centroid.
        let na = sc.uwb.anchors.len() as f64;
        let mut prev = [
            sc.uwb.anchors.iter().map(|a| a.pos_m[0]).sum::<f64>() / na,
            sc.uwb.anchors.iter().map(|a| a.pos_m[1]).sum::<f64>() / na,
        ];
        let mut ti = 0;
        for epoch in out
            .tdoa
            .split_inclusive(|m| m.header.flags & UwbTdoa::FLAG_EPOCH_END != 0)
        {
            let t = epoch[0].header.meas_time_ns;
            while out.truth[ti].header.meas_time_ns < t {
                ti += 1;
            }
            let truth = &out.truth[ti];
            assert_eq!(
                truth.header.meas_time_ns, t,
                "UWB epochs fall on IMU/truth times"
            );
            let fix = solve_2d(epoch, sc.height_m, prev);
            prev = fix;
            for k in 0..2 {
                let e = fix[k] - truth.pos_m[k];
                st.sum_sq[k] += e * e;
                st.mean_err[k] += e;
                smin[k] = smin[k].min(e);
                smax[k] = smax[k].max(e);
            }
            st.n += 1;
        }
        for k in 0..2 {
            st.min[k] = st.min[k].min(smin[k]);
            st.max[k] = st.max[k].max(smax[k]);
            st.mean_min[k] += smin[k] / nseeds as f64;
            st.mean_max[k] += smax[k] / nseeds as f64;
        }
    }
    for k in 0..2 {
        st.mean_err[k] /= st.n as f64;
    }
    let r = st.rmse();
    println!(
        "{name}: {} fixes; RMSE E {:.4} N {:.4} (mean {:.4}); mean error E {:+.4} N {:+.4}; \
         per-seed range (mean) E {:+.3}..{:+.3} N {:+.3}..{:+.3}; overall E {:+.3}..{:+.3} N {:+.3}..{:+.3}",
        st.n,
        r[0],
        r[1],
        0.5 * (r[0] + r[1]),
        st.mean_err[0],
        st.mean_err[1],
        st.mean_min[0],
        st.mean_max[0],
        st.mean_min[1],
        st.mean_max[1],
        st.min[0],
        st.max[0],
        st.min[1],
        st.max[1],
    );
    st
}

#[test]
fn paper_3_4_uwb_only_matches_table_1() {
    let st = uwb_only("paper-3.4", 1..21);
    let r = st.rmse();
    // Table 1: 0.0650 E, 0.0723 N including the outliers.
    assert!((0.055..0.085).contains(&r[0]), "E RMSE {}", r[0]);
    assert!((0.060..0.090).contains(&r[1]), "N RMSE {}", r[1]);
}

#[test]
fn paper_4_3_static_uwb_only_matches_the_text() {
    let st = uwb_only("paper-4.3-static", 1..21);
    let r = st.rmse();
    // Section 4.3: 0.0125 E, 0.0389 N.
    assert!((0.009..0.017).contains(&r[0]), "E RMSE {}", r[0]);
    assert!((0.030..0.048).contains(&r[1]), "N RMSE {}", r[1]);
}

#[test]
fn paper_4_4_dynamic_uwb_only_matches_the_text() {
    let st = uwb_only("paper-4.4-dynamic", 1..21);
    let r = st.rmse();
    // Section 4.4: RMSE 0.1022 m.
    let mean = 0.5 * (r[0] + r[1]);
    assert!((0.08..0.125).contains(&mean), "mean RMSE {mean}");
}

#[test]
fn nlos_long_uwb_only_summary() {
    let st = uwb_only("nlos-long", 1..21);
    let r = st.rmse();
    assert!(r[0] < 0.5 && r[1] < 0.5, "{r:?}");
}

/// Prints the UWB-only figures of any scenario file, for calibrating new ones:
/// `SIM_CAL_FILE=/abs/path.toml cargo test -p insuwb-sim --release --test sim
/// -- calibration::calibrate_file --ignored --nocapture`
#[test]
#[ignore = "tool: needs SIM_CAL_FILE"]
fn calibrate_file() {
    let path = std::env::var("SIM_CAL_FILE").expect("set SIM_CAL_FILE");
    let sc = Scenario::from_toml_path(std::path::Path::new(&path)).unwrap();
    uwb_only_sc(&sc, 1..21);
}
