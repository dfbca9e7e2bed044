//! Loading a dataset from a file: a project log (a file or a folder of
//! segments) or a UTIL Crazyflie log (detected from the content), with the
//! fusion settings that go with it.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use insuwb_data::cflog::Integrity;
use insuwb_eval::run::Dataset;
use insuwb_fusion::config::FusionConfig;
use insuwb_log::Record;
use serde::{Deserialize, Serialize};

/// Metadata key under which a log carries the fusion settings it was made with.
pub const META_FUSION_CONFIG: &str = "fusion_config";

/// Options of an evaluation, from a config file's `[eval]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalOptions {
    /// Evaluate from the first to the last instant the ground-truth height
    /// exceeds this (m); 0 evaluates everything (real flights: 0.3 m, the
    /// UTIL README's flight segment).
    pub min_height_m: f64,
    /// Filters run when the command line names none (kf, shaf, stf, iakf, iakf_tdoa).
    pub filters: Vec<insuwb_msg::FilterKind>,
    /// Where the solutions are evaluated: `fixes` (the UWB fix epochs, the
    /// paper's Table 1) or `truth` (the ground-truth sample times, each
    /// solution interpolated there, as the UTIL references are measured).
    pub epochs: insuwb_eval::run::Epochs,
    /// Which part of a log is evaluated: `flight` (ground truth above
    /// `min_height_m`; a log that never rises above it is an error) or
    /// `all` (a vehicle that stays on the floor). A manifest's `segment`
    /// column and `insuwb eval --segment` override it.
    pub segment: insuwb_eval::run::Segment,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            min_height_m: 0.0,
            filters: crate::eval_cmd::DEFAULT_FILTERS.to_vec(),
            epochs: insuwb_eval::run::Epochs::Fixes,
            segment: insuwb_eval::run::Segment::Flight,
        }
    }
}

/// A config file for `eval`, `import` and the stages: `[fusion]`, `[import]`, `[eval]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ConfigFile {
    /// Fusion settings.
    pub fusion: FusionConfig,
    /// UTIL import options.
    pub import: insuwb_data::util::ImportOptions,
    /// Evaluation options.
    pub eval: EvalOptions,
    /// The optical-flow deck's model (a UTIL log's `estFlow` and `estTOF`
    /// records to body velocities, `--aiding flow`).
    pub flow: insuwb_data::FlowDeck,
}

impl ConfigFile {
    /// Loads a config file, or the built-in preset of that name.
    pub fn load(name_or_path: &str) -> Result<Self> {
        let p = Path::new(name_or_path);
        if p.exists() || p.extension().is_some_and(|e| e == "toml") {
            Ok(insuwb_config::load_file(p)?)
        } else {
            let b = insuwb_config::builtin("preset", name_or_path)?;
            Ok(insuwb_config::load_str(b.text, b.origin)?)
        }
    }
}

/// What kind of file a path holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    /// The project's log format.
    ProjectLog,
    /// A Crazyflie micro-SD event log (UTIL dataset).
    CfLog,
}

/// Reads at most `limit` bytes of `path`, with an error naming the file.
fn read_limited(path: &Path, limit: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let f =
        std::fs::File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let mut buf = Vec::new();
    f.take(limit)
        .read_to_end(&mut buf)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    Ok(buf)
}

/// Detects the kind of `path` from its first bytes.
pub fn detect(path: &Path) -> Result<FileKind> {
    let head = read_limited(path, 4096)?;
    if head.is_empty() {
        bail!("{}: the file is empty", path.display());
    }
    if insuwb_log::is_log(&head) {
        return Ok(FileKind::ProjectLog);
    }
    if insuwb_data::cflog::is_cflog(&head) {
        return Ok(FileKind::CfLog);
    }
    bail!(
        "{}: not an insuwb log nor a Crazyflie event log (first bytes: {:02x?})",
        path.display(),
        &head[..head.len().min(8)]
    )
}

/// Which velocity measurements aid the filters (`insuwb eval --aiding`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Aiding {
    /// None: IMU and UWB alone.
    #[default]
    None,
    /// The optical-flow deck's body velocities and its range finder's
    /// heights (a UTIL log's `estFlow` with its `estTOF` ranges; a
    /// scenario's `[sim.flow]`).
    Flow,
    /// Wheel odometry (a scenario's `[sim.odometry]`).
    Odometry,
}

impl Aiding {
    /// The body-velocity sources it takes from a scenario's simulation.
    #[must_use]
    pub fn scenario_sources(self) -> Vec<u32> {
        match self {
            Self::None => Vec::new(),
            Self::Flow => vec![insuwb_msg::BodyVelocity::SOURCE_FLOW],
            Self::Odometry => vec![insuwb_msg::BodyVelocity::SOURCE_ODOMETRY],
        }
    }
}

