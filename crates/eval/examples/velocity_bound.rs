//! How good a velocity sensor would have to be: the tight filter on UTIL
//! flights with the flow deck's velocities replaced by the motion
//! capture's, a diagnostic from truth (not an estimator).
//!
//! `cargo run --release -p insuwb-eval --example velocity_bound -- MANIFEST
//! CONFIG.toml SIGMA[,SIGMA...] [OPTIONS] [FLIGHT...]`
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
//!
//! Options, each a change to every run of a flight:
//!
//! - `--filter-frame`: the truth's velocity rotated into the attitude of
//!   the filter's `flow` run at that time instead (the motion capture's
//!   body frame is not the IMU's);
//! - `--vertical`: the body z axis measured too;
//! - `--no-heights`: without the range finder's heights;
//! - `--synthetic SIGMA`: every TDOA difference replaced by the truth's
//!   (at the antenna, the config's `fusion.tight.lever_arm_m`) plus that
//!   pair's median error over the flight segment plus seeded normal noise
//!   of SIGMA m: the radio's lasting errors without its varying ones;
//! - `--tdoa2-consecutive`: on a flight whose differences are mostly
//!   between anchors next to each other in the cycle of 8 (TDOA2), only
//!   those: the others are formed over a lost packet's slot;
//! - `--yaw`: each run's heading error against the motion capture's over
//!   the segment (RMS, mean, and every 2 s) on standard error.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::BTreeMap;
use std::path::Path;

use insuwb_data::segment::{flight_segment, interpolate_truth, DEFAULT_MIN_HEIGHT_M};
use insuwb_data::util::{load_util_flight, ImportOptions};
use insuwb_data::FlowDeck;
use insuwb_eval::batch::Manifest;
use insuwb_eval::run::{evaluate_at, Dataset, Epochs};
use insuwb_fusion::config::FusionConfig;
use insuwb_msg::{BodyVelocity, FilterKind, FusedState, GroundTruth, UwbTdoa};
use insuwb_sim::rng::{stream, Noise};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

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

#[derive(Debug, Default)]
struct Options {
    filter_frame: bool,
    vertical: bool,
    no_heights: bool,
    synthetic: Option<f64>,
    tdoa2_consecutive: bool,
    yaw: bool,
}

const HALF_BASE_NS: u64 = 20_000_000;

