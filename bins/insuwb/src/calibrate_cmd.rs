//! `insuwb calibrate`: a site calibration of the UWB TDOA errors
//! (`insuwb_uwb::calibration`) learnt from every flight of a manifest that
//! has ground truth, and (`--cross-validate`) its leave-one-flight-out
//! figures: each flight evaluated as `insuwb eval --flights` evaluates it,
//! with a calibration learnt on the other flights, for every candidate
//! model family, beside the same flight uncalibrated.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use insuwb_eval::batch::{self, FlightMetrics, Manifest, ManifestFlight};
use insuwb_uwb::calibration::{Family, GridParams, Sample, SiteCalibration};

use crate::dataset::{self, Loaded, NoFlowRecords};
use crate::eval_cmd::{evaluate_ref, print_result};

/// Model family on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelArg {
    /// One constant per anchor pair (its median residual).
    #[value(name = "pair_constant")]
    PairConstant,
    /// A median per anchor pair and x-y cell of `--cell-m`.
    Grid,
}

/// Arguments of `insuwb calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// The flights to learn from: a manifest as `insuwb eval --flights`
    /// reads it; every flight with ground truth (a UTIL log's motion
    /// capture, an insuwb log's `truth` records) is used.
    #[arg(long)]
    pub flights: PathBuf,
    /// Write the calibration into this TOML file.
    #[arg(long, required_unless_present = "cross_validate")]
    pub out: Option<PathBuf>,
    /// Model family.
    #[arg(long, value_enum, default_value_t = ModelArg::Grid)]
    pub model: ModelArg,
    /// Grid cell side, m.
    #[arg(long, default_value_t = GridParams::default().cell_m)]
    pub cell_m: f64,
    /// Fewest samples of a grid cell to use it (fewer: the pair's constant).
    #[arg(long, default_value_t = GridParams::default().min_count)]
    pub min_count: u32,
    /// Shrinkage of a grid cell towards its pair's constant: a cell of n
    /// samples keeps n / (n + this) of its departure.
    #[arg(long, default_value_t = GridParams::default().shrink_count)]
    pub shrink_count: f64,
    /// The share of each grid cell's departure from its pair's constant
    /// that the calibration applies, in [0, 1] (0: the pair's constant, 1:
    /// the cell's median).
    #[arg(long, default_value_t = GridParams::default().weight)]
    pub cell_weight: f64,
    /// Take the value of the cell holding the position instead of
    /// interpolating bilinearly between cell centres.
    #[arg(long)]
    pub nearest: bool,
    /// Leave-one-flight-out over the manifest, for every candidate family:
    /// each flight evaluated with a calibration learnt on the others.
    #[arg(long, conflicts_with = "out")]
    pub cross_validate: bool,
    /// Candidate families for --cross-validate, comma-separated:
    /// `pair_constant` or `grid:CELL_M`, followed by `:nearest` (else
    /// bilinear) and `:wWEIGHT` (the cells' weight, else --cell-weight) in
    /// any order (default:
    /// pair_constant,grid:0.5,grid:1,grid:2,grid:1:w1,grid:1:nearest).
    #[arg(long, requires = "cross_validate")]
    pub candidates: Option<String>,
    /// Config file or preset name (default: the loader's choice per log, as for `insuwb eval`).
    #[arg(long)]
    pub config: Option<String>,
    /// Filters to evaluate with --cross-validate (default: the config's).
    #[arg(long)]
    pub filters: Option<String>,
    /// Velocity measurements that aid the filters in --cross-validate (as
    /// `insuwb eval --aiding`); the calibration itself is learnt from the
    /// TDOA residuals alone.
    #[arg(long, value_enum, default_value_t = dataset::Aiding::None, requires = "cross_validate")]
    pub aiding: dataset::Aiding,
    /// Threads (default: the available cores). The output does not depend on it.
    #[arg(long)]
    pub jobs: Option<std::num::NonZeroUsize>,
    /// Read Crazyflie logs even if their CRC does not match.
    #[arg(long)]
    pub ignore_crc: bool,
    /// Print one JSON object on standard output (tables go to standard error).
    #[arg(long)]
    pub json: bool,
}

/// A calibration read from a file, with its path for messages.
#[derive(Debug, Clone)]
pub struct CalibrationFile {
    /// The file.
    pub path: PathBuf,
    /// The calibration.
    pub calibration: Arc<SiteCalibration>,
}

