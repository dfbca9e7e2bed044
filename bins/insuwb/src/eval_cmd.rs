//! `insuwb eval`, `insuwb sim`, `insuwb fit-ar` and `insuwb import`.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use insuwb_eval::metrics::Metrics;
use insuwb_eval::run::EvalReport;
use insuwb_eval::scenario::{dataset_with as scenario_dataset, monte_carlo_with, ScenarioOptions};
use insuwb_fusion::scenario::ScenarioFile;
use insuwb_log::{LogWriter, Metadata, Record};
use insuwb_msg::FilterKind;

use crate::dataset::{self, ConfigFile, META_FUSION_CONFIG};

/// Filters run when `--filters` is not given.
pub const DEFAULT_FILTERS: [FilterKind; 4] = [
    FilterKind::Kf,
    FilterKind::Shaf,
    FilterKind::Stf,
    FilterKind::Iakf,
];

/// Parses `--filters kf,iakf`.
/// `iakf_twr` names the tight filter as `iakf_tdoa` does: on a ranging
/// log it fuses the ranges and its solution is called so.
pub fn parse_filters(list: Option<&str>, default: &[FilterKind]) -> Result<Vec<FilterKind>> {
    let Some(list) = list else {
        return Ok(default.to_vec());
    };
    list.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| match s {
            insuwb_eval::run::TIGHT_TWR_KEY => Ok(FilterKind::IakfTdoa),
            s => s.parse::<FilterKind>().context("--filters"),
        })
        .collect()
}

/// Arguments of `insuwb eval`.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// A log to evaluate: an insuwb log or a UTIL Crazyflie log (detected from its content).
    pub file: Option<PathBuf>,
    /// Evaluate every flight of a manifest instead, in parallel: a CSV file
    /// with `file` and `anchors` columns (paths relative to it); every other
    /// column whose name ends in `_m` is a reference horizontal RMSE (m),
    /// printed beside and summarised as ratios.
    #[arg(long, conflicts_with_all = ["file", "scenario", "anchors"])]
    pub flights: Option<PathBuf>,
    /// Threads for --flights (default: the available cores).
    #[arg(long, requires = "flights")]
    pub jobs: Option<std::num::NonZeroUsize>,
    /// Simulate a scenario instead: a built-in name (paper-3.4, paper-4.3-static,
    /// paper-4.4-dynamic, nlos-long, ground-outage, twr-3.4) or a TOML file; `model-true` runs the
    /// consistency check on data drawn from the filter's own model.
    #[arg(long, conflicts_with = "file")]
    pub scenario: Option<String>,
    /// Monte-Carlo runs of the scenario (seeds seed, seed+1, ...); metrics are averaged.
    #[arg(long, default_value_t = 1)]
    pub runs: u32,
    /// First seed (default: the scenario's own).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Filters to run, comma-separated (kf, shaf, stf, iakf, iakf_tdoa); default all.
    #[arg(long)]
    pub filters: Option<String>,
    /// Anchor survey for a Crazyflie log (anN_p,x,y,z rows).
    #[arg(long)]
    pub anchors: Option<PathBuf>,
    /// Config file ([fusion], [import], [eval]) or built-in preset name; overrides the default.
    #[arg(long)]
    pub config: Option<String>,
    /// Read a Crazyflie log even if its CRC does not match (a log cut short is read up to its last whole record without it).
    #[arg(long)]
    pub ignore_crc: bool,
    /// Print one JSON object on standard output (tables go to standard error).
    #[arg(long)]
    pub json: bool,
    /// Write SVG figures into this directory.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write every solution's estimates, the truth and the error at each
    /// epoch into this CSV file (one row per solution and epoch).
    #[arg(long, conflicts_with = "flights")]
    pub tracks: Option<PathBuf>,
    /// A site calibration of the TDOA differences (`insuwb calibrate`),
    /// applied to every difference before the fixes and the tight filter
    /// use it; refused for a log whose anchors are not the calibration's.
    #[arg(long, conflicts_with = "scenario")]
    pub calibration: Option<PathBuf>,
    /// The vehicle model of the INS and every filter, overriding the
    /// config's `[fusion] vehicle`: free (every accelerometer axis
    /// integrated), multirotor (thrust along body z and rotor drag) or
    /// ground (no lateral or vertical body velocity).
    #[arg(long)]
    pub vehicle: Option<insuwb_nav::vehicle::VehicleKind>,
    /// The part of a log evaluated: `flight` (ground truth above the
    /// config's `[eval] min_height_m`) or `all` (the whole log: a vehicle
    /// that stays on the floor); default: a manifest's `segment` column,
    /// else the config's `[eval] segment`.
    #[arg(long, conflicts_with = "scenario")]
    pub segment: Option<insuwb_eval::run::Segment>,
    /// Velocity measurements that aid the filters (`flow`: a UTIL log's
    /// optical-flow deck or a scenario's `[sim.flow]`; `odometry`: a
    /// scenario's `[sim.odometry]`); the solutions keep their names, so
    /// the same command with and without it compares them. A log or
    /// scenario without such measurements is an error; without the flag
    /// a scenario's simulated velocities are not used.
    #[arg(long, value_enum, default_value_t = dataset::Aiding::None)]
    pub aiding: dataset::Aiding,
    /// With --scenario: evaluate at the ground truth's sample times inside
    /// START,END (s from the start of the run), each solution interpolated
    /// there (a filter's coasting states included, where the scenario's
    /// `[fusion.output]` has them), instead of at the UWB fix epochs of the
    /// whole run: a UWB outage has no fix epoch.
    #[arg(long, value_name = "START,END", value_parser = parse_window)]
    pub window: Option<[f64; 2]>,
}

