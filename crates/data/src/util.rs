//! Typed import of a UTIL flight: IMU, UWB TDOA and ground-truth samples
//! from a parsed Crazyflie log and the flight's anchor file.
//!
//! Conventions of the output (those of `insuwb-msg`):
//! - times are u64 nanoseconds since the log's first record (of any event
//!   type, in file order); the logger clock's microseconds are multiplied by
//!   1000. `header.seq` counts each output stream from 0;
//! - IMU samples are stamped at the accelerometer times. The gyroscope is a
//!   separate event (logged about 15 us after the accelerometer, and the two
//!   counts can differ by a few), so it is linearly interpolated onto the
//!   accelerometer times. Accelerations in g are multiplied by
//!   [`STANDARD_GRAVITY_MPS2`] (the Crazyflie firmware's convention), gyro
//!   rates in deg/s converted to rad/s. The Crazyflie body frame is
//!   x forward, y left, z up (FLU), as insuwb's: no axis change (checked on
//!   the data: at rest the accelerometer reads +1 g on z, and the gyro agrees
//!   with the body rates differentiated from the ground-truth attitude);
//! - TDOA `diff_m = |p - a_idB| - |p - a_idA|` with `anchor_a = idA`,
//!   `anchor_b = idB`, and the anchor positions from the anchor file;
//! - two-way ranges (`estDistance`, the TWR logs) `range_m = distance`
//!   to `anchor = id`, with its position from the anchor file and
//!   no quality (the log carries none);
//! - ground truth (`estPose`, Vicon frame x east, y north, z up) with the
//!   quaternion reordered from scalar-last to `[w, x, y, z]` and normalised;
//!   near-duplicate stamps (about 20 us apart) are dropped, the first one
//!   kept. Velocity is not provided (`FLAG_VEL_VALID` clear).

use std::path::{Path, PathBuf};

use insuwb_msg::{GroundTruth, Header, ImuSample, UwbRange, UwbTdoa};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::anchors::{AnchorError, Anchors};
use crate::cflog::{CfLog, CfLogError, Integrity, ParseOptions, Record};
use crate::flow::{FlowRecord, RangeRecord};

/// Standard gravity, m/s^2: the Crazyflie firmware converts its accelerometer
/// to g with this value, so g are turned back into m/s^2 with it.
pub const STANDARD_GRAVITY_MPS2: f64 = 9.80665;

/// Position of the UWB antenna in the Crazyflie body frame (FLU), m
/// (dataset README; the IMU is at the body origin).
pub const UWB_ANTENNA_LEVER_ARM_M: [f64; 3] = [-0.01245, 0.00127, 0.0908];

/// The four UTIL flights of `shared/data/util` and their anchor files
/// (dataset README table).
pub const UTIL_LOGS: [(&str, &str); 4] = [
    ("cfBolt-log00", "anchors-const3.txt"),
    ("test-log00", "anchors-const3.txt"),
    ("0426-traj3", "anchors-0426.txt"),
    ("0426-traj5", "anchors-0426.txt"),
];

/// Largest log file [`load_util_flight`] reads into memory, bytes (1 GiB;
/// the UTIL logs are about 3.4 MB).
pub const MAX_LOG_BYTES: u64 = 1 << 30;

/// Largest anchor file [`load_util_flight`] reads, bytes.
pub const MAX_ANCHOR_FILE_BYTES: u64 = 1 << 20;

/// Event and variable names used by the importer (UTIL logs).
mod names {
    pub const ACC: &str = "estAcceleration";
    pub const ACC_VARS: [&str; 3] = ["acc.x", "acc.y", "acc.z"];
    pub const GYRO: &str = "estGyroscope";
    pub const GYRO_VARS: [&str; 3] = ["gyro.x", "gyro.y", "gyro.z"];
    pub const TDOA: &str = "estTDOA";
    pub const TDOA_VARS: [&str; 3] = ["idA", "idB", "distanceDiff"];
    pub const TWR: &str = "estDistance";
    pub const TWR_VARS: [&str; 2] = ["id", "distance"];
    pub const FLOW: &str = "estFlow";
    pub const FLOW_VARS: [&str; 2] = ["motion.deltaX", "motion.deltaY"];
    pub const TOF: &str = "estTOF";
    pub const TOF_VARS: [&str; 1] = ["range.zrange"];
    pub const POSE: &str = "estPose";
    pub const POSE_VARS: [&str; 7] = [
        "locSrv.x",
        "locSrv.y",
        "locSrv.z",
        "locSrv.qx",
        "locSrv.qy",
        "locSrv.qz",
        "locSrv.qw",
    ];
}