impl CalibrationFile {
    /// Reads a calibration file.
    pub fn load(path: &Path) -> Result<Self> {
        // The error names the file and the key.
        let c = SiteCalibration::load(path)?;
        Ok(Self {
            path: path.to_owned(),
            calibration: Arc::new(c),
        })
    }

    /// Checks that the log `log` (anchors from `anchors`, else its TDOA
    /// stream) is of the calibration's constellation and sets it in the
    /// log's fusion settings.
    pub fn apply(&self, loaded: &mut Loaded, anchors: Option<&PathBuf>, log: &Path) -> Result<()> {
        let (other, origin) = flight_anchors(loaded, anchors, log)?;
        self.calibration
            .check_anchors(&other, &self.path, &origin)?;
        loaded.config.fusion.calibration = Some(self.calibration.clone());
        Ok(())
    }
}

/// The anchors of a flight: its anchor survey file when given (a UTIL
/// log), else those its TDOA stream carries; and where they came from.
fn flight_anchors(
    loaded: &Loaded,
    anchors: Option<&PathBuf>,
    log: &Path,
) -> Result<(BTreeMap<u32, [f64; 3]>, String)> {
    if let Some(path) = anchors {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        let origin = path.display().to_string();
        let a = insuwb_data::Anchors::parse(&text, &origin)?;
        let map = a
            .ids()
            .filter_map(|id| a.get(id).map(|p| (id, p)))
            .collect();
        return Ok((map, origin));
    }
    let mut map = BTreeMap::new();
    for m in &loaded.data.tdoa {
        map.entry(m.anchor_a).or_insert(m.anchor_a_pos_m);
        map.entry(m.anchor_b).or_insert(m.anchor_b_pos_m);
    }
    Ok((
        map,
        format!("{} (anchors of its TDOA records)", log.display()),
    ))
}

/// `q` (`[w, x, y, z]`, body to ENU) applied to `v`.
fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if !(n.is_finite() && n > 0.0) {
        return v;
    }
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    // t = 2 (q_v x v); v' = v + w t + q_v x t
    let t = [
        2.0 * (y * v[2] - z * v[1]),
        2.0 * (z * v[0] - x * v[2]),
        2.0 * (x * v[1] - y * v[0]),
    ];
    [
        v[0] + w * t[0] + (y * t[2] - z * t[1]),
        v[1] + w * t[1] + (z * t[0] - x * t[2]),
        v[2] + w * t[2] + (x * t[1] - y * t[0]),
    ]
}

/// The residual of every TDOA difference of the flight segment (truth
/// height above `eval.min_height_m`): measured minus true difference at
/// the antenna (truth interpolated to the measurement time, plus the lever
/// arm `fusion.tight.lever_arm_m` rotated by the truth's attitude).
fn residuals(loaded: &Loaded) -> Vec<Sample> {
    let d = &loaded.data;
    let lever = loaded.config.fusion.tight.lever_arm_m;
    let min_h = loaded.config.eval.min_height_m;
    let (t0, t1) = match d.segment {
        Some(s) => s,
        None if min_h <= 0.0 => (0, u64::MAX),
        None => return Vec::new(),
    };
    let mut out = Vec::with_capacity(d.tdoa.len());
    for m in &d.tdoa {
        let t = m.header.meas_time_ns;
        if t < t0 || t > t1 {
            continue;
        }
        let Some(g) = insuwb_data::interpolate_truth(&d.truth, t) else {
            continue;
        };
        if min_h > 0.0 && g.pos_m[2] <= min_h {
            continue;
        }
        let r = rotate(g.quat, lever);
        let ant = [g.pos_m[0] + r[0], g.pos_m[1] + r[1], g.pos_m[2] + r[2]];
        let truth =
            insuwb_uwb::calibration::true_difference(&ant, &m.anchor_a_pos_m, &m.anchor_b_pos_m);
        out.push(Sample {
            a: m.anchor_a,
            b: m.anchor_b,
            pos_m: ant,
            residual_m: m.diff_m - truth,
        });
    }
    out
}

/// One flight, loaded, with its anchors and residuals.
struct Flight {
    loaded: Loaded,
    anchors: BTreeMap<u32, [f64; 3]>,
    anchors_origin: String,
    samples: Vec<Sample>,
    /// The log holds the records `--aiding` asked for (else the flight is
    /// learnt from but not evaluated).
    aided: bool,
}