/// Parses `--window 30,41`.
fn parse_window(s: &str) -> Result<[f64; 2], String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("expected START,END in seconds, got {s:?}"))?;
    let num = |t: &str| t.trim().parse::<f64>().map_err(|e| format!("{t:?}: {e}"));
    let (a, b) = (num(a)?, num(b)?);
    if !(a.is_finite() && b.is_finite() && a >= 0.0 && a < b) {
        return Err(format!("expected 0 <= START < END, got {a},{b}"));
    }
    Ok([a, b])
}

/// Runs `insuwb eval`.
pub fn eval(a: &EvalArgs) -> Result<()> {
    if a.window.is_some() && a.scenario.is_none() {
        bail!("--window is for --scenario: a log is evaluated where its [eval] table says");
    }
    if a.scenario.as_deref() == Some("model-true") {
        return model_true(a);
    }
    if let Some(manifest) = &a.flights {
        return crate::batch_cmd::eval_flights(a, manifest);
    }
    let (rows, title): (Vec<(String, Metrics)>, String) = if let Some(name) = &a.scenario {
        let mut file = ScenarioFile::load(name)?;
        if let Some(c) = &a.config {
            file.fusion = ConfigFile::load(c)?.fusion;
        }
        if let Some(v) = a.vehicle {
            file.fusion.vehicle = v;
        }
        let filters = parse_filters(a.filters.as_deref(), &DEFAULT_FILTERS)?;
        let seed = a.seed.unwrap_or(file.sim.seed);
        let opts = ScenarioOptions {
            velocity_sources: a.aiding.scenario_sources(),
            window_s: a.window,
        };
        if a.plot.is_some() || a.tracks.is_some() {
            let data = scenario_dataset(&file, seed, &opts)?;
            let cfg = file.fusion_for_seed(seed)?;
            let epochs = if opts.window_s.is_some() {
                insuwb_eval::run::Epochs::Truth
            } else {
                insuwb_eval::run::Epochs::Fixes
            };
            let rep = insuwb_eval::run::evaluate_at(&data, &cfg, &filters, epochs)?;
            if let Some(dir) = &a.plot {
                write_plots(&rep, &data, dir)?;
            }
            if let Some(path) = &a.tracks {
                write_tracks(&rep, &data, path)?;
            }
        }
        let rows = monte_carlo_with(&file, &filters, a.runs, seed, &opts)?;
        let mut title = format!(
            "scenario {} ({} run(s) from seed {seed})",
            file.sim.name,
            a.runs.max(1)
        );
        if a.aiding != dataset::Aiding::None {
            title.push_str(&format!(", aided by {:?}", a.aiding).to_lowercase());
        }
        if let Some([s0, s1]) = a.window {
            title.push_str(&format!(", at the truth's times in {s0}..{s1} s"));
        }
        (rows, title)
    } else if let Some(path) = &a.file {
        let mut loaded =
            dataset::load(path, a.anchors.as_ref(), a.config.as_deref(), a.ignore_crc)?;
        if !loaded.recorded.is_empty() {
            return eval_recorded(a, path, &loaded);
        }
        if let Some(v) = a.vehicle {
            loaded.config.fusion.vehicle = v;
        }
        loaded.choose_segment(a.segment, path)?;
        loaded.use_aiding(a.aiding, path)?;
        if let Some(c) = &a.calibration {
            let c = crate::calibrate_cmd::CalibrationFile::load(c)?;
            c.apply(&mut loaded, a.anchors.as_ref(), path)?;
        }
        let (loaded, rep) = evaluate_loaded(loaded, a.filters.as_deref())?;
        if let Some(dir) = &a.plot {
            write_plots(&rep, &loaded.data, dir)?;
        }
        if let Some(p) = &a.tracks {
            write_tracks(&rep, &loaded.data, p)?;
        }
        let rows = rep
            .solutions
            .into_iter()
            .map(|s| (s.key, s.metrics))
            .collect();
        (
            rows,
            format!("{} ({})", path.display(), loaded.segment_note),
        )
    } else {
        bail!("give a FILE, --flights MANIFEST.csv or --scenario NAME (see insuwb eval --help)");
    };
    let table = format_table(&title, &rows);
    print_result(a.json, &table, || {
        insuwb_eval::run::to_json(&rows).map_err(|e| anyhow::anyhow!("{e}"))
    })
}

