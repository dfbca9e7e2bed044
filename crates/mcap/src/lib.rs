//! MCAP export of insuwb logs (`insuwb log export LOG --mcap OUT.mcap`):
//! every record of a log file or of a run directory of segments becomes a
//! ROS 2 CDR message with its `ros2msg` schema, in an MCAP file of profile
//! `ros2`, so a recording opens in Foxglove and converts with the ROS 2
//! tools (rosbag2, `rosbags`), every channel decodable.
//!
//! - The ROS types are those of the ROS 2 bridge, built by the same
//!   conversions ([`insuwb_ros2::convert`]): `fused` becomes
//!   `nav_msgs/msg/Odometry` and `tf2_msgs/msg/TFMessage`, `imu`
//!   `sensor_msgs/msg/Imu`, `health` `diagnostic_msgs/msg/DiagnosticArray`.
//! - Every other topic, and the whole fused state, is a message of the
//!   package `insuwb_msgs` ([`msgs`]).
//! - [`cdr`]: the encoding (encapsulation header `00 01 00 00`, then plain
//!   little-endian CDR), `insuwb_ros2::cdr`.
//! - [`RecordWriter`] turns records into messages on any `Write + Seek`;
//!   [`export_log`] reads a log (a file, or a run directory's segments in
//!   order) into an MCAP file and reports where a cut log stopped
//!   ([`Cut`]).
//!
//! The topic and type table, the times and the stamps follow (the text
//! of `docs/MCAP_EXPORT.md`).
//!
//! ```
//! use insuwb_log::Record;
//! use insuwb_mcap::{ExportOptions, RecordWriter};
//! use insuwb_msg::{FusedState, Header};
//! let mut w = RecordWriter::new(std::io::Cursor::new(Vec::new()), ExportOptions::default())?;
//! let fused = FusedState { header: Header::new(0, 2_000_000_000), quat: [1.0, 0.0, 0.0, 0.0], ..Default::default() };
//! w.write(&Record::Fused(fused))?;
//! let (out, stats) = w.finish()?;
//! assert_eq!(stats.messages["/insuwb/odom"], 1);
//! assert_eq!(stats.messages["/tf"], 1);
//! assert!(out.into_inner().starts_with(b"\x89MCAP0\r\n"));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
#![doc = include_str!("../../../docs/MCAP_EXPORT.md")]
#![deny(missing_docs)]

pub use insuwb_ros2::cdr;
pub mod msgs;