/// Settings of [`UtilFlight::from_cflog_with`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImportOptions {
    /// Ground-truth samples closer than this to the previous kept one are
    /// dropped as near-duplicates, ns. Default 100 000 (100 us): the UTIL logs
    /// hold duplicates about 20 us apart while Vicon frames are 3.3 ms apart
    /// (measured on the four logs).
    pub truth_dedup_ns: u64,
    /// Longest gyroscope gap the gyro is interpolated across onto an
    /// accelerometer time, ns. Default 50 000 000 (50 ms): the UTIL logs have
    /// IMU gaps of up to 42 ms (dataset README); accelerometer samples in a
    /// longer gap are dropped (`ImportStats::accel_unpaired`).
    pub imu_max_interp_gap_ns: u64,
    /// Before the first or after the last gyroscope sample, the nearest one is
    /// held for accelerometer samples within this distance, ns. Default
    /// 2 000 000 (2 ms, two IMU periods; the streams are about 15 us apart).
    pub imu_edge_hold_ns: u64,
    /// Ground-truth quaternions whose norm differs from 1 by more than this are
    /// dropped (dimensionless). Default 0.1: the logged quaternions are
    /// quantised (norm error below 0.01 measured), anything worse is corrupt.
    pub truth_quat_norm_tol: f64,
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            truth_dedup_ns: 100_000,
            imu_max_interp_gap_ns: 50_000_000,
            imu_edge_hold_ns: 2_000_000,
            truth_quat_norm_tol: 0.1,
        }
    }
}

/// An [`ImportOptions`] value out of range; names the key and the value.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ImportConfigError {
    /// `truth_dedup_ns` too large.
    #[error("import.truth_dedup_ns must be <= 10000000 (10 ms), got {0}")]
    TruthDedup(u64),
    /// `imu_max_interp_gap_ns` zero.
    #[error("import.imu_max_interp_gap_ns must be > 0, got {0}")]
    ImuMaxGap(u64),
    /// `imu_edge_hold_ns` larger than the interpolation gap.
    #[error("import.imu_edge_hold_ns must be <= import.imu_max_interp_gap_ns ({max}), got {got}")]
    ImuEdgeHold {
        /// The value given.
        got: u64,
        /// `imu_max_interp_gap_ns`.
        max: u64,
    },
    /// `truth_quat_norm_tol` outside (0, 1).
    #[error("import.truth_quat_norm_tol must be in (0, 1), got {0}")]
    QuatTol(f64),
}

impl ImportOptions {
    /// Checks every value.
    ///
    /// # Errors
    /// The first out-of-range key.
    pub fn validate(&self) -> Result<(), ImportConfigError> {
        if self.truth_dedup_ns > 10_000_000 {
            return Err(ImportConfigError::TruthDedup(self.truth_dedup_ns));
        }
        if self.imu_max_interp_gap_ns == 0 {
            return Err(ImportConfigError::ImuMaxGap(self.imu_max_interp_gap_ns));
        }
        if self.imu_edge_hold_ns > self.imu_max_interp_gap_ns {
            return Err(ImportConfigError::ImuEdgeHold {
                got: self.imu_edge_hold_ns,
                max: self.imu_max_interp_gap_ns,
            });
        }
        if !(self.truth_quat_norm_tol > 0.0 && self.truth_quat_norm_tol < 1.0) {
            return Err(ImportConfigError::QuatTol(self.truth_quat_norm_tol));
        }
        Ok(())
    }
}

/// What the import read, and what it skipped and why. Each skip counter
/// counts records (or samples) left out of the output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ImportStats {
    /// Records in the log.
    pub records: u64,
    /// Records of event types the importer does not use (estBarometer, ...).
    pub unknown_events: u64,
    /// Accelerometer records read.
    pub accel_records: u64,
    /// Gyroscope records read.
    pub gyro_records: u64,
    /// TDOA records read.
    pub tdoa_records: u64,
    /// Ground-truth records read.
    pub truth_records: u64,
    /// Two-way-ranging records read (`estDistance`).
    #[serde(default)]
    pub distance_records: u64,
    /// Optical-flow records read (`estFlow`).
    #[serde(default)]
    pub flow_records: u64,
    /// Time-of-flight range records read (`estTOF`).
    #[serde(default)]
    pub range_records: u64,
    /// TDOA or two-way-ranging records naming an anchor id the anchor file
    /// lacks (or not an integer).
    pub unknown_anchor: u64,
    /// TDOA records with `idA == idB`.
    pub same_anchor: u64,
    /// Records stamped before the previous record of their stream (or before
    /// the log's first record).
    pub time_backwards: u64,
    /// IMU records stamped at the same time as the previous one of their stream.
    pub time_repeated: u64,
    /// Records with a NaN or infinite value.
    pub non_finite: u64,
    /// Ground-truth records whose quaternion norm is off by more than the tolerance.
    pub bad_quaternion: u64,
    /// Ground-truth records dropped as near-duplicates.
    pub truth_duplicates: u64,
    /// Accelerometer samples without a gyroscope sample to pair with.
    pub accel_unpaired: u64,
}

/// Why a flight could not be imported.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ImportError {
    /// The options are out of range.
    #[error(transparent)]
    Config(#[from] ImportConfigError),
    /// A used event lacks one of the variables the importer needs.
    #[error("event {event} has no variable {variable}")]
    MissingVariable {
        /// Event name.
        event: &'static str,
        /// Variable name.
        variable: &'static str,
    },
}

