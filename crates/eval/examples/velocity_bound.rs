//! How good a velocity sensor would have to be: the tight filter on UTIL
//! flights with the flow deck's velocities replaced by the motion
//! capture's, a diagnostic from truth (not an estimator).
//!
//! `cargo run --release -p insuwb-eval --example velocity_bound -- MANIFEST
//! CONFIG.toml SIGMA[,SIGMA...] [FLIGHT...]`
//!
//! For every flight of the manifest that carries flow (or those named),
//! over its flight segment (truth above the config's `[eval]
//! min_height_m`, else 0.3 m), at the truth's sample times as `insuwb eval`
//! measures: the horizontal RMSE of `iakf_tdoa` with the flow deck's own
//! velocities and heights (`flow`, as `insuwb eval --aiding flow`), then,
//! for each SIGMA (m/s), with each flow velocity replaced by the truth's
//! body velocity at its time plus seeded normal noise of SIGMA per axis,
//! stated as `max(SIGMA, 0.01)` (the config's `sigma_factor` still
//! applies); the heights stay the range finder's. Each as a ratio to the
//! manifest's `uwb_ls_ref_m`, then the median / worst / flights above 1.0.
//! The truth's body velocity: the central difference of its positions over
//! 40 ms, rotated into the motion capture's body frame.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;

use insuwb_data::segment::{flight_segment, interpolate_truth, DEFAULT_MIN_HEIGHT_M};
use insuwb_data::util::{load_util_flight, ImportOptions};
use insuwb_data::FlowDeck;
use insuwb_eval::batch::Manifest;
use insuwb_eval::run::{evaluate_at, Dataset, Epochs};
use insuwb_fusion::config::FusionConfig;
use insuwb_msg::{BodyVelocity, FilterKind, GroundTruth};
use insuwb_sim::rng::{stream, Noise};
use nalgebra::{UnitQuaternion, Vector3};

#[derive(Debug, serde::Deserialize)]
struct Preset {
    #[serde(default)]
    fusion: FusionConfig,
    #[serde(default)]
    import: ImportOptions,
    #[serde(default)]
    flow: FlowDeck,
    #[serde(default)]
    eval: Option<toml::Value>,
}

const HALF_BASE_NS: u64 = 20_000_000;

/// The truth's body-frame velocity at `t`.
fn truth_body_velocity(truth: &[GroundTruth], t: u64) -> Option<[f64; 3]> {
    let a = interpolate_truth(truth, t.checked_sub(HALF_BASE_NS)?)?;
    let b = interpolate_truth(truth, t + HALF_BASE_NS)?;
    let g = interpolate_truth(truth, t)?;
    let dt = 2.0 * HALF_BASE_NS as f64 * 1e-9;
    let v = Vector3::from_iterator((0..3).map(|i| (b.pos_m[i] - a.pos_m[i]) / dt));
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        g.quat[0], g.quat[1], g.quat[2], g.quat[3],
    ));
    let vb = q.inverse() * v;
    Some([vb.x, vb.y, vb.z])
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let manifest = Manifest::load(Path::new(&a[1])).unwrap();
    let preset: Preset = toml::from_str(&std::fs::read_to_string(&a[2]).unwrap()).unwrap();
    let sigmas: Vec<f64> = a[3].split(',').map(|s| s.parse().unwrap()).collect();
    let want: Vec<&String> = a[4..].iter().collect();
    let min_h = preset
        .eval
        .as_ref()
        .and_then(|e| e.get("min_height_m"))
        .and_then(toml::Value::as_float)
        .filter(|h| *h > 0.0)
        .unwrap_or(DEFAULT_MIN_HEIGHT_M);
    let ref_col = manifest
        .references
        .iter()
        .position(|r| r == "uwb_ls_ref_m")
        .expect("a uwb_ls_ref_m column");
    print!("{:18} {:>7}", "flight", "flow");
    for s in &sigmas {
        print!(" {:>7}", format!("v{s}"));
    }
    println!("   (iakf_tdoa / uwb_ls_ref_m)");
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); sigmas.len() + 1];
    for (fi, f) in manifest.flights.iter().enumerate() {
        if !want.is_empty() && !want.iter().any(|w| f.name.ends_with(w.as_str())) {
            continue;
        }
        let flight = load_util_flight(
            &f.file,
            f.anchors.as_ref().expect("an anchors column"),
            &insuwb_data::cflog::ParseOptions::default(),
            &preset.import,
        )
        .unwrap();
        if flight.flow.is_empty() {
            continue;
        }
        let (velocity, _) =
            insuwb_data::flow_velocities(&flight.flow, &flight.ranges, &flight.imu, &preset.flow);
        let (height, _) = insuwb_data::range_heights(&flight.ranges, &preset.flow);
        let reference = f.references[ref_col].expect("a reference");
        let mut data = Dataset {
            name: f.name.clone(),
            imu: flight.imu,
            tdoa: flight.tdoa,
            range: Vec::new(),
            truth: flight.truth,
            velocity: velocity.clone(),
            height,
            segment: None,
        };
        data.segment = flight_segment(&data.truth, min_h);
        let run = |data: &Dataset| {
            let rep =
                evaluate_at(data, &preset.fusion, &[FilterKind::IakfTdoa], Epochs::Truth).unwrap();
            let s = rep.solutions.iter().find(|s| s.key == "iakf_tdoa").unwrap();
            s.metrics.rmse_horizontal / reference
        };
        let mut row = vec![run(&data)];
        for (k, &sigma) in sigmas.iter().enumerate() {
            let mut rng = stream(17 + fi as u64, k as u64);
            data.velocity = velocity
                .iter()
                .filter_map(|v| {
                    let tv = truth_body_velocity(&data.truth, v.header.meas_time_ns)?;
                    let mut out = *v;
                    let s = sigma.max(0.01);
                    out.vel_mps = [tv[0] + rng.normal(sigma), tv[1] + rng.normal(sigma), 0.0];
                    out.sigma_mps = [s, s, 0.0];
                    Some(out)
                })
                .collect::<Vec<BodyVelocity>>();
            row.push(run(&data));
        }
        print!("{:18} ", f.name);
        for (c, r) in cols.iter_mut().zip(&row) {
            print!(" {r:7.3}");
            c.push(*r);
        }
        println!();
    }
    print!("{:18} ", "median/worst/>1");
    for c in &mut cols {
        c.sort_by(f64::total_cmp);
        if c.is_empty() {
            continue;
        }
        print!(
            " {:.3}/{:.3}/{}",
            (c[(c.len() - 1) / 2] + c[c.len() / 2]) / 2.0,
            c[c.len() - 1],
            c.iter().filter(|&&r| r > 1.0).count()
        );
    }
    println!();
}