use std::collections::BTreeMap;
use std::fmt;
use std::fs::File;
use std::io::{self, BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use insuwb_log::{
    HeaderError, LogReader, OpenError, ReadError, ReadSegmentsError, Record, TailReason, TailReport,
};
use insuwb_msg::{name_str, topics, StageRole};
use insuwb_report::clock::ClockOffset;
use insuwb_report::health::StageSeen;
use insuwb_ros2::convert::{self, ConvertError, Frames, RosStamp};
use insuwb_ros2::msgs::{DiagnosticArray, Header, RosMessage, TfMessage, Time};

/// MCAP topic of `fused` as `nav_msgs/msg/Odometry`.
pub const TOPIC_ODOM: &str = "/insuwb/odom";
/// MCAP topic of `fused` as `tf2_msgs/msg/TFMessage`.
pub const TOPIC_TF: &str = "/tf";
/// MCAP topic of `fused` as `insuwb_msgs/msg/FusedState`.
pub const TOPIC_FUSED: &str = "/insuwb/fused";
/// MCAP topic of `imu` as `sensor_msgs/msg/Imu`.
pub const TOPIC_IMU: &str = "/insuwb/imu";
/// MCAP topic of `health` as `diagnostic_msgs/msg/DiagnosticArray`.
pub const TOPIC_DIAGNOSTICS: &str = "/diagnostics";
/// MCAP topic of `uwb_tdoa` as `insuwb_msgs/msg/UwbTdoa`.
pub const TOPIC_UWB_TDOA: &str = "/insuwb/uwb_tdoa";
/// MCAP topic of `uwb_range` as `insuwb_msgs/msg/UwbRange`.
pub const TOPIC_UWB_RANGE: &str = "/insuwb/uwb_range";
/// MCAP topic of `uwb_fix` as `insuwb_msgs/msg/UwbFix`.
pub const TOPIC_UWB_FIX: &str = "/insuwb/uwb_fix";
/// MCAP topic of `nav` as `insuwb_msgs/msg/NavState`.
pub const TOPIC_NAV: &str = "/insuwb/nav";
/// MCAP topic of `correction` as `insuwb_msgs/msg/InsCorrection`.
pub const TOPIC_CORRECTION: &str = "/insuwb/correction";
/// MCAP topic of `diag` as `insuwb_msgs/msg/FilterDiag`.
pub const TOPIC_DIAG: &str = "/insuwb/diag";
/// MCAP topic of `truth` as `insuwb_msgs/msg/GroundTruth`.
pub const TOPIC_TRUTH: &str = "/insuwb/truth";
/// MCAP topic of `body_vel` as `insuwb_msgs/msg/BodyVelocity`.
pub const TOPIC_BODY_VEL: &str = "/insuwb/body_vel";
/// MCAP topic of `height` as `insuwb_msgs/msg/Height`.
pub const TOPIC_HEIGHT: &str = "/insuwb/height";

/// The MCAP topics each insuwb topic is written to: one message on each
/// per record (a record a ROS conversion refuses is counted in
/// [`ExportStats::skipped`] instead).
#[must_use]
pub fn mcap_topics(insuwb_topic: &str) -> &'static [&'static str] {
    match insuwb_topic {
        topics::IMU => &[TOPIC_IMU],
        topics::UWB_TDOA => &[TOPIC_UWB_TDOA],
        topics::UWB_RANGE => &[TOPIC_UWB_RANGE],
        topics::UWB_FIX => &[TOPIC_UWB_FIX],
        topics::NAV => &[TOPIC_NAV],
        topics::CORRECTION => &[TOPIC_CORRECTION],
        topics::FUSED => &[TOPIC_ODOM, TOPIC_TF, TOPIC_FUSED],
        topics::DIAG => &[TOPIC_DIAG],
        topics::TRUTH => &[TOPIC_TRUTH],
        topics::HEALTH => &[TOPIC_DIAGNOSTICS],
        topics::BODY_VEL => &[TOPIC_BODY_VEL],
        topics::HEIGHT => &[TOPIC_HEIGHT],
        _ => &[],
    }
}

/// The MCAP profile of an export.
pub const PROFILE: &str = "ros2";
/// The schema encoding of every channel.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// The message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "cdr";
/// Name of the MCAP metadata record holding the log's header.
pub const METADATA_NAME: &str = "insuwb_log";

/// What an export writes besides the records.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExportOptions {
    /// Frame ids (defaults `map`, `base_link`, `base_link`, as the bridge's
    /// `[ros2]` defaults); the `insuwb_msgs` messages with positions use
    /// `frame_id` too, the body velocities and heights `child_frame_id`.
    pub frames: Frames,
    /// `hardware_id` of the diagnostics (default `insuwb`).
    pub hardware_id: String,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self {
            frames: Frames::default(),
            hardware_id: "insuwb".into(),
        }
    }
}

/// Counts of an export.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ExportStats {
    /// Records read, by insuwb topic.
    pub records: BTreeMap<&'static str, u64>,
    /// Messages written, by MCAP topic.
    pub messages: BTreeMap<&'static str, u64>,
    /// Messages not written because a conversion refused the record, by
    /// MCAP topic.
    pub skipped: BTreeMap<&'static str, u64>,
    /// Why the first message was skipped.
    pub first_skip: Option<String>,
}

impl ExportStats {
    /// Records read in all.
    #[must_use]
    pub fn total_records(&self) -> u64 {
        self.records.values().sum()
    }

    /// Messages written in all.
    #[must_use]
    pub fn total_messages(&self) -> u64 {
        self.messages.values().sum()
    }
}

/// Error starting an MCAP file ([`RecordWriter::new`]).
#[derive(Debug, thiserror::Error)]
#[error("cannot start the MCAP file: {0}")]
pub struct StartError(pub mcap::McapError);

/// Error writing a record or metadata ([`RecordWriter::write`]).
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// A message did not encode.
    #[error("{0}")]
    Encode(cdr::EncodeError),
    /// The MCAP writer failed (I/O, too many channels).
    #[error("cannot write to MCAP topic {topic}: {error}")]
    Mcap {
        /// The MCAP topic (or metadata record) being written.
        topic: String,
        /// The writer's error.
        error: mcap::McapError,
    },
}