/// Why [`load_util_flight`] failed; names the file.
///
/// Each message is whole (file and cause), and no variant exposes its cause
/// as [`std::error::Error::source`]: a report that prints the chain
/// (`anyhow`'s `{:#}`) shows every cause once.
#[derive(Debug, Error)]
pub enum LoadError {
    /// The file could not be read.
    #[error("cannot read {path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        error: std::io::Error,
    },
    /// The file is larger than the limit.
    #[error("{path} is {len} bytes, more than the {max} bytes allowed")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its length.
        len: u64,
        /// The limit.
        max: u64,
    },
    /// The anchor file is not UTF-8.
    #[error("{path} is not UTF-8 text")]
    NotText {
        /// The file.
        path: PathBuf,
    },
    /// The log is malformed.
    #[error("{path}: {error}")]
    Log {
        /// The file.
        path: PathBuf,
        /// The format error.
        error: CfLogError,
    },
    /// The anchor file is malformed (the error names the file).
    #[error(transparent)]
    Anchors(#[from] AnchorError),
    /// The import failed.
    #[error("{path}: {error}")]
    Import {
        /// The log file.
        path: PathBuf,
        /// The import error.
        error: ImportError,
    },
}

/// One UTIL flight as insuwb samples.
#[derive(Debug, Clone, PartialEq)]
pub struct UtilFlight {
    /// IMU samples at the accelerometer times (see the module doc).
    pub imu: Vec<ImuSample>,
    /// TDOA measurements, in log order.
    pub tdoa: Vec<UwbTdoa>,
    /// Two-way ranges (`estDistance`), in log order; empty for a TDOA log.
    pub twr: Vec<UwbRange>,
    /// Ground truth, strictly increasing times, deduplicated.
    pub truth: Vec<GroundTruth>,
    /// The flow deck's motion counts (`estFlow`), increasing times; empty
    /// for a log without the deck ([`crate::flow`] turns them into
    /// velocities).
    pub flow: Vec<FlowRecord>,
    /// The flow deck's time-of-flight ranges (`estTOF`, mm to m),
    /// increasing times.
    pub ranges: Vec<RangeRecord>,
    /// Logger-clock time of the log's first record, us: the zero of every
    /// `meas_time_ns`.
    pub start_time_us: u64,
    /// What was read and skipped.
    pub stats: ImportStats,
    /// How the log ended: CRC checked, CRC mismatch read anyway, or cut
    /// short (where: warn the user, the samples stop there).
    pub integrity: Integrity,
}

/// Column indices of one event's variables, resolved once.
struct Columns<const N: usize> {
    id: u16,
    idx: [usize; N],
}

