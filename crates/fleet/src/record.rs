//! The station's recording: each robot's stream in its own insuwb log,
//! `DIR/<robot>/seg-NNNNN.iulog`, written as the logger stage writes a run
//! directory ([`insuwb_log::SegmentWriter`]: a new segment at every start,
//! size rotation, the flush policy), so `insuwb log info`, `log export` and
//! `eval` read `DIR/<robot>` as they read a robot's own log.
//!
//! A robot's log is opened at its first record; its metadata names the
//! robot (`robot`), the station (`station`), and what the times mean
//! (`meas_time`, `pub_time`): the records keep the robot's stamps as
//! measurement times, in the robot's stamp clock, and carry the station's
//! receive time (CLOCK_MONOTONIC) as their publish time.
//!
//! ```
//! use insuwb_fleet::record::{FleetRecorder, RecordSettings};
//! use insuwb_msg::{FusedState, Header};
//!
//! let dir = std::env::temp_dir().join(format!("insuwb-fleet-doc-{}", std::process::id()));
//! let mut rec = FleetRecorder::open(&dir, RecordSettings::new("station-1")).unwrap();
//! let s = FusedState { header: Header::new(0, 1_000_000_000), ..FusedState::default() };
//! rec.fused("r1", &s, 5_000_000).unwrap();
//! let done = rec.finish().unwrap();
//! assert_eq!((done[0].robot.as_str(), done[0].records), ("r1", 1));
//! let read = insuwb_log::read_segments(dir.join("r1")).unwrap();
//! assert_eq!(read.records.len(), 1);
//! let meta = &read.segments[0].header.as_ref().unwrap().meta;
//! assert_eq!(meta.entries["robot"], "r1");
//! assert_eq!(meta.entries["station"], "station-1");
//! # std::fs::remove_dir_all(&dir).unwrap();
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use insuwb_log::{
    CreateError, Metadata, Record, SegmentConfig, SegmentConfigError, SegmentWriter, WriteError,
};
use insuwb_msg::{FusedState, Health};

use crate::keys::{check_robot_id, KeyError};

/// The metadata key naming the robot of a station's recording.
pub const META_ROBOT: &str = "robot";
/// The metadata key naming the station that recorded it.
pub const META_STATION: &str = "station";

/// How the station records.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordSettings {
    /// The station's name, in every log's metadata.
    pub station: String,
    /// Segment size and flush policy (the logger's defaults: 64 MiB
    /// segments, a flush every second).
    pub segments: SegmentConfig,
    /// More metadata entries for every log.
    pub meta: Vec<(String, String)>,
}

impl RecordSettings {
    /// The defaults for station `station`.
    #[must_use]
    pub fn new(station: &str) -> Self {
        Self {
            station: station.to_owned(),
            segments: SegmentConfig::default(),
            meta: Vec::new(),
        }
    }
}

/// Opening the recording failed.
#[derive(Debug, thiserror::Error)]
pub enum RecorderOpenError {
    /// The segment settings are invalid.
    #[error("RecorderOpenError::Segments: {0}")]
    Segments(#[from] SegmentConfigError),
    /// The folder cannot be created, or is not a folder.
    #[error("RecorderOpenError::Dir: {path}: {error}")]
    Dir {
        /// The folder.
        path: PathBuf,
        /// The I/O error.
        error: std::io::Error,
    },
}

/// Recording a robot's sample failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The robot id is no robot id (it names the robot's folder).
    #[error("RecordError::RobotId: {0}")]
    RobotId(#[from] KeyError),
    /// The robot's log cannot be opened.
    #[error("RecordError::Open: robot {robot}: {error}")]
    Open {
        /// The robot.
        robot: String,
        /// Why.
        error: CreateError,
    },
    /// Writing or flushing the robot's log failed (a full disk, say).
    #[error("RecordError::Write: robot {robot}: {error}")]
    Write {
        /// The robot.
        robot: String,
        /// Why.
        error: WriteError,
    },
}

/// What was recorded of one robot.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RobotRecording {
    /// The robot.
    pub robot: String,
    /// Its folder of segments.
    pub dir: PathBuf,
    /// Records written.
    pub records: u64,
}

