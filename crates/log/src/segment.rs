//! Segmented logs for the logger stage: [`SegmentWriter`] (run directory,
//! `seg-NNNNN.iulog` files, size rotation, flush policy, a new segment per
//! start) and [`read_segments`].

use std::fs::{self, DirBuilder};
use std::io;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::format::{encode_header, HeaderError, LogHeader, Metadata, RecordEncoder};
use crate::reader::{LogReader, OpenError, TailReason, TailReport};
use crate::record::Record;
use crate::writer::{create_file, CreateError, LogWriter, WriteError, DIR_MODE};

/// Extension of segment files.
pub const SEGMENT_EXT: &str = "iulog";
/// Smallest accepted `max_segment_bytes`.
pub const MIN_SEGMENT_BYTES: u64 = 4096;

/// When a [`SegmentWriter`] pushes buffered records to the file.
///
/// Whatever the policy, records are also written when the 64 KiB buffer
/// fills, on rotation and on [`SegmentWriter::finish`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FlushPolicy {
    /// Flush after this many records since the last flush (none: no count
    /// trigger). Default none (design choice: time bounds the loss instead).
    pub every_records: Option<u32>,
    /// Flush when this many milliseconds of the caller's monotonic clock have
    /// passed since the last flush and records are pending (none: no time
    /// trigger). Default 1000 ms (design choice: a crash loses at most ~1 s).
    pub every_ms: Option<u64>,
    /// fsync after each policy flush (survives power loss, costs a disk
    /// round trip per flush). Default false (design choice).
    pub fsync: bool,
}

impl Default for FlushPolicy {
    fn default() -> Self {
        Self {
            every_records: None,
            every_ms: Some(1000),
            fsync: false,
        }
    }
}

impl FlushPolicy {
    /// Checks the policy.
    ///
    /// # Errors
    /// [`SegmentConfigError`] naming the offending key.
    pub fn validate(&self) -> Result<(), SegmentConfigError> {
        if self.every_records == Some(0) {
            return Err(SegmentConfigError::EveryRecordsZero);
        }
        if self.every_ms == Some(0) {
            return Err(SegmentConfigError::EveryMsZero);
        }
        Ok(())
    }
}

/// Configuration of a [`SegmentWriter`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SegmentConfig {
    /// A segment is closed and the next one opened before a record would take
    /// it past this size, bytes (a segment always takes at least one record).
    /// Default 64 MiB (design choice: tens of minutes of a full pipeline).
    pub max_segment_bytes: u64,
    /// Flush policy.
    pub flush: FlushPolicy,
}

impl Default for SegmentConfig {
    fn default() -> Self {
        Self {
            max_segment_bytes: 64 * 1024 * 1024,
            flush: FlushPolicy::default(),
        }
    }
}

impl SegmentConfig {
    /// Checks the configuration.
    ///
    /// # Errors
    /// [`SegmentConfigError`] naming the offending key and value.
    pub fn validate(&self) -> Result<(), SegmentConfigError> {
        if self.max_segment_bytes < MIN_SEGMENT_BYTES {
            return Err(SegmentConfigError::MaxSegmentBytes {
                got: self.max_segment_bytes,
                min: MIN_SEGMENT_BYTES,
            });
        }
        self.flush.validate()
    }
}

/// Error validating a [`SegmentConfig`] or [`FlushPolicy`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SegmentConfigError {
    /// `max_segment_bytes` below [`MIN_SEGMENT_BYTES`].
    #[error("max_segment_bytes must be >= {min}, got {got}")]
    MaxSegmentBytes {
        /// Value given.
        got: u64,
        /// The minimum.
        min: u64,
    },
    /// `flush.every_records` is zero.
    #[error("flush.every_records must be > 0 (or absent), got 0")]
    EveryRecordsZero,
    /// `flush.every_ms` is zero.
    #[error("flush.every_ms must be > 0 (or absent), got 0")]
    EveryMsZero,
}

/// File name of segment `index`: `seg-00042.iulog`.
#[must_use]
pub fn segment_file_name(index: u32) -> String {
    format!("seg-{index:05}.{SEGMENT_EXT}")
}