/// `insuwb eval` of a log that holds fused states and no IMU and UWB
/// records (a fleet station's recording of a robot): its recorded track
/// as the one solution, `recorded` (states, span, rate; its accuracy where
/// the log has ground truth), instead of the filters.
fn eval_recorded(a: &EvalArgs, path: &Path, loaded: &dataset::Loaded) -> Result<()> {
    use insuwb_eval::recorded::{evaluate_recorded, RECORDED};
    if a.plot.is_some() || a.tracks.is_some() || a.filters.is_some() {
        bail!(
            "{}: the log holds fused states but no IMU and UWB records: no filter to run, plot or track (--filters, --plot, --tracks)",
            path.display()
        );
    }
    let d = &loaded.data;
    let r = evaluate_recorded(&loaded.recorded, &d.truth, d.segment)
        .with_context(|| format!("{}: the recorded track", path.display()))?;
    let mut table = format!(
        "{}: no IMU and UWB records to run the filters on; the recorded track ({} fused states) instead\n{:<10} {:>8} {:>10} {:>10}\n{:<10} {:>8} {:>10.3} {:>10.3}\n",
        path.display(),
        loaded.recorded.len(),
        "",
        "states",
        "span (s)",
        "rate (Hz)",
        RECORDED,
        r.states,
        r.span_s,
        r.rate_hz
    );
    match &r.metrics {
        Some(m) => table.push_str(&format_table(
            "against the log's ground truth:",
            &[(RECORDED.to_owned(), m.clone())],
        )),
        None => table.push_str("no ground truth in the log: no accuracy figures\n"),
    }
    print_result(a.json, &table, || {
        let mut v = match &r.metrics {
            Some(m) => insuwb_eval::run::to_json(&[(RECORDED.to_owned(), m.clone())])
                .map_err(|e| anyhow::anyhow!("{e}"))?,
            None => serde_json::json!({ RECORDED: {} }),
        };
        if let Some(o) = v
            .get_mut(RECORDED)
            .and_then(serde_json::Value::as_object_mut)
        {
            o.insert("states".into(), r.states.into());
            o.insert("span_s".into(), r.span_s.into());
            o.insert("rate_hz".into(), r.rate_hz.into());
        }
        Ok(v)
    })
}

/// Prints `table` on standard output; with `json`, the table goes to
/// standard error and the JSON object that `value` makes to standard output.
pub fn print_result(
    json: bool,
    table: &str,
    value: impl FnOnce() -> Result<serde_json::Value>,
) -> Result<()> {
    if json {
        eprint!("{table}");
        let v = value()?;
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &v)?;
        writeln!(out)?;
    } else {
        print!("{table}");
    }
    Ok(())
}