/// A log holds none of the velocity measurements `--aiding` asked for: a
/// single log stops with it; a manifest (`insuwb eval --flights`,
/// `insuwb calibrate --cross-validate`) leaves the flight out and names it.
#[derive(Debug, thiserror::Error)]
#[error("{}: no optical-flow velocities (a UTIL log's estFlow records, a project log's body_vel records of a flow source): --aiding flow needs a log of a vehicle with a flow deck", path.display())]
pub struct NoFlowRecords {
    /// The log.
    pub path: PathBuf,
}

impl NoFlowRecords {
    /// Whether `e`, or an error it wraps, is this one.
    #[must_use]
    pub fn is_cause_of(e: &anyhow::Error) -> bool {
        e.chain().any(|c| c.is::<Self>())
    }
}

/// What a run overrides of a log's settings (`insuwb eval --vehicle
/// --aiding`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RunChoice {
    /// The vehicle model instead of the config's.
    pub vehicle: Option<insuwb_nav::vehicle::VehicleKind>,
    /// The velocity aiding.
    pub aiding: Aiding,
    /// The part of the log evaluated instead of the config's.
    pub segment: Option<insuwb_eval::run::Segment>,
}

impl Loaded {
    /// Chooses the part of the log evaluated: `choice`, else the config's
    /// `[eval] segment`; logs which one. A flight segment of a log whose
    /// ground truth never rises above the height is an error that says
    /// how to evaluate the whole log instead.
    ///
    /// # Errors
    /// No flight segment where one is asked for (naming the file).
    pub fn choose_segment(
        &mut self,
        choice: Option<insuwb_eval::run::Segment>,
        path: &Path,
    ) -> Result<()> {
        use insuwb_eval::run::Segment;
        let span_s = |d: &Dataset| {
            d.imu
                .last()
                .map_or(0.0, |s| s.header.meas_time_ns as f64 * 1e-9)
        };
        match choice.unwrap_or(self.config.eval.segment) {
            Segment::All => {
                self.data.segment = None;
                self.segment_note = format!("the whole log, {:.1} s", span_s(&self.data));
            }
            Segment::Flight => match (self.flight_min_height_m, self.data.segment) {
                (Some(h), Some((a, b))) => {
                    self.segment_note = format!(
                        "the flight, {:.1}-{:.1} s (ground truth above {h} m)",
                        a as f64 * 1e-9,
                        b as f64 * 1e-9
                    );
                }
                (Some(h), None) => bail!(
                    "{}: the ground truth never rises above {h} m: the vehicle does not fly. \
                     Evaluate the whole log with --segment all, `[eval] segment = \"all\"` \
                     in the config, or a manifest column `segment` of `all`",
                    path.display()
                ),
                (None, _) => {
                    self.segment_note = format!("the whole log, {:.1} s", span_s(&self.data));
                }
            },
        }
        tracing::info!("{}: evaluating {}", path.display(), self.segment_note);
        Ok(())
    }

    /// Puts the velocities `aiding` names (and the flow deck's heights
    /// with its flow) into the dataset.
    ///
    /// # Errors
    /// The log holds no such records (naming the file).
    pub fn use_aiding(&mut self, aiding: Aiding, path: &Path) -> Result<()> {
        match aiding {
            Aiding::None => {
                self.data.velocity.clear();
                self.data.height.clear();
            }
            Aiding::Odometry => bail!(
                "{}: --aiding odometry is for a simulated scenario's wheel odometry (--scenario with [sim.odometry]); a log holds none",
                path.display()
            ),
            Aiding::Flow => {
                let flow: Vec<insuwb_msg::BodyVelocity> = self
                    .velocity
                    .iter()
                    .filter(|v| v.source == insuwb_msg::BodyVelocity::SOURCE_FLOW)
                    .copied()
                    .collect();
                if flow.is_empty() {
                    return Err(NoFlowRecords {
                        path: path.to_path_buf(),
                    }
                    .into());
                }
                self.data.velocity = flow;
                self.data.height.clone_from(&self.height);
                if let Some(h) = &self.height_stats {
                    tracing::info!(
                        "{}: {} heights from {} range records; refused: {} range below {} m, {} above {} m, {} time backwards",
                        path.display(),
                        h.heights,
                        h.records,
                        h.range_low,
                        self.config.flow.min_range_m,
                        h.range_high,
                        self.config.flow.max_range_m,
                        h.time_backwards
                    );
                }
                let Some(stats) = &self.flow_stats else {
                    return Ok(());
                };
                tracing::info!(
                    "{}: {} flow velocities from {} flow records; refused: {} no range, {} range below {} m, {} above {} m, {} no body rates, {} time backwards",
                    path.display(),
                    stats.velocities,
                    stats.records,
                    stats.no_range,
                    stats.range_low,
                    self.config.flow.min_range_m,
                    stats.range_high,
                    self.config.flow.max_range_m,
                    stats.no_gyro,
                    stats.time_backwards
                );
            }
        }
        Ok(())
    }
}