/// Index of a segment file name (`seg-` + at least five digits + `.iulog`), if it is one.
#[must_use]
pub fn parse_segment_name(name: &str) -> Option<u32> {
    let digits = name
        .strip_prefix("seg-")?
        .strip_suffix(SEGMENT_EXT)?
        .strip_suffix('.')?;
    if digits.len() < 5 || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// One segment file of a run directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SegmentFile {
    /// Its index (from the name).
    pub index: u32,
    /// Its path.
    pub path: PathBuf,
}

fn list_segment_files(dir: &Path) -> io::Result<Vec<SegmentFile>> {
    let mut out = Vec::new();
    for entry in fs::read_dir(dir)? {
        let entry = entry?;
        let name = entry.file_name();
        let Some(index) = name.to_str().and_then(parse_segment_name) else {
            continue;
        };
        if entry.file_type()?.is_file() {
            out.push(SegmentFile {
                index,
                path: entry.path(),
            });
        }
    }
    out.sort_by_key(|s| s.index);
    Ok(out)
}

/// Lists the segment files of a run directory, in index order.
///
/// # Errors
/// [`ReadSegmentsError::ListDir`] when the directory cannot be read.
pub fn list_segments(dir: impl AsRef<Path>) -> Result<Vec<SegmentFile>, ReadSegmentsError> {
    let dir = dir.as_ref();
    list_segment_files(dir).map_err(|error| ReadSegmentsError::ListDir {
        path: dir.to_path_buf(),
        error,
    })
}

/// Writer of a run directory of segments, for the logger stage.
///
/// Opening it always starts a NEW segment numbered after every existing one
/// (a restarted logger never appends to an old file). Files are created 0600
/// and a created directory 0700. Times are the caller's CLOCK_MONOTONIC ns.
#[derive(Debug)]
pub struct SegmentWriter {
    dir: PathBuf,
    meta: Metadata,
    config: SegmentConfig,
    enc: RecordEncoder,
    current: Option<LogWriter>,
    index: u32,
    next_index: u32,
    segments_opened: u32,
    records: u64,
    records_since_flush: u32,
    last_flush_ns: u64,
}

/// Attempts at a fresh segment name when another process races us.
const CREATE_ATTEMPTS: u32 = 16;

impl SegmentWriter {
    /// Creates the run directory if needed (mode 0700) and opens a new segment in it.
    ///
    /// # Errors
    /// [`CreateError`]: invalid config, bad path (empty, not a directory),
    /// the directory cannot be created or listed, the segment cannot be created.
    pub fn open(
        dir: impl AsRef<Path>,
        meta: Metadata,
        config: SegmentConfig,
        now_ns: u64,
    ) -> Result<Self, CreateError> {
        config.validate()?;
        let dir = dir.as_ref();
        if dir.as_os_str().is_empty() {
            return Err(CreateError::BadPath {
                path: dir.to_path_buf(),
                reason: "empty path",
            });
        }
        if dir.exists() && !dir.is_dir() {
            return Err(CreateError::BadPath {
                path: dir.to_path_buf(),
                reason: "not a directory",
            });
        }
        let mut builder = DirBuilder::new();
        builder.recursive(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::DirBuilderExt;
            builder.mode(DIR_MODE);
        }
        builder
            .create(dir)
            .map_err(|error| CreateError::CreateDir {
                path: dir.to_path_buf(),
                error,
            })?;
        let mut w = Self {
            dir: dir.to_path_buf(),
            meta,
            config,
            enc: RecordEncoder::new(),
            current: None,
            index: 0,
            next_index: 0,
            segments_opened: 0,
            records: 0,
            records_since_flush: 0,
            last_flush_ns: now_ns,
        };
        w.open_next(now_ns)?;
        Ok(w)
    }