/// Error ending an MCAP file ([`RecordWriter::finish`]).
#[derive(Debug, thiserror::Error)]
#[error("cannot finish the MCAP file (summary, footer): {0}")]
pub struct FinishError(pub mcap::McapError);

/// Turns insuwb records into ROS 2 messages of an MCAP file: a channel per
/// MCAP topic, created with its schema at its first message.
pub struct RecordWriter<W: Write + Seek> {
    writer: mcap::Writer<W>,
    options: ExportOptions,
    schemas: BTreeMap<String, u16>,
    channels: BTreeMap<&'static str, (u16, u32)>,
    stats: ExportStats,
    stages: Vec<(String, StageSeen)>,
    coasting: bool,
}

impl<W: Write + Seek> fmt::Debug for RecordWriter<W> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RecordWriter")
            .field("options", &self.options)
            .field("channels", &self.channels)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

/// The MCAP publish time of a sample: its `pub_time_ns`, or its
/// `meas_time_ns` when it was never published (0, e.g. `insuwb sim` logs).
fn publish_time(h: &insuwb_msg::Header) -> u64 {
    if h.pub_time_ns == 0 {
        h.meas_time_ns
    } else {
        h.pub_time_ns
    }
}

impl<W: Write + Seek> RecordWriter<W> {
    /// Starts an MCAP file of profile `ros2` on `w` (uncompressed chunks).
    ///
    /// # Errors
    /// [`StartError`] when the header cannot be written.
    pub fn new(w: W, options: ExportOptions) -> Result<Self, StartError> {
        let opts = mcap::WriteOptions::new()
            .profile(PROFILE)
            .compression(None)
            .library(concat!("insuwb-mcap ", env!("CARGO_PKG_VERSION")));
        let writer = mcap::Writer::with_options(w, opts).map_err(StartError)?;
        Ok(Self {
            writer,
            options,
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            stats: ExportStats::default(),
            stages: Vec::new(),
            coasting: false,
        })
    }

    /// Writes an MCAP metadata record.
    ///
    /// # Errors
    /// [`WriteError::Mcap`] when the writer fails.
    pub fn write_metadata(
        &mut self,
        name: &str,
        entries: BTreeMap<String, String>,
    ) -> Result<(), WriteError> {
        self.writer
            .write_metadata(&mcap::records::Metadata {
                name: name.to_owned(),
                metadata: entries,
            })
            .map_err(|error| WriteError::Mcap {
                topic: format!("metadata {name}"),
                error,
            })
    }

    /// The counts so far.
    #[must_use]
    pub fn stats(&self) -> &ExportStats {
        &self.stats
    }

    fn skip(&mut self, topic: &'static str, why: &ConvertError, seq: u64) {
        *self.stats.skipped.entry(topic).or_default() += 1;
        if self.stats.first_skip.is_none() {
            self.stats.first_skip = Some(format!("{topic}: sample seq {seq}: {why}"));
        }
    }

    fn channel<M: RosMessage>(&mut self, topic: &'static str) -> Result<u16, WriteError> {
        if let Some((id, _)) = self.channels.get(topic) {
            return Ok(*id);
        }
        let mcap_err = |error| WriteError::Mcap {
            topic: topic.to_owned(),
            error,
        };
        let name = M::type_name();
        let schema = match self.schemas.get(&name) {
            Some(id) => *id,
            None => {
                let id = self
                    .writer
                    .add_schema(&name, SCHEMA_ENCODING, M::schema().as_bytes())
                    .map_err(mcap_err)?;
                self.schemas.insert(name, id);
                id
            }
        };
        let id = self
            .writer
            .add_channel(schema, topic, MESSAGE_ENCODING, &BTreeMap::new())
            .map_err(mcap_err)?;
        self.channels.insert(topic, (id, 0));
        Ok(id)
    }