fn load_flight(a: &CalibrateArgs, f: &ManifestFlight) -> Result<Flight> {
    let mut loaded = dataset::load(
        &f.file,
        f.anchors.as_ref(),
        a.config.as_deref(),
        a.ignore_crc,
    )?;
    let aided = match loaded.use_aiding(a.aiding, &f.file) {
        Err(e) if NoFlowRecords::is_cause_of(&e) => {
            tracing::warn!("{e}: learnt from, not evaluated");
            loaded.use_aiding(dataset::Aiding::None, &f.file)?;
            false
        }
        r => r.map(|()| true)?,
    };
    if !loaded.recorded.is_empty() {
        bail!("{}: the log holds no IMU and UWB records", f.file.display());
    }
    let (anchors, anchors_origin) = flight_anchors(&loaded, f.anchors.as_ref(), &f.file)?;
    let samples = residuals(&loaded);
    Ok(Flight {
        loaded,
        anchors,
        anchors_origin,
        samples,
        aided,
    })
}

fn threads(jobs: Option<std::num::NonZeroUsize>) -> usize {
    jobs.map_or_else(
        || std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get),
        std::num::NonZeroUsize::get,
    )
}

fn costs(manifest: &Manifest) -> Vec<u64> {
    manifest
        .flights
        .iter()
        .map(|f| std::fs::metadata(&f.file).map_or(0, |m| m.len()))
        .collect()
}

/// Loads every flight in parallel (manifest order), the error naming the flight.
fn load_all(a: &CalibrateArgs, manifest: &Manifest, jobs: usize) -> Result<Vec<Flight>> {
    batch::map_in_parallel(
        &costs(manifest),
        jobs,
        |i| load_flight(a, &manifest.flights[i]),
        |_, _| {},
    )
    .map_err(|e| e.error.context(manifest.flight_label(e.index)))
}

/// The constellation of the flights: the first flight's anchors, every
/// other flight's checked against them (the calibration's rule).
fn constellation(manifest: &Manifest, flights: &[Flight]) -> Result<BTreeMap<u32, [f64; 3]>> {
    let Some(first) = flights.iter().find(|f| !f.samples.is_empty()) else {
        bail!(
            "{}: no flight has ground truth over a flight segment to learn from",
            manifest.path.display()
        );
    };
    // A calibration of the first flight's anchors, only to check the others.
    let probe = SiteCalibration::learn(first.anchors.clone(), Family::PairConstant, &first.samples)
        .with_context(|| format!("learning from {}", first.loaded.data.name))?;
    for (i, f) in flights.iter().enumerate() {
        probe
            .check_anchors(
                &f.anchors,
                Path::new(&first.anchors_origin),
                &f.anchors_origin,
            )
            .with_context(|| {
                format!(
                    "{}: not the constellation of the first flight",
                    manifest.flight_label(i)
                )
            })?;
    }
    Ok(first.anchors.clone())
}

/// An anchor whose offset over a flight (after the frame's) is beyond this
/// is named, m: on the shared UTIL flights the largest per flight is
/// 0.03-0.24 m, 0.32 m on one (docs/REAL_FLIGHTS.md, "Site calibration").
const ANCHOR_OFFSET_WARN_M: f64 = 0.3;

/// A frame offset longer than this is named, m: above the radio's
/// in-flight error; on the shared UTIL flights 0.03-0.29 m, but 0.66-0.68
/// m on two.
const FRAME_OFFSET_WARN_M: f64 = 0.4;

/// One flight's survey check ([`insuwb_uwb::survey`]).
struct Survey {
    /// The flight's name.
    flight: String,
    /// Its frame offset, if one was solved.
    frame: Option<insuwb_uwb::survey::FrameOffset>,
    /// Each anchor's offset, after the frame's.
    anchors: BTreeMap<u32, f64>,
}