/// The recording of every robot heard, one folder each.
#[derive(Debug)]
pub struct FleetRecorder {
    dir: PathBuf,
    settings: RecordSettings,
    robots: BTreeMap<String, SegmentWriter>,
}

impl FleetRecorder {
    /// Checks the settings and creates `dir` (owner only) if needed.
    ///
    /// # Errors
    /// [`RecorderOpenError`].
    pub fn open(
        dir: impl AsRef<Path>,
        settings: RecordSettings,
    ) -> Result<Self, RecorderOpenError> {
        settings.segments.validate()?;
        let dir = dir.as_ref().to_path_buf();
        let mut b = std::fs::DirBuilder::new();
        b.recursive(true);
        {
            use std::os::unix::fs::DirBuilderExt;
            b.mode(insuwb_log::DIR_MODE);
        }
        b.create(&dir).map_err(|error| RecorderOpenError::Dir {
            path: dir.clone(),
            error,
        })?;
        Ok(Self {
            dir,
            settings,
            robots: BTreeMap::new(),
        })
    }

    /// The folder of the recording.
    #[must_use]
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn writer(&mut self, robot: &str, now_ns: u64) -> Result<&mut SegmentWriter, RecordError> {
        if !self.robots.contains_key(robot) {
            check_robot_id(robot)?;
            let s = &self.settings;
            let mut meta = Metadata::new(format!(
                "insuwb fleet record: robot {robot} at station {}",
                s.station
            ))
            .with(META_ROBOT, robot)
            .with(META_STATION, s.station.clone())
            .with(
                "meas_time",
                "the robot's stamps, in its stamp clock (CLOCK_REALTIME unless the robot sets stamp_clock = \"monotonic\")",
            )
            .with(
                "pub_time",
                "the station's receive time, CLOCK_MONOTONIC of the station",
            );
            for (k, v) in &s.meta {
                meta = meta.with(k.clone(), v.clone());
            }
            let w = SegmentWriter::open(self.dir.join(robot), meta, s.segments.clone(), now_ns)
                .map_err(|error| RecordError::Open {
                    robot: robot.to_owned(),
                    error,
                })?;
            self.robots.insert(robot.to_owned(), w);
        }
        self.robots
            .get_mut(robot)
            .ok_or_else(|| RecordError::RobotId(KeyError::RobotId(robot.to_owned())))
    }

    fn append(&mut self, robot: &str, rec: &Record, now_ns: u64) -> Result<(), RecordError> {
        self.writer(robot, now_ns)?
            .append(rec, now_ns)
            .map_err(|error| RecordError::Write {
                robot: robot.to_owned(),
                error,
            })
    }

    /// Records a fused state of `robot` at `now_ns` (CLOCK_MONOTONIC, for
    /// the flush policy).
    ///
    /// # Errors
    /// [`RecordError`].
    pub fn fused(&mut self, robot: &str, s: &FusedState, now_ns: u64) -> Result<(), RecordError> {
        self.append(robot, &Record::Fused(*s), now_ns)
    }

    /// Records a heartbeat of one of `robot`'s stages.
    ///
    /// # Errors
    /// [`RecordError`].
    pub fn health(&mut self, robot: &str, h: &Health, now_ns: u64) -> Result<(), RecordError> {
        self.append(robot, &Record::Health(*h), now_ns)
    }

    /// Applies the flush policy to every robot's log (call it periodically).
    ///
    /// # Errors
    /// [`RecordError::Write`].
    pub fn tick(&mut self, now_ns: u64) -> Result<(), RecordError> {
        for (robot, w) in &mut self.robots {
            w.tick(now_ns).map_err(|error| RecordError::Write {
                robot: robot.clone(),
                error,
            })?;
        }
        Ok(())
    }