/// `--scenario model-true`: data generated from the filter's own model (the
/// paper-3.4 settings' F, Q, H, R_0, P_0; no outliers), Monte-Carlo NEES and
/// NIS against their chi-square bands, per filter.
fn model_true(a: &EvalArgs) -> Result<()> {
    use insuwb_eval::consistency::{run_consistency, ConsistencyConfig};
    let file = ScenarioFile::load("paper-3.4")?;
    let fusion = match &a.config {
        Some(c) => ConfigFile::load(c)?.fusion,
        None => file.fusion,
    };
    let filters = parse_filters(a.filters.as_deref(), &DEFAULT_FILTERS)?;
    let mut map = serde_json::Map::new();
    let mut table = format!(
        "model-true: {} runs from seed {}, predict at {} Hz, update every 10 predicts, 150 updates\n{:<6} {:>9} {:>9} {:>16} {:>16}\n",
        a.runs.max(1),
        a.seed.unwrap_or(1),
        fusion.model.ar_rate_hz,
        "",
        "NEES",
        "NIS",
        "NEES in band",
        "NIS in band"
    );
    for kind in filters {
        let cc = ConsistencyConfig {
            runs: a.runs.max(1),
            steps: 150,
            update_every: 10,
            seed: a.seed.unwrap_or(1),
            kind,
        };
        let r = run_consistency(&fusion.model, &fusion.filter, &fusion.setup, &cc)?;
        table.push_str(&format!(
            "{:<6} {:>9.3} {:>9.3} {:>15.1}% {:>15.1}%   (95 % band of the mean NEES [{:.2}, {:.2}], NIS [{:.2}, {:.2}])\n",
            kind.name().to_uppercase(),
            r.nees_mean,
            r.nis_mean,
            100.0 * r.nees_in_band_fraction,
            100.0 * r.nis_in_band_fraction,
            r.nees_band[0],
            r.nees_band[1],
            r.nis_band[0],
            r.nis_band[1]
        ));
        map.insert(
            kind.name().to_owned(),
            serde_json::json!({
                "nees_mean": r.nees_mean,
                "nis_mean": r.nis_mean,
                "nees_in_band_fraction": r.nees_in_band_fraction,
                "nis_in_band_fraction": r.nis_in_band_fraction,
                "nees_band": r.nees_band,
                "nis_band": r.nis_band,
            }),
        );
    }
    print_result(a.json, &table, || Ok(serde_json::Value::Object(map)))
}

/// Loads a log (`dataset::load`: `config` if given, else the log's own
/// settings or its format's preset) and evaluates it with `filters`, else
/// the filters its config names; logs the config and the run time.
pub fn evaluate_file(
    path: &Path,
    anchors: Option<&PathBuf>,
    config: Option<&str>,
    ignore_crc: bool,
    filters: Option<&str>,
    calibration: Option<&crate::calibrate_cmd::CalibrationFile>,
    run: dataset::RunChoice,
) -> Result<(dataset::Loaded, EvalReport)> {
    let mut loaded = dataset::load(path, anchors, config, ignore_crc)?;
    if let Some(v) = run.vehicle {
        loaded.config.fusion.vehicle = v;
    }
    loaded.use_aiding(run.aiding, path)?;
    if !loaded.recorded.is_empty() {
        bail!(
            "{}: the log holds fused states but no IMU and UWB records to run the filters on: `insuwb eval {}` reports its recorded track",
            path.display(),
            path.display()
        );
    }
    loaded.choose_segment(run.segment, path)?;
    if let Some(c) = calibration {
        c.apply(&mut loaded, anchors, path)?;
    }
    evaluate_loaded(loaded, filters)
}

/// Evaluates a loaded log with `filters`, else the filters its config
/// names; logs the config and the run time.
fn evaluate_loaded(
    loaded: dataset::Loaded,
    filters: Option<&str>,
) -> Result<(dataset::Loaded, EvalReport)> {
    let rep = evaluate_ref(&loaded, &loaded.config.fusion, filters)?;
    Ok((loaded, rep))
}