impl Survey {
    /// The table of the survey checks, a flight a row.
    fn table(all: &[Self]) -> String {
        use std::fmt::Write as _;
        let mut t = String::from(
            "survey check (the radio's frame against the ground truth's, then the anchor \
             furthest off after it):\nflight                  frame e/n/u (m)     residual RMS (m)  \
             anchor\n",
        );
        for s in all {
            let name = Path::new(&s.flight)
                .file_name()
                .map_or(s.flight.clone(), |n| n.to_string_lossy().into_owned());
            let frame = s.frame.map_or_else(
                || format!("{:<17}   {:<14}", "-", "-"),
                |f| {
                    let [x, y, z] = f.offset_m;
                    format!(
                        "{x:+.2} {y:+.2} {z:+.2}   {:.3} -> {:.3}",
                        f.rms_before_m, f.rms_after_m
                    )
                },
            );
            let worst = s
                .anchors
                .iter()
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .map_or_else(|| "-".to_owned(), |(id, v)| format!("{id}: {v:+.2}"));
            let _ = writeln!(t, "{name:<23} {frame}    {worst}");
        }
        t
    }

    fn to_json(&self) -> serde_json::Value {
        let by_id: serde_json::Map<String, serde_json::Value> = self
            .anchors
            .iter()
            .map(|(id, v)| (id.to_string(), (*v).into()))
            .collect();
        serde_json::json!({
            "flight": self.flight,
            "frame_offset_m": self.frame.map(|f| f.offset_m),
            "frame_rms_before_m": self.frame.map(|f| f.rms_before_m),
            "frame_rms_after_m": self.frame.map(|f| f.rms_after_m),
            "offsets": by_id,
        })
    }
}

/// Each flight's survey check ([`insuwb_uwb::survey::check`]); a frame
/// beyond [`FRAME_OFFSET_WARN_M`] and an anchor beyond
/// [`ANCHOR_OFFSET_WARN_M`] are warned of.
fn survey(manifest: &Manifest, flights: &[Flight]) -> Vec<Survey> {
    let mut out = Vec::new();
    for (i, f) in flights.iter().enumerate() {
        if f.samples.is_empty() {
            continue;
        }
        let label = manifest.flight_label(i);
        let check = insuwb_uwb::survey::check(&f.samples, &f.anchors);
        match &check.frame {
            Ok(o) => {
                let [x, y, z] = o.offset_m;
                if (x * x + y * y + z * z).sqrt() > FRAME_OFFSET_WARN_M {
                    tracing::warn!(
                        "{label}: the radio places the tag ({x:+.2}, {y:+.2}, {z:+.2}) m (east, north, \
                         up) from the ground truth over the whole flight (residual RMS {:.2} m, \
                         {:.2} m less that): the anchors' survey and the ground truth's frame \
                         disagree; a calibration learns it as this site's bias",
                        o.rms_before_m,
                        o.rms_after_m
                    );
                }
            }
            Err(e) => tracing::warn!("{label}: no frame offset: {e}"),
        }
        match check.anchors {
            Ok(o) => {
                for (id, v) in o.iter().filter(|(_, v)| v.abs() > ANCHOR_OFFSET_WARN_M) {
                    tracing::warn!(
                        "{label}: anchor {id} reads {v:+.2} m against the others over the flight \
                         (its survey or its antenna delay): a calibration learns it as this \
                         site's bias"
                    );
                }
                out.push(Survey {
                    flight: f.loaded.data.name.clone(),
                    frame: check.frame.ok(),
                    anchors: o,
                });
            }
            Err(e) => tracing::warn!("{label}: no anchor offsets: {e}"),
        }
    }
    out
}

/// Learns from the samples of every flight but `skip`.
fn learn(
    anchors: &BTreeMap<u32, [f64; 3]>,
    family: Family,
    flights: &[Flight],
    skip: Option<usize>,
) -> Result<SiteCalibration> {
    let n: usize = flights.iter().map(|f| f.samples.len()).sum();
    let mut samples = Vec::with_capacity(n);
    for (i, f) in flights.iter().enumerate() {
        if Some(i) != skip {
            samples.extend_from_slice(&f.samples);
        }
    }
    Ok(SiteCalibration::learn(anchors.clone(), family, &samples)?)
}

fn family_of(a: &CalibrateArgs) -> Family {
    match a.model {
        ModelArg::PairConstant => Family::PairConstant,
        ModelArg::Grid => Family::Grid(grid_of(a)),
    }
}

/// The grid's settings on the command line.
fn grid_of(a: &CalibrateArgs) -> GridParams {
    GridParams {
        cell_m: a.cell_m,
        min_count: a.min_count,
        shrink_count: a.shrink_count,
        weight: a.cell_weight,
        bilinear: !a.nearest,
    }
}