/// A dataset with the config it should be evaluated with.
#[derive(Debug)]
pub struct Loaded {
    /// The data.
    pub data: Dataset,
    /// The fused states of a project log that holds no IMU or TDOA
    /// records (a fleet station's recording of a robot): its recorded
    /// track is what there is to evaluate. Empty otherwise.
    pub recorded: Vec<insuwb_msg::FusedState>,
    /// The settings (from `--config`, the log's metadata, or the preset of its format).
    pub config: ConfigFile,
    /// Where the config came from, for messages.
    pub config_origin: String,
    /// The log's body velocities (a project log's `body_vel` records, or
    /// a UTIL log's flow deck through [`insuwb_data::flow`]): what
    /// `--aiding` chooses from.
    pub velocity: Vec<insuwb_msg::BodyVelocity>,
    /// What a UTIL log's flow records gave (None: no flow records, or a
    /// project log).
    pub flow_stats: Option<insuwb_data::FlowStats>,
    /// The log's heights (a project log's `height` records, or a UTIL
    /// log's range finder through [`insuwb_data::range_heights`]): they
    /// aid with the flow (`--aiding flow`).
    pub height: Vec<insuwb_msg::Height>,
    /// What a UTIL log's range records gave (None: no flow records, or a
    /// project log).
    pub height_stats: Option<insuwb_data::HeightStats>,
    /// The height the flight segment is cut at, m (`None`: the whole log,
    /// a log without flight phases).
    pub flight_min_height_m: Option<f64>,
    /// Which part of the log is evaluated, in words ([`Loaded::choose_segment`]).
    pub segment_note: String,
}

/// Loads a project log (a file, or a folder of `seg-*.iulog` segments as
/// the logger and `insuwb fleet record` write) or a UTIL log.
pub fn load(
    path: &Path,
    anchors: Option<&PathBuf>,
    config: Option<&str>,
    ignore_crc: bool,
) -> Result<Loaded> {
    if path.is_dir() {
        return load_project_log(path, config);
    }
    match detect(path)? {
        FileKind::ProjectLog => load_project_log(path, config),
        FileKind::CfLog => load_util(path, anchors, config, ignore_crc),
    }
}

/// The records and metadata of a project log file, or of a folder of
/// segments (the first segment's metadata); a damaged tail is warned about.
fn read_project_log(path: &Path) -> Result<(Vec<Record>, insuwb_log::Metadata)> {
    if path.is_dir() {
        // The errors name the folder or segment and the cause.
        let read = insuwb_log::read_segments(path)?;
        for (seg, t) in read.tails() {
            tracing::warn!("{}: {t}; using the records before it", seg.display());
        }
        let Some(meta) = read
            .segments
            .iter()
            .find_map(|s| s.header.as_ref().map(|h| h.meta.clone()))
        else {
            bail!(
                "{}: no seg-*.iulog segment with a header in this folder",
                path.display()
            );
        };
        return Ok((read.records, meta));
    }
    // The error names the file and its cause.
    let (records, tail, header) = insuwb_log::read_all(path)?;
    if let Some(t) = tail {
        tracing::warn!(
            "{}: {t}; using the {} records before it",
            path.display(),
            records.len()
        );
    }
    Ok((records, header.meta))
}