fn unit(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// The truth's ENU velocity at `t`.
fn truth_velocity(truth: &[GroundTruth], t: u64) -> Option<Vector3<f64>> {
    let a = interpolate_truth(truth, t.checked_sub(HALF_BASE_NS)?)?;
    let b = interpolate_truth(truth, t + HALF_BASE_NS)?;
    let dt = 2.0 * HALF_BASE_NS as f64 * 1e-9;
    Some(Vector3::from_iterator(
        (0..3).map(|i| (b.pos_m[i] - a.pos_m[i]) / dt),
    ))
}

/// The attitude of the fused state at or before `t` (`j`: where the last
/// search ended).
fn fused_attitude(fused: &[FusedState], j: &mut usize, t: u64) -> Option<UnitQuaternion<f64>> {
    while *j + 1 < fused.len() && fused[*j + 1].header.meas_time_ns <= t {
        *j += 1;
    }
    fused.get(*j).map(|s| unit(s.quat))
}

/// The differences of `data` replaced by the truth's plus each pair's
/// median error over the segment plus noise `sigma`.
fn synthesise(data: &mut Dataset, lever: Vector3<f64>, sigma: f64, seed: u64) {
    let truth = &data.truth;
    let geometry = |t: &UwbTdoa| {
        let g = interpolate_truth(truth, t.header.meas_time_ns)?;
        let ant = Vector3::from(g.pos_m) + unit(g.quat) * lever;
        let pa = Vector3::from(t.anchor_a_pos_m);
        let pb = Vector3::from(t.anchor_b_pos_m);
        Some((ant - pb).norm() - (ant - pa).norm())
    };
    let mut errors: BTreeMap<(u32, u32), Vec<f64>> = BTreeMap::new();
    for t in &data.tdoa {
        let inside = data
            .segment
            .is_none_or(|(a, b)| (a..=b).contains(&t.header.meas_time_ns));
        if let (true, Some(h)) = (inside, geometry(t)) {
            errors
                .entry((t.anchor_a, t.anchor_b))
                .or_default()
                .push(t.diff_m - h);
        }
    }
    let median: BTreeMap<(u32, u32), f64> = errors
        .into_iter()
        .map(|(k, mut v)| {
            v.sort_by(f64::total_cmp);
            (k, v[v.len() / 2])
        })
        .collect();
    let mut rng = stream(seed, 0);
    let synthetic: Vec<UwbTdoa> = data
        .tdoa
        .iter()
        .filter_map(|t| {
            let bias = median
                .get(&(t.anchor_a, t.anchor_b))
                .copied()
                .unwrap_or(0.0);
            let mut out = *t;
            out.diff_m = geometry(t)? + bias + rng.normal(sigma);
            Some(out)
        })
        .collect();
    data.tdoa = synthetic;
}

/// The heading error of `fused` against the truth over `segment`: RMS and
/// mean (deg), and one sample every 2 s (s, deg).
fn yaw_errors(
    fused: &[FusedState],
    truth: &[GroundTruth],
    segment: Option<(u64, u64)>,
) -> (f64, f64, Vec<(f64, f64)>) {
    let (mut sq, mut sum, mut n) = (0.0, 0.0, 0usize);
    let mut trace = Vec::new();
    let mut next_ns = 0u64;
    for st in fused {
        let t = st.header.meas_time_ns;
        if !segment.is_none_or(|(a, b)| (a..=b).contains(&t)) {
            continue;
        }
        let Some(g) = interpolate_truth(truth, t) else {
            continue;
        };
        let (_, _, yaw) = unit(g.quat).euler_angles();
        let d = (st.yaw_rad - yaw + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        sq += d * d;
        sum += d;
        n += 1;
        if t >= next_ns {
            trace.push((t as f64 * 1e-9, d.to_degrees()));
            next_ns = t + 2_000_000_000;
        }
    }
    let nf = n.max(1) as f64;
    (
        (sq / nf).sqrt().to_degrees(),
        (sum / nf).to_degrees(),
        trace,
    )
}

/// Only the differences between anchors next to each other in a cycle of
/// 8, where most of them are.
fn keep_consecutive(tdoa: &mut Vec<UwbTdoa>) {
    let next = |t: &UwbTdoa| matches!((t.anchor_b + 8 - t.anchor_a % 8) % 8, 1 | 7);
    let n = tdoa.iter().filter(|t| next(t)).count();
    if n * 10 > tdoa.len() * 9 {
        tdoa.retain(next);
    }
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let manifest = Manifest::load(Path::new(&a[1])).unwrap();
    let preset: Preset = toml::from_str(&std::fs::read_to_string(&a[2]).unwrap()).unwrap();
    let sigmas: Vec<f64> = a[3].split(',').map(|s| s.parse().unwrap()).collect();
    let mut opt = Options::default();
    let mut want = Vec::new();
    let mut rest = a[4..].iter();
    while let Some(arg) = rest.next() {
        match arg.as_str() {
            "--filter-frame" => opt.filter_frame = true,
            "--vertical" => opt.vertical = true,
            "--no-heights" => opt.no_heights = true,
            "--synthetic" => opt.synthetic = Some(rest.next().unwrap().parse().unwrap()),
            "--tdoa2-consecutive" => opt.tdoa2_consecutive = true,
            "--yaw" => opt.yaw = true,
            name => want.push(name.to_owned()),
        }
    }
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
            height: if opt.no_heights { Vec::new() } else { height },
            segment: None,
        };
        data.segment = flight_segment(&data.truth, min_h);
        if opt.tdoa2_consecutive {
            keep_consecutive(&mut data.tdoa);
        }
        if let Some(sigma) = opt.synthetic {
            let lever = Vector3::from(preset.fusion.tight.lever_arm_m);
            synthesise(&mut data, lever, sigma, 99 + fi as u64);
        }
        let run = |data: &Dataset| {
            let rep =
                evaluate_at(data, &preset.fusion, &[FilterKind::IakfTdoa], Epochs::Truth).unwrap();
            let s = rep
                .solutions
                .into_iter()
                .find(|s| s.key == "iakf_tdoa")
                .unwrap();
            let fused = s.run.map(|r| r.fused).unwrap_or_default();
            if opt.yaw {
                let (rms, mean, trace) = yaw_errors(&fused, &data.truth, data.segment);
                let trace: Vec<String> = trace
                    .iter()
                    .map(|(t, d)| format!("{t:.0}s {d:+.0}"))
                    .collect();
                eprintln!(
                    "{}: yaw error RMS {rms:.1} deg, mean {mean:+.1}; {}",
                    f.name,
                    trace.join(" ")
                );
            }
            (s.metrics.rmse_horizontal / reference, fused)
        };
        let (first, fused) = run(&data);
        let mut row = vec![first];
        for (k, &sigma) in sigmas.iter().enumerate() {
            let mut rng = stream(17 + fi as u64, k as u64);
            let mut j = 0usize;
            let s = sigma.max(0.01);
            data.velocity = velocity
                .iter()
                .filter_map(|v| {
                    let t = v.header.meas_time_ns;
                    let att = if opt.filter_frame {
                        fused_attitude(&fused, &mut j, t)?
                    } else {
                        unit(interpolate_truth(&data.truth, t)?.quat)
                    };
                    let vb = att.inverse() * truth_velocity(&data.truth, t)?;
                    let mut out = *v;
                    out.vel_mps = [vb.x + rng.normal(sigma), vb.y + rng.normal(sigma), vb.z];
                    out.sigma_mps = [s, s, if opt.vertical { s } else { 0.0 }];
                    Some(out)
                })
                .collect::<Vec<BodyVelocity>>();
            row.push(run(&data).0);
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