/// Parses `--candidates`.
fn parse_candidates(a: &CalibrateArgs) -> Result<Vec<Family>> {
    let text = a
        .candidates
        .as_deref()
        .unwrap_or("pair_constant,grid:0.5,grid:1,grid:2,grid:1:w1,grid:1:nearest");
    text.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            let parts: Vec<&str> = s.split(':').collect();
            match parts.as_slice() {
                ["pair_constant"] => Ok(Family::PairConstant),
                ["grid", rest @ ..] => {
                    let mut g = grid_of(a);
                    let Some((cell, options)) = rest.split_first() else {
                        return Ok(Family::Grid(g));
                    };
                    g.cell_m = cell.parse().with_context(|| {
                        format!("--candidates: '{s}': '{cell}' is not a cell size in m")
                    })?;
                    g.bilinear = true;
                    for p in options {
                        if *p == "nearest" {
                            g.bilinear = false;
                        } else if *p == "bilinear" {
                            g.bilinear = true;
                        } else if let Some(w) = p.strip_prefix('w') {
                            g.weight = w.parse().with_context(|| {
                                format!("--candidates: '{s}': '{w}' is not a weight")
                            })?;
                        } else {
                            bail!("--candidates: '{s}': '{p}' is neither `nearest` nor `wWEIGHT`");
                        }
                    }
                    Ok(Family::Grid(g))
                }
                _ => bail!(
                    "--candidates: '{s}' is not a family (pair_constant, grid:CELL_M[:nearest][:wWEIGHT])"
                ),
            }
        })
        .collect()
}

/// Runs `insuwb calibrate`.
pub fn run(a: &CalibrateArgs) -> Result<()> {
    let manifest = Manifest::load(&a.flights)?;
    let jobs = threads(a.jobs);
    let t0 = std::time::Instant::now();
    let flights = load_all(a, &manifest, jobs)?;
    let anchors = constellation(&manifest, &flights)?;
    let with_truth = flights.iter().filter(|f| !f.samples.is_empty()).count();
    tracing::info!(
        "loaded {} flights ({with_truth} with ground truth over a flight segment, {} residuals) in {:.2} s",
        flights.len(),
        flights.iter().map(|f| f.samples.len()).sum::<usize>(),
        t0.elapsed().as_secs_f64()
    );
    let offsets = survey(&manifest, &flights);
    if a.cross_validate {
        return cross_validate(a, &manifest, &flights, &anchors, jobs);
    }
    let Some(out) = &a.out else {
        bail!("give --out FILE or --cross-validate");
    };
    let family = family_of(a);
    let c = learn(&anchors, family, &flights, None)?;
    c.save(out)?;
    let mut noise: Vec<f64> = c.pairs().values().map(|p| p.noise_m).collect();
    noise.sort_by(f64::total_cmp);
    let cells: usize = c.pairs().values().map(|p| p.cells.len()).sum();
    let table = format!(
        "{}{}: {} from {with_truth} flights of {}: {} anchors, {} pairs, {cells} cells, noise after the bias {:.3} m at the median pair\n",
        Survey::table(&offsets),
        out.display(),
        family.label(),
        manifest.path.display(),
        c.anchors().len(),
        c.pairs().len(),
        batch::median(&noise).unwrap_or(f64::NAN),
    );
    print_result(a.json, &table, || {
        Ok(serde_json::json!({
            "file": out.display().to_string(),
            "family": family.label(),
            "flights": with_truth,
            "anchors": c.anchors().len(),
            "pairs": c.pairs().len(),
            "cells": cells,
            "noise_median_m": batch::median(&noise),
            "anchor_offsets_m": offsets.iter().map(Survey::to_json).collect::<Vec<_>>(),
        }))
    })
}