/// Evaluates a loaded log with the fusion settings `fusion` (its own, or
/// those with a calibration) and `filters`, else the filters its config
/// names; logs the config and the run time.
pub fn evaluate_ref(
    loaded: &dataset::Loaded,
    fusion: &insuwb_fusion::config::FusionConfig,
    filters: Option<&str>,
) -> Result<EvalReport> {
    tracing::info!("config: {}", loaded.config_origin);
    let filters = parse_filters(filters, &loaded.config.eval.filters)?;
    let t0 = std::time::Instant::now();
    let rep =
        insuwb_eval::run::evaluate_at(&loaded.data, fusion, &filters, loaded.config.eval.epochs)?;
    let elapsed = t0.elapsed();
    let dur_s = loaded
        .data
        .imu
        .last()
        .map_or(0.0, |s| s.header.meas_time_ns as f64 * 1e-9);
    tracing::info!(
        "evaluated {} solutions on {:.1} s of data in {:.3} s ({:.4} of real time)",
        rep.solutions.len(),
        dur_s,
        elapsed.as_secs_f64(),
        elapsed.as_secs_f64() / dur_s.max(1e-9)
    );
    Ok(rep)
}

/// Writes the figures of one evaluation into `dir`, anchors taken from the TDOA stream.
pub fn write_plots(
    rep: &insuwb_eval::run::EvalReport,
    data: &insuwb_eval::run::Dataset,
    dir: &Path,
) -> Result<()> {
    let anchors = insuwb_eval::plot::anchor_positions(&data.tdoa);
    let files = insuwb_eval::plot::write_figures(rep, &data.truth, &anchors, dir)?;
    for f in files {
        tracing::info!("wrote {}", f.display());
    }
    Ok(())
}

/// Writes every solution's estimates of one evaluation into the CSV file `path`.
pub fn write_tracks(
    rep: &insuwb_eval::run::EvalReport,
    data: &insuwb_eval::run::Dataset,
    path: &Path,
) -> Result<()> {
    let rows = insuwb_eval::tracks::write(rep, data, path)?;
    tracing::info!("wrote {rows} rows into {}", path.display());
    Ok(())
}

/// The table of Table 1's shape, plus horizontal RMS, max distance, NEES,
/// NIS and the divergence monitor's resets inside the evaluated segment.
#[must_use]
pub fn format_table(title: &str, rows: &[(String, Metrics)]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "{title}");
    let _ = writeln!(
        s,
        "{:<10} {:>8} {:>8} {:>8}  {:>19}  {:>19} {:>8} {:>8} {:>7} {:>7} {:>7}",
        "",
        "RMSE E",
        "RMSE N",
        "Mean",
        "range E (m)",
        "range N (m)",
        "RMS hor",
        "max",
        "NEES",
        "NIS",
        "resets"
    );
    for (k, m) in rows {
        let opt = |v: Option<f64>| v.map_or("-".to_owned(), |x| format!("{x:.2}"));
        // A count, or the mean over Monte-Carlo runs.
        let resets = m.divergences.map_or("-".to_owned(), |x| {
            if x.fract() == 0.0 {
                format!("{x:.0}")
            } else {
                format!("{x:.2}")
            }
        });
        let _ = writeln!(
            s,
            "{:<10} {:>8.4} {:>8.4} {:>8.4}  {:>8.4} ~ {:>8.4}  {:>8.4} ~ {:>8.4} {:>8.4} {:>8.4} {:>7} {:>7} {:>7}",
            insuwb_eval::batch::solution_title(k),
            m.rmse_east,
            m.rmse_north,
            m.rmse_mean,
            m.range_east[0],
            m.range_east[1],
            m.range_north[0],
            m.range_north[1],
            m.rmse_horizontal,
            m.max_dist,
            opt(m.nees_mean),
            opt(m.nis_mean),
            resets
        );
    }
    s
}

/// Arguments of `insuwb sim`.
#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Built-in scenario name or TOML file.
    #[arg(long)]
    pub scenario: String,
    /// Seed (default: the scenario's own).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output log file (must not exist).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `insuwb sim`: writes IMU, TDOA and ground truth into a project log,