    fn put<M: RosMessage>(
        &mut self,
        topic: &'static str,
        msg: &M,
        h: &insuwb_msg::Header,
    ) -> Result<(), WriteError> {
        let data = cdr::encode(msg, &M::type_name()).map_err(WriteError::Encode)?;
        let channel_id = self.channel::<M>(topic)?;
        let sequence = self.channels.get_mut(topic).map_or(0, |(_, seq)| {
            let s = *seq;
            *seq = seq.wrapping_add(1);
            s
        });
        self.writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence,
                    log_time: h.meas_time_ns,
                    publish_time: publish_time(h),
                },
                &data,
            )
            .map_err(|error| WriteError::Mcap {
                topic: topic.to_owned(),
                error,
            })?;
        *self.stats.messages.entry(topic).or_default() += 1;
        Ok(())
    }

    /// Writes the messages of one record (see [`mcap_topics`]).
    ///
    /// # Errors
    /// [`WriteError`] when a message does not encode or the writer fails.
    pub fn write(&mut self, rec: &Record) -> Result<(), WriteError> {
        *self.stats.records.entry(rec.topic()).or_default() += 1;
        let h = *rec.header();
        let stamp: Time = match ClockOffset::ZERO.stamp(h.meas_time_ns) {
            Ok(t) => t,
            Err(e) => {
                for t in mcap_topics(rec.topic()) {
                    self.skip(t, &e, h.seq);
                }
                return Ok(());
            }
        };
        let frames = self.options.frames.clone();
        let frame = frames.frame_id.as_str();
        let clock = &ClockOffset::ZERO;
        match rec {
            Record::Imu(s) => match convert::imu_to_ros(s, &frames, clock) {
                Ok(m) => self.put(TOPIC_IMU, &m, &h)?,
                Err(e) => self.skip(TOPIC_IMU, &e, h.seq),
            },
            Record::Fused(s) => {
                use insuwb_msg::FusedState as F;
                self.coasting = s.header.flags & (F::FLAG_DEGRADED | F::FLAG_STALE) != 0;
                match convert::fused_to_odometry(s, &frames, clock) {
                    Ok(m) => self.put(TOPIC_ODOM, &m, &h)?,
                    Err(e) => self.skip(TOPIC_ODOM, &e, h.seq),
                }
                match convert::fused_to_transform(s, &frames, clock) {
                    Ok(t) => self.put(
                        TOPIC_TF,
                        &TfMessage {
                            transforms: vec![t],
                        },
                        &h,
                    )?,
                    Err(e) => self.skip(TOPIC_TF, &e, h.seq),
                }
                self.put(
                    TOPIC_FUSED,
                    &msgs::FusedState::from_sample(s, stamp, frame),
                    &h,
                )?;
            }
            Record::Health(s) => {
                let name = name_str(&s.stage);
                let at = h.meas_time_ns;
                let seen = match self.stages.iter_mut().find(|(n, _)| *n == name) {
                    Some((_, seen)) => {
                        seen.note(*s, at);
                        *seen
                    }
                    None => {
                        let seen = StageSeen::new(*s, at);
                        self.stages.push((name.clone(), seen));
                        seen
                    }
                };
                let coasting = self.coasting && name == StageRole::Fusion.name();
                let status = convert::stage_status(
                    &name,
                    &self.options.hardware_id,
                    Some(&seen),
                    coasting,
                    at,
                    u64::MAX,
                );
                let m = DiagnosticArray {
                    header: Header {
                        stamp,
                        frame_id: String::new(),
                    },
                    status: vec![status],
                };
                self.put(TOPIC_DIAGNOSTICS, &m, &h)?;
            }
            Record::Tdoa(s) => self.put(
                TOPIC_UWB_TDOA,
                &msgs::UwbTdoa::from_sample(s, stamp, frame),
                &h,
            )?,
            Record::Range(s) => self.put(
                TOPIC_UWB_RANGE,
                &msgs::UwbRange::from_sample(s, stamp, frame),
                &h,
            )?,
            Record::Fix(s) => self.put(
                TOPIC_UWB_FIX,
                &msgs::UwbFix::from_sample(s, stamp, frame),
                &h,
            )?,
            Record::Nav(s) => {
                self.put(TOPIC_NAV, &msgs::NavState::from_sample(s, stamp, frame), &h)?;
            }
            Record::Correction(s) => self.put(
                TOPIC_CORRECTION,
                &msgs::InsCorrection::from_sample(s, stamp, frame),
                &h,
            )?,
            Record::Diag(s) => {
                self.put(TOPIC_DIAG, &msgs::FilterDiag::from_sample(s, stamp), &h)?;
            }
            Record::Truth(s) => self.put(
                TOPIC_TRUTH,
                &msgs::GroundTruth::from_sample(s, stamp, frame),
                &h,
            )?,
            Record::BodyVel(s) => self.put(
                TOPIC_BODY_VEL,
                &msgs::BodyVelocity::from_sample(s, stamp, &frames.child_frame_id),
                &h,
            )?,
            Record::Height(s) => self.put(
                TOPIC_HEIGHT,
                &msgs::Height::from_sample(s, stamp, &frames.child_frame_id),
                &h,
            )?,
        }
        Ok(())
    }

    /// Ends the file (summary section with statistics and indexes, footer)
    /// and returns the sink and the counts.
    ///
    /// # Errors
    /// [`FinishError`] when the writer fails.
    pub fn finish(mut self) -> Result<(W, ExportStats), FinishError> {
        self.writer.finish().map_err(FinishError)?;
        Ok((self.writer.into_inner(), self.stats))
    }
}