/// `--cross-validate`.
fn cross_validate(
    a: &CalibrateArgs,
    manifest: &Manifest,
    flights: &[Flight],
    anchors: &BTreeMap<u32, [f64; 3]>,
    jobs: usize,
) -> Result<()> {
    let families = parse_candidates(a)?;
    let n = flights.len();
    // The flights evaluated: those with the aiding's records (all without
    // --aiding); every flight is learnt from.
    let (evaluated_manifest, evaluated, left_out) = crate::batch_cmd::keep_evaluated(
        manifest.clone(),
        flights
            .iter()
            .enumerate()
            .map(|(i, f)| f.aided.then_some(i))
            .collect(),
    )?;
    let m = evaluated.len();
    // Item k: family k / m (the last "family" is none: uncalibrated), flight
    // evaluated[k % m].
    let per_flight = costs(manifest);
    let item_costs: Vec<u64> = (0..(families.len() + 1) * m)
        .map(|k| per_flight[evaluated[k % m]])
        .collect();
    let quiet = tracing::Dispatch::new(
        tracing_subscriber::fmt()
            .with_writer(std::io::stderr)
            .with_max_level(tracing::Level::WARN)
            .finish(),
    );
    let results = batch::map_in_parallel(
        &item_costs,
        jobs,
        |k| -> Result<FlightMetrics> {
            tracing::dispatcher::with_default(&quiet, || {
                let (fam, i) = (k / m, evaluated[k % m]);
                let f = &flights[i];
                let mut fusion = f.loaded.config.fusion.clone();
                if let Some(family) = families.get(fam) {
                    let c = learn(anchors, *family, flights, Some(i))?;
                    fusion.calibration = Some(Arc::new(c));
                }
                let rep = evaluate_ref(&f.loaded, &fusion, a.filters.as_deref())?;
                Ok(rep
                    .solutions
                    .into_iter()
                    .filter(|s| s.key != "ins")
                    .map(|s| (s.key, s.metrics))
                    .collect())
            })
        },
        |_, _| {},
    )
    .map_err(|e| {
        e.error
            .context(manifest.flight_label(evaluated[e.index % m]))
    })?;
    let manifest = &evaluated_manifest;
    let blocks: Vec<&[FlightMetrics]> = results.chunks(m).collect();
    let Some((uncal, cal)) = blocks.split_last() else {
        bail!("nothing evaluated");
    };
    let uncal_sum = batch::summarize(manifest, uncal);
    let sums: Vec<_> = cal.iter().map(|r| batch::summarize(manifest, r)).collect();
    let mut table = format!(
        "{}: leave-one-flight-out, each flight with a calibration learnt on the other {}\n",
        manifest.path.display(),
        n.saturating_sub(1)
    );
    if !left_out.is_empty() {
        table.push_str(&format!(
            "{} of {n} flights learnt from but not evaluated, their logs hold no optical-flow records: {}\n",
            left_out.len(),
            left_out.join(", ")
        ));
    }
    for (family, r) in families.iter().zip(cal.iter()) {
        table.push_str(&format_flights(manifest, &family.label(), r, uncal));
    }
    table.push_str(&format_summary(manifest, &families, &sums, &uncal_sum));
    print_result(a.json, &table, || {
        let mut fams = Vec::new();
        for ((family, r), s) in families.iter().zip(cal.iter()).zip(&sums) {
            let mut v = batch::to_json(manifest, r, s)
                .map_err(|e| anyhow::anyhow!("{}: {e}", manifest.path.display()))?;
            if let Some(o) = v.as_object_mut() {
                o.insert("family".into(), family.label().into());
            }
            fams.push(v);
        }
        let u = batch::to_json(manifest, uncal, &uncal_sum)
            .map_err(|e| anyhow::anyhow!("{}: {e}", manifest.path.display()))?;
        Ok(serde_json::json!({ "uncalibrated": u, "families": fams, "left_out": left_out }))
    })
}

/// The RMSE of `key` on a flight.
fn rmse(r: &FlightMetrics, key: &str) -> Option<f64> {
    r.iter()
        .find(|(k, _)| k == key)
        .map(|(_, m)| m.rmse_horizontal)
}

fn keys(results: &[FlightMetrics]) -> Vec<String> {
    let mut keys: Vec<String> = Vec::new();
    for (k, _) in results.iter().flatten() {
        if !keys.contains(k) {
            keys.push(k.clone());
        }
    }
    keys
}