fn load_project_log(path: &Path, config: Option<&str>) -> Result<Loaded> {
    let (records, meta) = read_project_log(path)?;
    let mut data = Dataset {
        name: path.display().to_string(),
        ..Dataset::default()
    };
    let mut recorded = Vec::new();
    let mut velocity = Vec::new();
    let mut height = Vec::new();
    for r in records {
        match r {
            Record::BodyVel(s) => velocity.push(s),
            Record::Height(s) => height.push(s),
            Record::Imu(s) => data.imu.push(s),
            Record::Tdoa(s) => data.tdoa.push(s),
            Record::Range(s) => data.range.push(s),
            Record::Truth(s) => data.truth.push(s),
            Record::Fused(s) => recorded.push(s),
            _ => {}
        }
    }
    let sensors = !(data.imu.is_empty() || (data.tdoa.is_empty() && data.range.is_empty()));
    if !sensors && recorded.is_empty() {
        bail!(
            "{}: the log holds {} IMU, {} TDOA, {} range and no fused records: nothing to evaluate",
            path.display(),
            data.imu.len(),
            data.tdoa.len(),
            data.range.len()
        );
    }
    if sensors {
        recorded.clear();
    }
    sort_streams(&mut data);
    let (config, origin) = match config {
        Some(c) => (ConfigFile::load(c)?, c.to_owned()),
        None => match meta.entries.get(META_FUSION_CONFIG) {
            Some(text) => (
                insuwb_config::load_str::<ConfigFile>(
                    text,
                    &format!("{} (metadata)", path.display()),
                )?,
                format!("{} (metadata)", path.display()),
            ),
            None => (ConfigFile::default(), "built-in defaults".to_owned()),
        },
    };
    let flight_min_height_m = (config.eval.min_height_m > 0.0).then_some(config.eval.min_height_m);
    if let Some(h) = flight_min_height_m {
        data.segment = insuwb_data::segment::flight_segment(&data.truth, h);
    }
    Ok(Loaded {
        data,
        recorded,
        config,
        config_origin: origin,
        velocity,
        flow_stats: None,
        height,
        height_stats: None,
        flight_min_height_m,
        segment_note: String::new(),
    })
}

fn sort_streams(d: &mut Dataset) {
    d.imu.sort_by_key(|s| s.header.meas_time_ns);
    d.tdoa.sort_by_key(|s| s.header.meas_time_ns);
    d.range.sort_by_key(|s| s.header.meas_time_ns);
    d.truth.sort_by_key(|s| s.header.meas_time_ns);
}

fn load_util(
    path: &Path,
    anchors: Option<&PathBuf>,
    config: Option<&str>,
    ignore_crc: bool,
) -> Result<Loaded> {
    let anchors = anchors.with_context(|| {
        format!(
            "{}: a Crazyflie log needs --anchors FILE (the anchor survey, anN_p,x,y,z rows)",
            path.display()
        )
    })?;
    let (config, origin) = match config {
        Some(c) => (ConfigFile::load(c)?, c.to_owned()),
        None => (ConfigFile::load("util")?, "built-in preset util".to_owned()),
    };
    let flight = insuwb_data::util::load_util_flight(
        path,
        anchors,
        &insuwb_data::cflog::ParseOptions { ignore_crc },
        &config.import,
    )?;
    let s = &flight.stats;
    match &flight.integrity {
        Integrity::CrcOk => {}
        Integrity::CrcMismatch { stored, computed } => tracing::warn!(
            "{}: CRC mismatch: stored {stored:#010x}, computed {computed:#010x}; \
             reading its {} records anyway (--ignore-crc)",
            path.display(),
            s.records
        ),
        Integrity::Cut(cut) => tracing::warn!(
            "{}: {cut}; using the {} records before it",
            path.display(),
            s.records
        ),
    }
    tracing::info!(
        "{}: {} IMU, {} TDOA, {} range, {} truth samples; skipped: {} unknown-anchor UWB, {} backwards, {} non-finite",
        path.display(),
        flight.imu.len(),
        flight.tdoa.len(),
        flight.twr.len(),
        flight.truth.len(),
        s.unknown_anchor,
        s.time_backwards,
        s.non_finite
    );
    let min_h = if config.eval.min_height_m > 0.0 {
        config.eval.min_height_m
    } else {
        insuwb_data::segment::DEFAULT_MIN_HEIGHT_M
    };
    let segment = insuwb_data::segment::flight_segment(&flight.truth, min_h);
    config
        .flow
        .validate()
        .with_context(|| format!("{origin}: [flow]"))?;
    let (velocity, flow_stats, height, height_stats) = if flight.flow.is_empty() {
        (Vec::new(), None, Vec::new(), None)
    } else {
        let (v, stats) =
            insuwb_data::flow_velocities(&flight.flow, &flight.ranges, &flight.imu, &config.flow);
        let (h, hstats) = insuwb_data::range_heights(&flight.ranges, &config.flow);
        (v, Some(stats), h, Some(hstats))
    };
    let mut data = Dataset {
        name: path.display().to_string(),
        imu: flight.imu,
        tdoa: flight.tdoa,
        range: flight.twr,
        truth: flight.truth,
        velocity: Vec::new(),
        height: Vec::new(),
        segment,
    };
    sort_streams(&mut data);
    Ok(Loaded {
        data,
        recorded: Vec::new(),
        config,
        config_origin: origin,
        velocity,
        flow_stats,
        height,
        height_stats,
        flight_min_height_m: Some(min_h),
        segment_note: String::new(),
    })
}