    /// Records written so far per robot.
    pub fn robots(&self) -> impl Iterator<Item = (&str, u64)> {
        self.robots
            .iter()
            .map(|(r, w)| (r.as_str(), w.records_written()))
    }

    /// Closes every robot's log; what was recorded of each.
    ///
    /// # Errors
    /// [`RecordError::Write`] for the first log that cannot be closed (the
    /// others are closed all the same).
    pub fn finish(self) -> Result<Vec<RobotRecording>, RecordError> {
        let mut out = Vec::with_capacity(self.robots.len());
        let mut first_err = None;
        for (robot, w) in self.robots {
            let rec = RobotRecording {
                robot: robot.clone(),
                dir: w.dir().to_path_buf(),
                records: w.records_written(),
            };
            if let Err(error) = w.finish() {
                first_err.get_or_insert(RecordError::Write { robot, error });
            }
            out.push(rec);
        }
        match first_err {
            Some(e) => Err(e),
            None => Ok(out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::{fixed_name, Header};

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("insuwb-fleet-rec-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn each_robot_gets_its_own_log_with_its_metadata() {
        let dir = tmp("two");
        let mut settings = RecordSettings::new("st");
        settings
            .meta
            .push(("stamp_clock".into(), "realtime".into()));
        let mut rec = FleetRecorder::open(&dir, settings).unwrap();
        for k in 0..5u64 {
            let s = FusedState {
                header: Header::new(k, 1_000 + k),
                ..FusedState::default()
            };
            rec.fused("r1", &s, k).unwrap();
            if k % 2 == 0 {
                rec.fused("r2", &s, k).unwrap();
            }
        }
        let h = Health {
            header: Header::new(0, 7),
            stage: fixed_name("fusion"),
            pid: 42,
            ..Health::default()
        };
        rec.health("r2", &h, 9).unwrap();
        rec.tick(2_000_000_000).unwrap();
        assert_eq!(rec.robots().collect::<Vec<_>>(), [("r1", 5), ("r2", 4)]);
        let done = rec.finish().unwrap();
        assert_eq!(done.len(), 2);
        assert_eq!(done[1].dir, dir.join("r2"));
        let r2 = insuwb_log::read_segments(dir.join("r2")).unwrap();
        assert_eq!(r2.records.len(), 4);
        assert!(matches!(r2.records[3], Record::Health(x) if x.pid == 42));
        let meta = &r2.segments[0].header.as_ref().unwrap().meta;
        assert_eq!(meta.entries[META_ROBOT], "r2");
        assert_eq!(meta.entries[META_STATION], "st");
        assert_eq!(meta.entries["stamp_clock"], "realtime");
        assert!(
            meta.source.contains("robot r2 at station st"),
            "{}",
            meta.source
        );
        // A second recording into the same folder opens new segments.
        let mut again = FleetRecorder::open(&dir, RecordSettings::new("st")).unwrap();
        again.fused("r1", &FusedState::default(), 0).unwrap();
        again.finish().unwrap();
        let r1 = insuwb_log::read_segments(dir.join("r1")).unwrap();
        assert_eq!((r1.segments.len(), r1.records.len()), (2, 6));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn bad_robot_ids_and_folders_are_refused() {
        let dir = tmp("bad");
        let mut rec = FleetRecorder::open(&dir, RecordSettings::new("st")).unwrap();
        let e = rec.fused("../x", &FusedState::default(), 0).unwrap_err();
        assert!(e.to_string().starts_with("RecordError::RobotId: "), "{e}");
        assert!(!dir.join("../x").exists());
        let file = dir.join("file");
        std::fs::write(&file, "x").unwrap();
        let e = FleetRecorder::open(&file, RecordSettings::new("st")).unwrap_err();
        assert!(e.to_string().starts_with("RecorderOpenError::Dir: "), "{e}");
        let mut bad = RecordSettings::new("st");
        bad.segments.max_segment_bytes = 1;
        let e = FleetRecorder::open(&dir, bad).unwrap_err();
        assert!(
            e.to_string().starts_with("RecorderOpenError::Segments: "),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