fn columns<const N: usize>(
    log: &CfLog,
    event: &'static str,
    vars: [&'static str; N],
) -> Result<Option<Columns<N>>, ImportError> {
    let Some(desc) = log.event_by_name(event) else {
        return Ok(None);
    };
    let mut idx = [0usize; N];
    for (slot, variable) in idx.iter_mut().zip(vars) {
        *slot = desc
            .variable_index(variable)
            .ok_or(ImportError::MissingVariable { event, variable })?;
    }
    Ok(Some(Columns { id: desc.id, idx }))
}

impl<const N: usize> Columns<N> {
    /// The variables as f64 (NaN where a value is missing, never the case
    /// for a parsed log).
    fn f64s(&self, r: &Record<'_>) -> [f64; N] {
        self.idx
            .map(|i| r.values.get(i).map_or(f64::NAN, |v| v.as_f64()))
    }
}

/// A timestamped 3-vector of one IMU stream.
type Vec3At = (u64, [f64; 3]);

/// Appends an IMU record to its stream after the time and finiteness checks.
fn push_imu(stream: &mut Vec<Vec3At>, t_ns: u64, v: [f64; 3], stats: &mut ImportStats) {
    match stream.last() {
        Some(&(last, _)) if t_ns < last => stats.time_backwards += 1,
        Some(&(last, _)) if t_ns == last => stats.time_repeated += 1,
        _ if !v.iter().all(|x| x.is_finite()) => stats.non_finite += 1,
        _ => stream.push((t_ns, v)),
    }
}

/// Gyro value at `t_ns` from the sorted gyro stream, per the options.
fn gyro_at(gyro: &[Vec3At], t_ns: u64, opts: &ImportOptions) -> Option<[f64; 3]> {
    let j = gyro.partition_point(|&(t, _)| t <= t_ns);
    match (j.checked_sub(1).and_then(|i| gyro.get(i)), gyro.get(j)) {
        (Some(&(t0, g0)), _) if t0 == t_ns => Some(g0),
        (Some(&(t0, g0)), Some(&(t1, g1))) => {
            let span = t1 - t0;
            (span <= opts.imu_max_interp_gap_ns).then(|| {
                let w = (t_ns - t0) as f64 / span as f64;
                [
                    g0[0] + w * (g1[0] - g0[0]),
                    g0[1] + w * (g1[1] - g0[1]),
                    g0[2] + w * (g1[2] - g0[2]),
                ]
            })
        }
        (None, Some(&(t1, g1))) => (t1 - t_ns <= opts.imu_edge_hold_ns).then_some(g1),
        (Some(&(t0, g0)), None) => (t_ns - t0 <= opts.imu_edge_hold_ns).then_some(g0),
        (None, None) => None,
    }
}

impl UtilFlight {
    /// Imports a flight with the default [`ImportOptions`].
    ///
    /// # Errors
    /// See [`UtilFlight::from_cflog_with`].
    pub fn from_cflog(log: &CfLog, anchors: &Anchors) -> Result<Self, ImportError> {
        Self::from_cflog_with(log, anchors, &ImportOptions::default())
    }

    /// Imports a flight: `estAcceleration` + `estGyroscope` -> [`ImuSample`],
    /// `estTDOA` -> [`UwbTdoa`], `estPose` -> [`GroundTruth`] (conventions in
    /// the module doc). Records that cannot be used are skipped and counted in
    /// [`ImportStats`]; an event type that is absent gives an empty stream.
    ///
    /// # Errors
    /// [`ImportError::Config`] for invalid options, and
    /// [`ImportError::MissingVariable`] when a used event lacks a variable.
    pub fn from_cflog_with(
        log: &CfLog,
        anchors: &Anchors,
        opts: &ImportOptions,
    ) -> Result<Self, ImportError> {
        opts.validate()?;
        let acc_c = columns(log, names::ACC, names::ACC_VARS)?;
        let gyro_c = columns(log, names::GYRO, names::GYRO_VARS)?;
        let tdoa_c = columns(log, names::TDOA, names::TDOA_VARS)?;
        let twr_c = columns(log, names::TWR, names::TWR_VARS)?;
        let pose_c = columns(log, names::POSE, names::POSE_VARS)?;
        let flow_c = columns(log, names::FLOW, names::FLOW_VARS)?;
        let tof_c = columns(log, names::TOF, names::TOF_VARS)?;

        let start_time_us = log.record(0).map_or(0, |r| r.time_us);
        let mut stats = ImportStats::default();
        let mut accel: Vec<Vec3At> = Vec::new();
        let mut gyro: Vec<Vec3At> = Vec::new();
        let mut tdoa: Vec<UwbTdoa> = Vec::new();
        let mut twr: Vec<UwbRange> = Vec::new();
        let mut truth: Vec<GroundTruth> = Vec::new();
        let mut flow: Vec<FlowRecord> = Vec::new();
        let mut ranges: Vec<RangeRecord> = Vec::new();
        let mut last_tdoa_ns = 0u64;
        let mut last_pose_ns: Option<u64> = None;
        let deg = std::f64::consts::PI / 180.0;
        let used_ids = [
            acc_c.as_ref().map(|c| c.id),
            gyro_c.as_ref().map(|c| c.id),
            tdoa_c.as_ref().map(|c| c.id),
            twr_c.as_ref().map(|c| c.id),
            pose_c.as_ref().map(|c| c.id),
            flow_c.as_ref().map(|c| c.id),
            tof_c.as_ref().map(|c| c.id),
        ];

        for r in log.records() {
            stats.records += 1;
            let used = used_ids.contains(&Some(r.event.id));
            if !used {
                stats.unknown_events += 1;
                continue;
            }
            // Microseconds since the first record; a stamp before it went backwards.
            let Some(t_ns) = r
                .time_us
                .checked_sub(start_time_us)
                .map(|d| d.saturating_mul(1000))
            else {
                stats.time_backwards += 1;
                continue;
            };
            if let Some(c) = acc_c.as_ref().filter(|c| c.id == r.event.id) {
                stats.accel_records += 1;
                let v = c.f64s(&r).map(|g| g * STANDARD_GRAVITY_MPS2);
                push_imu(&mut accel, t_ns, v, &mut stats);
            } else if let Some(c) = gyro_c.as_ref().filter(|c| c.id == r.event.id) {
                stats.gyro_records += 1;
                let v = c.f64s(&r).map(|d| d * deg);
                push_imu(&mut gyro, t_ns, v, &mut stats);
            } else if let Some(c) = tdoa_c.as_ref().filter(|c| c.id == r.event.id) {
                stats.tdoa_records += 1;
                let id_of = |k: usize| {
                    c.idx
                        .get(k)
                        .and_then(|&i| r.values.get(i))
                        .and_then(|v| v.as_u32())
                };
                let (ida, idb) = (id_of(0), id_of(1));
                let diff_m = c.f64s(&r)[2];
                if t_ns < last_tdoa_ns {
                    stats.time_backwards += 1;
                    continue;
                }
                let (Some(ida), Some(idb)) = (ida, idb) else {
                    stats.unknown_anchor += 1;
                    continue;
                };
                let (Some(pa), Some(pb)) = (anchors.get(ida), anchors.get(idb)) else {
                    stats.unknown_anchor += 1;
                    continue;
                };
                if ida == idb {
                    stats.same_anchor += 1;
                    continue;
                }
                if !diff_m.is_finite() {
                    stats.non_finite += 1;
                    continue;
                }
                last_tdoa_ns = t_ns;
                tdoa.push(UwbTdoa {
                    header: Header::new(tdoa.len() as u64, t_ns),
                    anchor_a: ida,
                    anchor_b: idb,
                    diff_m,
                    anchor_a_pos_m: pa,
                    anchor_b_pos_m: pb,
                });
            } else if let Some(c) = twr_c.as_ref().filter(|c| c.id == r.event.id) {
                stats.distance_records += 1;
                let id = c
                    .idx
                    .first()
                    .and_then(|&i| r.values.get(i))
                    .and_then(|v| v.as_u32());
                let range_m = c.f64s(&r)[1];
                if twr.last().is_some_and(|m| t_ns < m.header.meas_time_ns) {
                    stats.time_backwards += 1;
                    continue;
                }
                let Some((id, pos)) = id.and_then(|id| Some((id, anchors.get(id)?))) else {
                    stats.unknown_anchor += 1;
                    continue;
                };
                if !range_m.is_finite() {
                    stats.non_finite += 1;
                    continue;
                }
                twr.push(UwbRange {
                    header: Header::new(twr.len() as u64, t_ns),
                    anchor: id,
                    quality: 0,
                    range_m,
                    anchor_pos_m: pos,
                });
            } else if let Some(c) = flow_c.as_ref().filter(|c| c.id == r.event.id) {
                stats.flow_records += 1;
                let [delta_x, delta_y] = c.f64s(&r);
                if flow.last().is_some_and(|f| t_ns <= f.t_ns) {
                    stats.time_backwards += 1;
                } else if !(delta_x.is_finite() && delta_y.is_finite()) {
                    stats.non_finite += 1;
                } else {
                    flow.push(FlowRecord {
                        t_ns,
                        delta_x,
                        delta_y,
                    });
                }
            } else if let Some(c) = tof_c.as_ref().filter(|c| c.id == r.event.id) {
                stats.range_records += 1;
                let [mm] = c.f64s(&r);
                if ranges.last().is_some_and(|f| t_ns <= f.t_ns) {
                    stats.time_backwards += 1;
                } else if !mm.is_finite() {
                    stats.non_finite += 1;
                } else {
                    ranges.push(RangeRecord {
                        t_ns,
                        range_m: mm * 1e-3,
                    });
                }
            } else if let Some(c) = pose_c.as_ref().filter(|c| c.id == r.event.id) {
                stats.truth_records += 1;
                let [x, y, z, qx, qy, qz, qw] = c.f64s(&r);
                if last_pose_ns.is_some_and(|last| t_ns < last) {
                    stats.time_backwards += 1;
                    continue;
                }
                if ![x, y, z, qx, qy, qz, qw].iter().all(|v| v.is_finite()) {
                    stats.non_finite += 1;
                    continue;
                }
                let norm = (qw * qw + qx * qx + qy * qy + qz * qz).sqrt();
                if (norm - 1.0).abs() > opts.truth_quat_norm_tol {
                    stats.bad_quaternion += 1;
                    continue;
                }
                if last_pose_ns.is_some_and(|last| t_ns - last < opts.truth_dedup_ns) {
                    stats.truth_duplicates += 1;
                    continue;
                }
                last_pose_ns = Some(t_ns);
                truth.push(GroundTruth {
                    header: Header::new(truth.len() as u64, t_ns),
                    pos_m: [x, y, z],
                    vel_mps: [0.0; 3],
                    quat: [qw / norm, qx / norm, qy / norm, qz / norm],
                });
            }
        }

        let mut imu = Vec::with_capacity(accel.len());
        for &(t_ns, a) in &accel {
            match gyro_at(&gyro, t_ns, opts) {
                Some(g) => imu.push(ImuSample {
                    header: Header::new(imu.len() as u64, t_ns),
                    accel_mps2: a,
                    gyro_rps: g,
                }),
                None => stats.accel_unpaired += 1,
            }
        }
        Ok(Self {
            imu,
            tdoa,
            twr,
            truth,
            flow,
            ranges,
            start_time_us,
            stats,
            integrity: log.integrity().clone(),
        })
    }

    /// Time from the log's first record to the last sample of any output
    /// stream, ns (0 for an empty flight).
    #[must_use]
    pub fn duration_ns(&self) -> u64 {
        let last = |t: Option<u64>| t.unwrap_or(0);
        last(self.imu.last().map(|s| s.header.meas_time_ns))
            .max(last(self.tdoa.last().map(|s| s.header.meas_time_ns)))
            .max(last(self.twr.last().map(|s| s.header.meas_time_ns)))
            .max(last(self.truth.last().map(|s| s.header.meas_time_ns)))
    }
}

/// Reads a whole file of at most `max` bytes.
fn read_bounded(path: &Path, max: u64) -> Result<Vec<u8>, LoadError> {
    let io = |error| LoadError::Io {
        path: path.to_owned(),
        error,
    };
    let len = std::fs::metadata(path).map_err(io)?.len();
    if len > max {
        return Err(LoadError::TooLarge {
            path: path.to_owned(),
            len,
            max,
        });
    }
    std::fs::read(path).map_err(io)
}

/// Reads and imports one flight: the log at `log_path` and its anchor file.
///
/// # Errors
/// [`LoadError`] naming the file that could not be read, parsed or imported.
pub fn load_util_flight(
    log_path: &Path,
    anchors_path: &Path,
    parse: &ParseOptions,
    import: &ImportOptions,
) -> Result<UtilFlight, LoadError> {
    let text = read_bounded(anchors_path, MAX_ANCHOR_FILE_BYTES)?;
    let text = String::from_utf8(text).map_err(|_| LoadError::NotText {
        path: anchors_path.to_owned(),
    })?;
    let anchors = Anchors::parse(&text, &anchors_path.display().to_string())?;
    let bytes = read_bounded(log_path, MAX_LOG_BYTES)?;
    let log = CfLog::parse(&bytes, parse).map_err(|error| LoadError::Log {
        path: log_path.to_owned(),
        error,
    })?;
    UtilFlight::from_cflog_with(&log, &anchors, import).map_err(|error| LoadError::Import {
        path: log_path.to_owned(),
        error,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testlog::build;

    const ACC: u16 = 1;
    const GYRO: u16 = 2;
    const TDOA: u16 = 3;
    const POSE: u16 = 4;
    const TOF: u16 = 5;
    const FLOW: u16 = 6;
    const BARO: u16 = 7;

    fn events() -> Vec<(u16, &'static str, &'static [&'static str])> {
        vec![
            (
                ACC,
                "estAcceleration",
                &["acc.x(f)", "acc.y(f)", "acc.z(f)"],
            ),
            (
                GYRO,
                "estGyroscope",
                &["gyro.x(f)", "gyro.y(f)", "gyro.z(f)"],
            ),
            (TDOA, "estTDOA", &["idA(B)", "idB(B)", "distanceDiff(f)"]),
            (
                POSE,
                "estPose",
                &[
                    "locSrv.x(f)",
                    "locSrv.y(f)",
                    "locSrv.z(f)",
                    "locSrv.qx(f)",
                    "locSrv.qy(f)",
                    "locSrv.qz(f)",
                    "locSrv.qw(f)",
                ],
            ),
            (TOF, "estTOF", &["range.zrange(H)"]),
            (FLOW, "estFlow", &["motion.deltaX(h)", "motion.deltaY(h)"]),
            (BARO, "estBarometer", &["baro.asl(f)"]),
        ]
    }

    fn f32s(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    fn tdoa(a: u8, b: u8, d: f32) -> Vec<u8> {
        let mut p = vec![a, b];
        p.extend_from_slice(&d.to_le_bytes());
        p
    }

    fn anchors() -> Anchors {
        Anchors::parse("an0_p,0,0,0\nan1_p,4,0,0\nan2_p,0,4,1\n", "test").unwrap()
    }

    fn flight() -> UtilFlight {
        let t = |us: u64| us;
        let recs = vec![
            (TOF, t(1000), 300u16.to_le_bytes().to_vec()),
            (GYRO, t(1500), f32s(&[90.0, 0.0, -30.0])),
            (ACC, t(500), f32s(&[9.0, 9.0, 9.0])), // before the first record
            (ACC, t(2000), f32s(&[0.0, 0.5, 1.0])),
            (POSE, t(2000), f32s(&[1.0, 2.0, 3.0, 0.0, 0.0, 0.6, 0.8])),
            (POSE, t(2000), f32s(&[1.1, 2.0, 3.0, 0.0, 0.0, 0.6, 0.8])), // duplicate
            (TDOA, t(2100), tdoa(0, 1, 0.5)),
            (TDOA, t(2100), tdoa(2, 0, -0.25)),
            (TDOA, t(2000), tdoa(2, 0, -0.25)), // backwards
            (TDOA, t(2200), tdoa(0, 5, 0.1)),   // unknown anchor
            (TDOA, t(2200), tdoa(1, 1, 0.1)),   // same anchor
            (TDOA, t(2200), tdoa(1, 0, f32::NAN)),
            (GYRO, t(2500), f32s(&[180.0, 0.0, -30.0])),
            (ACC, t(2500), f32s(&[0.0, 0.0, -1.0])),
            (ACC, t(2500), f32s(&[0.0, 0.0, 5.0])), // repeated
            (ACC, t(2400), f32s(&[0.0, 0.0, 5.0])), // backwards
            (ACC, t(2700), f32s(&[f32::INFINITY, 0.0, 5.0])),
            (ACC, t(3000), f32s(&[2.0, 0.0, 0.0])), // held gyro (0.5 ms after)
            (POSE, t(4000), f32s(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.05])),
            (POSE, t(5000), f32s(&[0.0, 0.0, 0.0, 0.0, 0.0, 1.2, 1.6])), // norm 2
            (
                POSE,
                t(6000),
                f32s(&[f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
            ),
            (ACC, t(10_000), f32s(&[0.0, 0.0, 1.0])), // 7.5 ms after the last gyro
            (
                FLOW,
                t(10_100),
                [(-3i16).to_le_bytes(), 7i16.to_le_bytes()].concat(),
            ),
            (
                FLOW,
                t(10_100),
                [1i16.to_le_bytes(), 1i16.to_le_bytes()].concat(),
            ), // repeated
            (TOF, t(10_200), 1234u16.to_le_bytes().to_vec()),
            (BARO, t(10_300), f32s(&[100.0])),
        ];
        let bytes = build(2, &events(), &recs);
        let log = CfLog::parse(&bytes, &ParseOptions::default()).unwrap();
        UtilFlight::from_cflog(&log, &anchors()).unwrap()
    }

    #[test]
    fn imports_two_way_ranges_with_their_anchors_and_counts_skips() {
        const DIST: u16 = 8;
        let mut ev = events();
        ev.push((DIST, "estDistance", &["id(B)", "distance(f)"]));
        let dist = |id: u8, d: f32| {
            let mut p = vec![id];
            p.extend_from_slice(&d.to_le_bytes());
            p
        };
        let recs = vec![
            (DIST, 1000, dist(1, 3.25)),
            (DIST, 1100, dist(2, 4.5)),
            (DIST, 1050, dist(0, 1.0)), // backwards
            (DIST, 1200, dist(9, 1.0)), // unknown anchor
            (DIST, 1300, dist(0, f32::NAN)),
            (DIST, 1400, dist(0, 2.0)),
        ];
        let bytes = build(2, &ev, &recs);
        let log = CfLog::parse(&bytes, &ParseOptions::default()).unwrap();
        let f = UtilFlight::from_cflog(&log, &anchors()).unwrap();
        assert!(f.tdoa.is_empty());
        let got: Vec<(u64, u32, f64, [f64; 3])> = f
            .twr
            .iter()
            .map(|m| (m.header.meas_time_ns, m.anchor, m.range_m, m.anchor_pos_m))
            .collect();
        assert_eq!(
            got,
            vec![
                (0, 1, 3.25, [4.0, 0.0, 0.0]),
                (100_000, 2, 4.5, [0.0, 4.0, 1.0]),
                (400_000, 0, 2.0, [0.0, 0.0, 0.0]),
            ]
        );
        assert_eq!(f.twr[2].header.seq, 2);
        let s = f.stats;
        assert_eq!(s.distance_records, 6);
        assert_eq!(
            (s.time_backwards, s.unknown_anchor, s.non_finite),
            (1, 1, 1)
        );
        assert_eq!(f.duration_ns(), 400_000);
    }

    #[test]
    fn imports_known_values_and_counts_skips() {
        let f = flight();
        assert_eq!(f.start_time_us, 1000);
        // IMU: accelerometer times, gyro interpolated (135 deg/s halfway).
        let times: Vec<u64> = f.imu.iter().map(|s| s.header.meas_time_ns).collect();
        assert_eq!(times, vec![1_000_000, 1_500_000, 2_000_000]);
        let seqs: Vec<u64> = f.imu.iter().map(|s| s.header.seq).collect();
        assert_eq!(seqs, vec![0, 1, 2]);
        let d = std::f64::consts::PI / 180.0;
        assert_eq!(f.imu[0].accel_mps2, [0.0, 0.5 * 9.80665, 9.80665]);
        assert!((f.imu[0].gyro_rps[0] - 135.0 * d).abs() < 1e-12);
        assert!((f.imu[0].gyro_rps[2] + 30.0 * d).abs() < 1e-12);
        assert_eq!(f.imu[1].accel_mps2, [0.0, 0.0, -9.80665]);
        assert!((f.imu[1].gyro_rps[0] - 180.0 * d).abs() < 1e-12);
        assert!((f.imu[2].gyro_rps[0] - 180.0 * d).abs() < 1e-12);
        assert_eq!(f.imu[2].accel_mps2[0], 2.0 * 9.80665);

        // TDOA: ids, sign convention untouched, anchor positions filled in.
        assert_eq!(f.tdoa.len(), 2);
        let m = f.tdoa[0];
        assert_eq!((m.anchor_a, m.anchor_b, m.diff_m), (0, 1, 0.5));
        assert_eq!(m.anchor_a_pos_m, [0.0; 3]);
        assert_eq!(m.anchor_b_pos_m, [4.0, 0.0, 0.0]);
        assert_eq!(m.header.meas_time_ns, 1_100_000);
        assert_eq!(f.tdoa[1].anchor_a_pos_m, [0.0, 4.0, 1.0]);
        assert_eq!(f.tdoa[1].diff_m, -0.25);
        assert_eq!(f.tdoa[1].header.seq, 1);

        // Truth: scalar-last -> [w, x, y, z], normalised, deduplicated.
        assert_eq!(f.truth.len(), 2);
        let g = f.truth[0];
        assert_eq!(g.header.meas_time_ns, 1_000_000);
        assert_eq!(g.pos_m, [1.0, 2.0, 3.0]);
        let q = g.quat;
        assert!(
            (q[0] - 0.8).abs() < 1e-7 && (q[3] - 0.6).abs() < 1e-7,
            "{q:?}"
        );
        assert_eq!((q[1], q[2]), (0.0, 0.0));
        assert_eq!(f.truth[1].quat, [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(f.truth[1].header.seq, 1);
        assert_eq!(f.truth[1].header.flags & GroundTruth::FLAG_VEL_VALID, 0);

        let s = f.stats;
        assert_eq!(s.records, 26);
        assert_eq!(s.unknown_events, 1);
        assert_eq!((s.flow_records, s.range_records), (2, 2));
        assert_eq!(
            f.flow,
            vec![FlowRecord {
                t_ns: 9_100_000,
                delta_x: -3.0,
                delta_y: 7.0
            }]
        );
        let r: Vec<(u64, f64)> = f.ranges.iter().map(|r| (r.t_ns, r.range_m)).collect();
        assert_eq!(r, vec![(0, 0.3), (9_200_000, 1.234)]);
        assert_eq!(s.accel_records, 7); // the one before the first record is not counted here
        assert_eq!(s.gyro_records, 2);
        assert_eq!(s.tdoa_records, 6);
        assert_eq!(s.truth_records, 5);
        assert_eq!(s.time_backwards, 4);
        assert_eq!(s.time_repeated, 1);
        assert_eq!(s.non_finite, 3);
        assert_eq!(s.unknown_anchor, 1);
        assert_eq!(s.same_anchor, 1);
        assert_eq!(s.bad_quaternion, 1);
        assert_eq!(s.truth_duplicates, 1);
        assert_eq!(s.accel_unpaired, 1);
        assert_eq!(f.duration_ns(), 3_000_000);
    }

    #[test]
    fn version_1_milliseconds_scale_to_ns() {
        // Version 1 stamps are milliseconds.
        let recs = vec![
            (GYRO, 7u64, f32s(&[0.0, 0.0, 0.0])),
            (ACC, 8, f32s(&[0.0, 0.0, 1.0])),
            (GYRO, 9, f32s(&[0.0, 0.0, 0.0])),
            (TDOA, 12, tdoa(0, 2, 1.0)),
        ];
        let bytes = build(1, &events(), &recs);
        let log = CfLog::parse(&bytes, &ParseOptions::default()).unwrap();
        let f = UtilFlight::from_cflog(&log, &anchors()).unwrap();
        assert_eq!(f.start_time_us, 7_000);
        assert_eq!(f.imu.len(), 1);
        assert_eq!(f.imu[0].header.meas_time_ns, 1_000_000);
        assert_eq!(f.tdoa[0].header.meas_time_ns, 5_000_000);
        assert!(f.truth.is_empty());
    }

    #[test]
    fn loads_a_cut_log_and_names_each_cause_once() {
        let dir = std::env::temp_dir().join(format!("insuwb-data-util-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let anchors = dir.join("anchors.txt");
        std::fs::write(&anchors, "an0_p,0,0,0\nan1_p,4,0,0\n").unwrap();
        let recs: Vec<(u16, u64, Vec<u8>)> = (0..6)
            .map(|k| (ACC, 1000 * (k + 1), f32s(&[0.0, 0.0, 1.0])))
            .collect();
        let bytes = build(2, &events(), &recs);
        let load = |bytes: &[u8]| {
            let path = dir.join("log");
            std::fs::write(&path, bytes).unwrap();
            load_util_flight(
                &path,
                &anchors,
                &ParseOptions::default(),
                &ImportOptions::default(),
            )
        };
        // Cut 7 bytes into the sixth record (22 bytes each): five read.
        let cut_at = bytes.len() - 4 - 22 + 7;
        let f = load(&bytes[..cut_at]).unwrap();
        assert_eq!(f.stats.accel_records, 5);
        let Integrity::Cut(cut) = &f.integrity else {
            panic!("{:?}", f.integrity);
        };
        assert_eq!((cut.offset, cut.bytes_ignored), (cut_at - 7, 7));
        assert_eq!(load(&bytes).unwrap().integrity, Integrity::CrcOk);
        // A wrong byte: the message names the file and the cause, once, and
        // exposes no source that a chain would print again.
        let mut bad = bytes.clone();
        bad[cut_at - 10] ^= 0x40;
        let err = load(&bad).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, LoadError::Log { .. }), "{msg}");
        assert_eq!(msg.matches("CRC mismatch").count(), 1, "{msg}");
        assert!(
            msg.starts_with(&dir.join("log").display().to_string()),
            "{msg}"
        );
        assert!(std::error::Error::source(&err).is_none());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn missing_variable_is_an_error() {
        let bytes = build(2, &[(TDOA, "estTDOA", &["idA(B)", "idB(B)"])], &[]);
        let log = CfLog::parse(&bytes, &ParseOptions::default()).unwrap();
        let err = UtilFlight::from_cflog(&log, &anchors()).unwrap_err();
        assert_eq!(
            err,
            ImportError::MissingVariable {
                event: "estTDOA",
                variable: "distanceDiff"
            }
        );
        assert_eq!(
            err.to_string(),
            "event estTDOA has no variable distanceDiff"
        );
    }

    #[test]
    fn options_validate_and_deserialize() {
        let d = ImportOptions::default();
        assert_eq!(d.validate(), Ok(()));
        let o = ImportOptions {
            truth_quat_norm_tol: 0.0,
            ..d.clone()
        };
        assert_eq!(
            o.validate().unwrap_err().to_string(),
            "import.truth_quat_norm_tol must be in (0, 1), got 0"
        );
        let o = ImportOptions {
            imu_edge_hold_ns: 60_000_000,
            ..d.clone()
        };
        assert!(matches!(
            o.validate(),
            Err(ImportConfigError::ImuEdgeHold { .. })
        ));
        let o = ImportOptions {
            truth_dedup_ns: 20_000_000,
            ..d.clone()
        };
        assert!(o.validate().is_err());
        let o = ImportOptions {
            imu_max_interp_gap_ns: 0,
            imu_edge_hold_ns: 0,
            ..d.clone()
        };
        assert!(o.validate().is_err());
        let log = CfLog::parse(&build(2, &events(), &[]), &ParseOptions::default()).unwrap();
        assert!(matches!(
            UtilFlight::from_cflog_with(&log, &anchors(), &o),
            Err(ImportError::Config(_))
        ));
        let parsed: ImportOptions = serde_json::from_str(r#"{"truth_dedup_ns": 5}"#).unwrap();
        assert_eq!(parsed.truth_dedup_ns, 5);
        assert_eq!(parsed.imu_max_interp_gap_ns, d.imu_max_interp_gap_ns);
        assert!(serde_json::from_str::<ImportOptions>(r#"{"nope": 1}"#).is_err());
    }
}