/// Where a cut (or damaged) log file stopped: its records before that
/// point are exported, nothing after it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Cut {
    /// The file.
    pub path: PathBuf,
    /// Its whole records, all exported.
    pub records: u64,
    /// Where and why reading stopped (`insuwb-log`'s report).
    pub report: TailReport,
}

impl fmt::Display for Cut {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {}; exported its {} whole records before byte {}",
            self.path.display(),
            self.report,
            self.records,
            self.report.last_good_offset
        )
    }
}

/// What [`export_log`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExportSummary {
    /// The log files read, in order.
    pub files: Vec<PathBuf>,
    /// The files that ended cut or damaged.
    pub cuts: Vec<Cut>,
    /// The counts.
    pub stats: ExportStats,
}

/// Error finding or reading the input log.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// The run directory cannot be listed.
    #[error("{0}")]
    List(ReadSegmentsError),
    /// A directory without any segment.
    #[error("{}: no seg-*.iulog segment in this directory", dir.display())]
    NoSegments {
        /// The directory.
        dir: PathBuf,
    },
    /// A file is missing, unreadable or not a log (the message names it).
    #[error("{0}")]
    Open(OpenError),
    /// Reading a record failed (I/O).
    #[error("{}: {error}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The read error.
        error: ReadError,
    },
}