    /// Opens the segment after every existing one.
    fn open_next(&mut self, now_ns: u64) -> Result<(), CreateError> {
        let existing = list_segment_files(&self.dir).map_err(|error| CreateError::ListDir {
            path: self.dir.clone(),
            error,
        })?;
        let exhausted = || CreateError::BadPath {
            path: self.dir.clone(),
            reason: "segment index space exhausted",
        };
        let mut index = match existing.last() {
            Some(last) => last.index.checked_add(1).ok_or_else(exhausted)?,
            None => 0,
        }
        .max(self.next_index);
        let header = encode_header(now_ns, &self.meta)?;
        let mut attempt = 0;
        let (path, file) = loop {
            let path = self.dir.join(segment_file_name(index));
            match create_file(&path) {
                Ok(file) => break (path, file),
                Err(e)
                    if e.io_kind() == Some(io::ErrorKind::AlreadyExists)
                        && attempt + 1 < CREATE_ATTEMPTS =>
                {
                    attempt += 1;
                    index = index.checked_add(1).ok_or_else(exhausted)?;
                }
                Err(e) => return Err(e),
            }
        };
        self.current = Some(LogWriter::start(path, file, &header)?);
        self.index = index;
        self.next_index = index.saturating_add(1);
        self.segments_opened += 1;
        self.records_since_flush = 0;
        self.last_flush_ns = now_ns;
        Ok(())
    }

    /// Closes the current segment (flush, and fsync when the policy says so).
    fn close_current(&mut self) -> Result<(), WriteError> {
        if let Some(mut w) = self.current.take() {
            if self.config.flush.fsync {
                w.sync()?;
            } else {
                w.finish()?;
            }
        }
        Ok(())
    }

    /// Appends one record, rotating first when it would take the segment past
    /// `max_segment_bytes`, then flushing when the policy says so.
    ///
    /// After a failed rotation the next call tries to open a new segment again.
    ///
    /// # Errors
    /// [`WriteError`]: encoding, writing (kind kept, ENOSPC is `StorageFull`),
    /// syncing, or opening the next segment failed.
    pub fn append(&mut self, rec: &Record, now_ns: u64) -> Result<(), WriteError> {
        let frame_len = self.enc.encode(rec)?.len() as u64;
        let rotate = match &self.current {
            None => true,
            Some(w) => {
                w.records_written() > 0
                    && w.bytes_written().saturating_add(frame_len) > self.config.max_segment_bytes
            }
        };
        if rotate {
            self.close_current()?;
            self.open_next(now_ns).map_err(WriteError::Rotate)?;
        }
        let Some(w) = self.current.as_mut() else {
            return Err(WriteError::Rotate(CreateError::BadPath {
                path: self.dir.clone(),
                reason: "no segment open",
            }));
        };
        w.append_frame(self.enc.frame())?;
        self.records += 1;
        self.records_since_flush = self.records_since_flush.saturating_add(1);
        self.tick(now_ns)?;
        Ok(())
    }

    /// Applies the time part of the flush policy without a record (call it
    /// periodically when idle). Returns whether it flushed.
    ///
    /// # Errors
    /// [`WriteError`] when the flush or fsync fails.
    pub fn tick(&mut self, now_ns: u64) -> Result<bool, WriteError> {
        if self.records_since_flush == 0 {
            return Ok(false);
        }
        let p = &self.config.flush;
        let by_count = p
            .every_records
            .is_some_and(|n| self.records_since_flush >= n);
        let by_time = p.every_ms.is_some_and(|ms| {
            now_ns.saturating_sub(self.last_flush_ns) >= ms.saturating_mul(1_000_000)
        });
        if !(by_count || by_time) {
            return Ok(false);
        }
        let fsync = p.fsync;
        if let Some(w) = self.current.as_mut() {
            if fsync {
                w.sync()?;
            } else {
                w.flush()?;
            }
        }
        self.records_since_flush = 0;
        self.last_flush_ns = now_ns;
        Ok(true)
    }

    /// Pushes buffered records to the current segment (no fsync).
    ///
    /// # Errors
    /// [`WriteError::Write`].
    pub fn flush(&mut self) -> Result<(), WriteError> {
        match self.current.as_mut() {
            Some(w) => w.flush(),
            None => Ok(()),
        }
    }

    /// Flushes and fsyncs the current segment.
    ///
    /// # Errors
    /// [`WriteError::Write`] or [`WriteError::Sync`].
    pub fn sync(&mut self) -> Result<(), WriteError> {
        match self.current.as_mut() {
            Some(w) => w.sync(),
            None => Ok(()),
        }
    }