/// with the fusion settings (INS start for this seed included) in its metadata.
pub fn sim(a: &SimArgs) -> Result<()> {
    let file = ScenarioFile::load(&a.scenario)?;
    let seed = a.seed.unwrap_or(file.sim.seed);
    let out = insuwb_sim::simulate(&file.sim, seed)?;
    let cfg = ConfigFile {
        fusion: file.fusion_for_seed(seed)?,
        ..ConfigFile::default()
    };
    let cfg_text = toml::to_string(&cfg).context("serialising the fusion config")?;
    let meta = Metadata::new(format!("insuwb sim {} seed={seed}", file.sim.name))
        .with("scenario", file.sim.name.clone())
        .with("seed", seed.to_string())
        .with(META_FUSION_CONFIG, cfg_text)
        .with(insuwb_group::robot::LOG_UWB_KIND, file.sim.uwb.kind.name());
    // The error names the file and the cause.
    let mut w = LogWriter::create(&a.out, &meta, 0)?;
    let mut n = 0u64;
    for r in out.merged() {
        let rec = match r {
            insuwb_sim::SimRecord::Imu(s) => Record::Imu(s),
            insuwb_sim::SimRecord::Tdoa(s) => Record::Tdoa(s),
            insuwb_sim::SimRecord::Range(s) => Record::Range(s),
            insuwb_sim::SimRecord::Truth(s) => Record::Truth(s),
            insuwb_sim::SimRecord::Velocity(s) => Record::BodyVel(s),
            insuwb_sim::SimRecord::Height(s) => Record::Height(s),
        };
        w.append(&rec)?;
        n += 1;
    }
    w.finish()?;
    eprintln!("wrote {n} records to {}", a.out.display());
    Ok(())
}

/// Arguments of `insuwb fit-ar`.
#[derive(Debug, clap::Args)]
pub struct FitArArgs {
    /// A log (insuwb or Crazyflie) holding a static segment.
    pub file: PathBuf,
    /// Start of the static segment, s from the log's start (default: detected).
    #[arg(long)]
    pub from: Option<f64>,
    /// End of the static segment, s (default: detected).
    #[arg(long)]
    pub to: Option<f64>,
    /// Anchor survey (needed to read a Crazyflie log).
    #[arg(long)]
    pub anchors: Option<PathBuf>,
}

/// Runs `insuwb fit-ar`: AR(3) of the east and north accelerometer and the
/// vertical gyro channels over a static segment, as a TOML snippet.
pub fn fit_ar(a: &FitArArgs) -> Result<()> {
    let loaded = dataset::load(&a.file, a.anchors.as_ref(), None, false)?;
    let imu = &loaded.data.imu;
    let (from_ns, to_ns) = match (a.from, a.to) {
        (Some(f), Some(t)) if t > f && f >= 0.0 => ((f * 1e9) as u64, (t * 1e9) as u64),
        (None, None) => {
            let mut det = insuwb_nav::align::StaticDetector::new(
                insuwb_nav::align::StaticDetectorConfig::default(),
            )?;
            let mut seg = None;
            for s in imu {
                if let Some(sg) = det.push(s.header.meas_time_ns, s.accel_mps2, s.gyro_rps)? {
                    seg = Some(sg);
                    break;
                }
            }
            let seg = seg
                .or_else(|| det.finish())
                .context("no static segment found at the start of the log: give --from and --to")?;
            (seg.start_ns, seg.end_ns)
        }
        _ => bail!("give both --from and --to (seconds, from < to), or neither"),
    };
    let seg: Vec<_> = imu
        .iter()
        .filter(|s| (from_ns..=to_ns).contains(&s.header.meas_time_ns))
        .collect();
    if seg.len() < 100 {
        bail!(
            "the segment {:.3}-{:.3} s holds {} IMU samples: at least 100 are needed",
            from_ns as f64 * 1e-9,
            to_ns as f64 * 1e-9,
            seg.len()
        );
    }
    let rate_hz = (seg.len() - 1) as f64
        / ((seg[seg.len() - 1].header.meas_time_ns - seg[0].header.meas_time_ns) as f64 * 1e-9);
    // At rest the body axes are the sensor channels: x and y accelerometers
    // stand for the east and north channels, z gyro for the heading rate.
    let ax: Vec<f64> = seg.iter().map(|s| s.accel_mps2[0]).collect();
    let ay: Vec<f64> = seg.iter().map(|s| s.accel_mps2[1]).collect();
    let gz: Vec<f64> = seg.iter().map(|s| s.gyro_rps[2]).collect();
    let fe = insuwb_nav::ar::fit_ar3(&ax)?;
    let fnn = insuwb_nav::ar::fit_ar3(&ay)?;
    let fw = insuwb_nav::ar::fit_ar3(&gz)?;
    println!(
        "# AR(3) fitted by Yule-Walker on {} static samples ({:.3}-{:.3} s) of {}\n\
         # at {rate_hz:.1} Hz: paste into the [fusion.model] table of a config.",
        seg.len(),
        from_ns as f64 * 1e-9,
        to_ns as f64 * 1e-9,
        a.file.display()
    );
    println!("[fusion.model]\nar_rate_hz = {rate_hz:.3}");
    for (name, f) in [("ar_accel_e", fe), ("ar_accel_n", fnn), ("ar_gyro", fw)] {
        println!(
            "{name} = {{ m = [{:.6e}, {:.6e}, {:.6e}], noise_var = {:.6e} }}  # mean {:.4e}",
            f.m[0], f.m[1], f.m[2], f.noise_var, f.mean
        );
    }
    Ok(())
}