/// Error exporting a log ([`export_log`]).
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The input log.
    #[error("{0}")]
    Input(InputError),
    /// The output file cannot be created.
    #[error("cannot create {}: {error}", path.display())]
    Create {
        /// The output path.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// Starting the output.
    #[error("{}: {error}", path.display())]
    Start {
        /// The output path.
        path: PathBuf,
        /// The error.
        error: StartError,
    },
    /// Writing the output.
    #[error("{}: {error}", path.display())]
    Write {
        /// The output path.
        path: PathBuf,
        /// The error.
        error: WriteError,
    },
    /// Ending the output.
    #[error("{}: {error}", path.display())]
    Finish {
        /// The output path.
        path: PathBuf,
        /// The error.
        error: FinishError,
    },
    /// Flushing the output to its file.
    #[error("cannot write {}: {error}", path.display())]
    Flush {
        /// The output path.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
}

/// The log files of `path`: the file itself, or the segments of a run
/// directory in index order (as `insuwb log info` reads them).
///
/// # Errors
/// [`InputError::List`] when the directory cannot be read,
/// [`InputError::NoSegments`] when it holds no segment.
pub fn log_files(path: &Path) -> Result<Vec<PathBuf>, InputError> {
    if path.is_dir() {
        let segs = insuwb_log::list_segments(path).map_err(InputError::List)?;
        if segs.is_empty() {
            return Err(InputError::NoSegments {
                dir: path.to_path_buf(),
            });
        }
        Ok(segs.into_iter().map(|s| s.path).collect())
    } else {
        Ok(vec![path.to_path_buf()])
    }
}

/// A segment that ends inside its header (a logger killed as it opened
/// it): a cut at offset 0 in a run directory, as `insuwb-log`'s
/// `read_segments` reports it.
fn header_cut(path: &Path, e: &OpenError) -> Option<Cut> {
    let OpenError::Header { error, .. } = e else {
        return None;
    };
    let have = match error {
        HeaderError::Empty => 0,
        HeaderError::Truncated { have, .. } => *have,
        _ => return None,
    };
    Some(Cut {
        path: path.to_path_buf(),
        records: 0,
        report: TailReport {
            last_good_offset: 0,
            bytes_ignored: have,
            reason: TailReason::TruncatedHeader,
        },
    })
}

/// Exports the log at `input` (a file, or a run directory of segments)
/// into a new MCAP file at `output`: every whole record, in file order.
/// A file that ends cut or damaged is exported up to its last whole
/// record and listed in [`ExportSummary::cuts`]; in a run directory a
/// segment cut inside its header is such a cut too. Every file's header is
/// checked before `output` is created; on a later error the partial
/// output is removed.
///
/// # Errors
/// [`ExportError`]: the input is missing, unreadable or not a log (the
/// message names the file), or the output cannot be written.
pub fn export_log(
    input: &Path,
    output: &Path,
    options: &ExportOptions,
) -> Result<ExportSummary, ExportError> {
    let files = log_files(input).map_err(ExportError::Input)?;
    let in_dir = input.is_dir();
    let mut cuts = Vec::new();
    let mut first_header = None;
    for f in &files {
        // The headers alone: the records are read once, while writing.
        match insuwb_log::read_header_file(f) {
            Ok(header) => {
                if first_header.is_none() {
                    first_header = Some(header);
                }
            }
            Err(e) => match header_cut(f, &e) {
                Some(_) if in_dir => {}
                _ => return Err(ExportError::Input(InputError::Open(e))),
            },
        }
    }
    let file = File::create(output).map_err(|error| ExportError::Create {
        path: output.to_path_buf(),
        error,
    })?;
    let result = write_all(
        BufWriter::with_capacity(1 << 20, file),
        output,
        &files,
        first_header.as_ref(),
        options,
        &mut cuts,
    );
    match result {
        Ok(stats) => Ok(ExportSummary { files, cuts, stats }),
        Err(e) => {
            // Best effort: the partial file is useless, the error says why.
            let _ = std::fs::remove_file(output);
            Err(e)
        }
    }
}

fn write_all(
    sink: BufWriter<File>,
    output: &Path,
    files: &[PathBuf],
    first_header: Option<&insuwb_log::LogHeader>,
    options: &ExportOptions,
    cuts: &mut Vec<Cut>,
) -> Result<ExportStats, ExportError> {
    let out = || output.to_path_buf();
    let mut w = RecordWriter::new(sink, options.clone())
        .map_err(|error| ExportError::Start { path: out(), error })?;
    if let Some(h) = first_header {
        let mut meta = BTreeMap::new();
        meta.insert("source".to_owned(), h.meta.source.clone());
        meta.insert("created_ns".to_owned(), h.created_ns.to_string());
        meta.insert("format_version".to_owned(), h.format_version.to_string());
        meta.insert("layout_version".to_owned(), h.layout_version.to_string());
        let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
        meta.insert("files".to_owned(), names.join("\n"));
        for (k, v) in &h.meta.entries {
            meta.insert(format!("meta.{k}"), v.clone());
        }
        w.write_metadata(METADATA_NAME, meta)
            .map_err(|error| ExportError::Write { path: out(), error })?;
    }
    for f in files {
        let mut reader = match LogReader::open(f) {
            Ok(r) => r,
            Err(e) => match header_cut(f, &e) {
                Some(cut) => {
                    cuts.push(cut);
                    continue;
                }
                None => return Err(ExportError::Input(InputError::Open(e))),
            },
        };
        for rec in reader.by_ref() {
            let rec = rec.map_err(|error| {
                ExportError::Input(InputError::Read {
                    path: f.clone(),
                    error,
                })
            })?;
            w.write(&rec)
                .map_err(|error| ExportError::Write { path: out(), error })?;
        }
        if let Some(report) = reader.tail() {
            cuts.push(Cut {
                path: f.clone(),
                records: reader.records_read(),
                report: report.clone(),
            });
        }
    }
    let (sink, stats) = w
        .finish()
        .map_err(|error| ExportError::Finish { path: out(), error })?;
    let file = sink.into_inner().map_err(|e| ExportError::Flush {
        path: out(),
        error: e.into_error(),
    })?;
    file.sync_all()
        .map_err(|error| ExportError::Flush { path: out(), error })?;
    Ok(stats)
}

#[cfg(test)]
mod tests;