/// Per flight, each solution's ratio to each reference: calibrated, and
/// uncalibrated in brackets.
fn format_flights(
    manifest: &Manifest,
    label: &str,
    cal: &[FlightMetrics],
    uncal: &[FlightMetrics],
) -> String {
    use std::fmt::Write as _;
    let keys = keys(cal);
    let w = manifest.name_width();
    let mut s = String::new();
    for (c, col) in manifest.references.iter().enumerate() {
        let _ = writeln!(s, "\n{label}: ratio to {col}, calibrated (uncalibrated)");
        let _ = write!(s, "{:<w$}", "flight");
        for k in &keys {
            let _ = write!(s, " {:>15}", batch::solution_title(k));
        }
        let _ = writeln!(s);
        for ((f, rc), ru) in manifest.flights.iter().zip(cal).zip(uncal) {
            let _ = write!(s, "{:<w$}", f.name);
            let r = f.references.get(c).copied().flatten();
            for k in &keys {
                let cell = match (r, rmse(rc, k), rmse(ru, k)) {
                    (Some(r), Some(x), Some(y)) => format!("{:.3} ({:.3})", x / r, y / r),
                    _ => "-".to_owned(),
                };
                let _ = write!(s, " {cell:>15}");
            }
            let _ = writeln!(s);
        }
    }
    s
}

/// Per reference and solution: median / worst / flights above 1 of each
/// family, then uncalibrated.
fn format_summary(
    manifest: &Manifest,
    families: &[Family],
    sums: &[Vec<batch::SolutionSummary>],
    uncal: &[batch::SolutionSummary],
) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let labels: Vec<String> = families
        .iter()
        .map(Family::label)
        .chain(std::iter::once("uncalibrated".to_owned()))
        .collect();
    let cols: Vec<&[batch::SolutionSummary]> = sums
        .iter()
        .map(Vec::as_slice)
        .chain(std::iter::once(uncal))
        .collect();
    for (c, col) in manifest.references.iter().enumerate() {
        let _ = writeln!(
            s,
            "\nsummary: ratio to {col}, median / worst / flights above 1"
        );
        let _ = write!(s, "{:<10}", "");
        for l in &labels {
            let _ = write!(s, " {l:>22}");
        }
        let _ = writeln!(s);
        for sol in uncal {
            let _ = write!(s, "{:<10}", batch::solution_title(&sol.key));
            for sum in &cols {
                let cell = sum
                    .iter()
                    .find(|x| x.key == sol.key)
                    .and_then(|x| x.references.get(c).copied().flatten())
                    .map_or_else(
                        || "-".to_owned(),
                        |r| {
                            format!(
                                "{:.3} / {:.3} / {:>2} of {}",
                                r.median, r.worst, r.above_1, r.flights
                            )
                        },
                    );
                let _ = write!(s, " {cell:>22}");
            }
            let _ = writeln!(s);
        }
    }
    s
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::{parse_candidates, rotate, CalibrateArgs};
    use clap::Parser;
    use insuwb_uwb::calibration::{Family, GridParams};

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: CalibrateArgs,
    }

    fn candidates(text: &str) -> anyhow::Result<Vec<Family>> {
        let cli = Cli::try_parse_from(
            ["calibrate", "--flights", "m.csv", "--cross-validate"]
                .into_iter()
                .chain(["--candidates", text]),
        )?;
        parse_candidates(&cli.args)
    }

    #[test]
    fn candidates_name_the_cell_its_lookup_and_its_weight() {
        let d = GridParams::default();
        let got = candidates(
            "pair_constant, grid:2, grid:1:w1, grid:1:nearest:w0.25, grid:0.5:w0:bilinear",
        )
        .unwrap();
        assert_eq!(
            got,
            [
                Family::PairConstant,
                Family::Grid(GridParams { cell_m: 2.0, ..d }),
                Family::Grid(GridParams { weight: 1.0, ..d }),
                Family::Grid(GridParams {
                    weight: 0.25,
                    bilinear: false,
                    ..d
                }),
                Family::Grid(GridParams {
                    cell_m: 0.5,
                    weight: 0.0,
                    ..d
                }),
            ]
        );
        for bad in ["grid:x", "grid:1:wx", "grid:1:far", "table:1"] {
            let e = candidates(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn rotation_by_a_quaternion() {
        // 90 deg about z: x -> y.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let v = rotate([h, 0.0, 0.0, h], [1.0, 0.0, 0.5]);
        assert!((v[0]).abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12 && (v[2] - 0.5).abs() < 1e-12);
        assert_eq!(
            rotate([1.0, 0.0, 0.0, 0.0], [1.0, 2.0, 3.0]),
            [1.0, 2.0, 3.0]
        );
    }
}