    /// Closes the current segment: flush, and fsync when the policy says so.
    ///
    /// # Errors
    /// [`WriteError`] when the flush or fsync fails.
    pub fn finish(mut self) -> Result<(), WriteError> {
        self.close_current()
    }

    /// The run directory.
    #[must_use]
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Path of the segment being written (none after a failed rotation).
    #[must_use]
    pub fn current_path(&self) -> Option<&Path> {
        self.current.as_ref().map(LogWriter::path)
    }

    /// Index of the segment being written (or last opened).
    #[must_use]
    pub fn segment_index(&self) -> u32 {
        self.index
    }

    /// Segments opened by this writer.
    #[must_use]
    pub fn segments_opened(&self) -> u32 {
        self.segments_opened
    }

    /// Records appended by this writer, all segments together.
    #[must_use]
    pub fn records_written(&self) -> u64 {
        self.records
    }
}

/// Error reading a run directory.
#[derive(Debug, thiserror::Error)]
pub enum ReadSegmentsError {
    /// The directory cannot be listed.
    #[error("cannot list log directory {path:?}: {error}")]
    ListDir {
        /// The directory.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// A segment cannot be opened or read (not a log, unsupported version, I/O).
    #[error(transparent)]
    Segment(#[from] OpenError),
}

/// What was read from one segment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SegmentSummary {
    /// Segment index.
    pub index: u32,
    /// Segment path.
    pub path: PathBuf,
    /// Its header (none when the file ends inside it: a logger stopped while creating it).
    pub header: Option<LogHeader>,
    /// Records read from it.
    pub records: u64,
    /// Where and why it ends damaged, if it does.
    pub tail: Option<TailReport>,
}

/// Records of a run directory and a summary per segment.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentsRead {
    /// All records, segment after segment, in file order.
    pub records: Vec<Record>,
    /// One summary per segment, in index order.
    pub segments: Vec<SegmentSummary>,
}

impl SegmentsRead {
    /// Tail reports of the segments that end damaged.
    pub fn tails(&self) -> impl Iterator<Item = (&Path, &TailReport)> {
        self.segments
            .iter()
            .filter_map(|s| s.tail.as_ref().map(|t| (s.path.as_path(), t)))
    }
}

/// Reads every `seg-*.iulog` file of a run directory in index order.
///
/// A damaged tail ends that segment's records (see its summary) and reading
/// goes on with the next segment; a segment cut inside its header (empty
/// included) counts as a damaged tail at offset 0.
///
/// # Errors
/// [`ReadSegmentsError`]: the directory cannot be listed, a segment is not a
/// log or has an unsupported version, a read fails.
pub fn read_segments(dir: impl AsRef<Path>) -> Result<SegmentsRead, ReadSegmentsError> {
    let mut out = SegmentsRead {
        records: Vec::new(),
        segments: Vec::new(),
    };
    for seg in list_segments(dir)? {
        let mut reader = match LogReader::open(&seg.path) {
            Ok(r) => r,
            Err(OpenError::Header { error, .. })
                if matches!(error, HeaderError::Empty | HeaderError::Truncated { .. }) =>
            {
                let have = match error {
                    HeaderError::Truncated { have, .. } => have,
                    _ => 0,
                };
                out.segments.push(SegmentSummary {
                    index: seg.index,
                    path: seg.path,
                    header: None,
                    records: 0,
                    tail: Some(TailReport {
                        last_good_offset: 0,
                        bytes_ignored: have,
                        reason: TailReason::TruncatedHeader,
                    }),
                });
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        for rec in reader.by_ref() {
            match rec {
                Ok(r) => out.records.push(r),
                Err(error) => {
                    return Err(OpenError::Read {
                        path: seg.path,
                        error,
                    }
                    .into())
                }
            }
        }
        out.segments.push(SegmentSummary {
            index: seg.index,
            path: seg.path,
            header: Some(reader.header().clone()),
            records: reader.records_read(),
            tail: reader.tail().cloned(),
        });
    }
    Ok(out)
}