/// Arguments of `insuwb import util`.
#[derive(Debug, clap::Args)]
pub struct ImportUtilArgs {
    /// The Crazyflie log.
    pub log: PathBuf,
    /// Its anchor survey.
    #[arg(long)]
    pub anchors: PathBuf,
    /// Output project log (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// Config file or preset whose [fusion] settings go into the log (default: util).
    #[arg(long)]
    pub config: Option<String>,
    /// Read the log even if its CRC does not match (a log cut short is read up to its last whole record without it).
    #[arg(long)]
    pub ignore_crc: bool,
}

/// Runs `insuwb import util`.
pub fn import_util(a: &ImportUtilArgs) -> Result<()> {
    let loaded = dataset::load(&a.log, Some(&a.anchors), a.config.as_deref(), a.ignore_crc)?;
    if dataset::detect(&a.log)? != dataset::FileKind::CfLog {
        bail!("{}: not a Crazyflie event log", a.log.display());
    }
    let mut cfg = loaded.config.clone();
    cfg.eval.min_height_m = insuwb_data::segment::DEFAULT_MIN_HEIGHT_M;
    let d = &loaded.data;
    let kind = if d.is_ranging() {
        insuwb_msg::UwbKind::Twr
    } else {
        insuwb_msg::UwbKind::Tdoa
    };
    let meta = Metadata::new(format!("insuwb import util {}", a.log.display()))
        .with(META_FUSION_CONFIG, toml::to_string(&cfg)?)
        .with(insuwb_group::robot::LOG_UWB_KIND, kind.name());
    // The error names the file and the cause.
    let mut w = LogWriter::create(&a.out, &meta, 0)?;
    // Merge by time: truth, IMU, TDOA (or ranges) at equal times.
    let mut recs: Vec<(u64, u8, Record)> =
        Vec::with_capacity(d.imu.len() + d.tdoa.len() + d.range.len() + d.truth.len());
    recs.extend(
        d.truth
            .iter()
            .map(|s| (s.header.meas_time_ns, 0, Record::Truth(*s))),
    );
    recs.extend(
        d.imu
            .iter()
            .map(|s| (s.header.meas_time_ns, 1, Record::Imu(*s))),
    );
    recs.extend(
        d.tdoa
            .iter()
            .map(|s| (s.header.meas_time_ns, 2, Record::Tdoa(*s))),
    );
    recs.extend(
        d.range
            .iter()
            .map(|s| (s.header.meas_time_ns, 2, Record::Range(*s))),
    );
    // The flow deck's velocities, if the log carries them: what the
    // vehicle measured, used when a replay or eval asks for the aiding.
    recs.extend(
        loaded
            .velocity
            .iter()
            .map(|s| (s.header.meas_time_ns, 3, Record::BodyVel(*s))),
    );
    // And its range finder's heights.
    recs.extend(
        loaded
            .height
            .iter()
            .map(|s| (s.header.meas_time_ns, 4, Record::Height(*s))),
    );
    recs.sort_by_key(|r| (r.0, r.1));
    for (_, _, r) in &recs {
        w.append(r)?;
    }
    w.finish()?;
    eprintln!("wrote {} records to {}", recs.len(), a.out.display());
    Ok(())
}
