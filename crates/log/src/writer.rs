//! Writing one log file: [`LogWriter`], and the errors of creating and writing logs.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::format::{encode_header, EncodeError, HeaderEncodeError, Metadata, RecordEncoder};
use crate::record::Record;
use crate::segment::SegmentConfigError;

/// Permission bits of log files (owner read/write only).
pub const FILE_MODE: u32 = 0o600;
/// Permission bits of run directories created by [`crate::SegmentWriter`].
pub const DIR_MODE: u32 = 0o700;
/// Capacity of the write buffer in front of the file, bytes.
const WRITE_BUFFER: usize = 64 * 1024;

/// Error creating a log file or a segment directory.
#[derive(Debug, thiserror::Error)]
pub enum CreateError {
    /// The path cannot hold a log (empty, no file name, a directory, a file where a directory is needed).
    #[error("bad log path {path:?}: {reason}")]
    BadPath {
        /// The path given.
        path: PathBuf,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// The file cannot be created (its kind is kept: `AlreadyExists`, `NotFound`, `PermissionDenied`...).
    #[error("cannot create log {path:?}: {error}")]
    Open {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// The run directory cannot be created.
    #[error("cannot create log directory {path:?}: {error}")]
    CreateDir {
        /// The directory.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// The run directory cannot be listed.
    #[error("cannot list log directory {path:?}: {error}")]
    ListDir {
        /// The directory.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// Writing the file header failed (disk full shows as kind `StorageFull`).
    #[error("cannot write the header of log {path:?}: {error}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// The metadata cannot be encoded.
    #[error(transparent)]
    Header(#[from] HeaderEncodeError),
    /// The segment configuration is invalid.
    #[error(transparent)]
    Config(#[from] SegmentConfigError),
}

impl CreateError {
    /// The kind of the underlying I/O error, if any.
    #[must_use]
    pub fn io_kind(&self) -> Option<io::ErrorKind> {
        match self {
            Self::Open { error, .. }
            | Self::CreateDir { error, .. }
            | Self::ListDir { error, .. }
            | Self::Write { error, .. } => Some(error.kind()),
            Self::BadPath { .. } | Self::Header(_) | Self::Config(_) => None,
        }
    }
}

/// Error appending to, flushing or syncing a log.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// Writing to the file failed (disk full shows as kind `StorageFull`, i.e. ENOSPC).
    #[error("cannot write log {path:?}: {error}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// fsync failed.
    #[error("cannot sync log {path:?}: {error}")]
    Sync {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        error: io::Error,
    },
    /// The record cannot be encoded.
    #[error(transparent)]
    Encode(#[from] EncodeError),
    /// Opening the next segment failed (rotation or restart after an error).
    #[error("cannot open the next log segment: {0}")]
    Rotate(CreateError),
}

impl WriteError {
    /// The kind of the underlying I/O error, if any.
    #[must_use]
    pub fn io_kind(&self) -> Option<io::ErrorKind> {
        match self {
            Self::Write { error, .. } | Self::Sync { error, .. } => Some(error.kind()),
            Self::Rotate(e) => e.io_kind(),
            Self::Encode(_) => None,
        }
    }

    /// `true` when the error is a full disk (ENOSPC).
    #[must_use]
    pub fn is_storage_full(&self) -> bool {
        self.io_kind() == Some(io::ErrorKind::StorageFull)
    }
}

/// Writer of one log file.
///
/// The header is written and flushed at creation; records are framed into a
/// reused buffer and written through a 64 KiB buffer, so [`LogWriter::append`]
/// allocates nothing in the steady state. Call [`LogWriter::flush`] (or
/// [`LogWriter::finish`]) to push buffered records to the file; dropping the
/// writer flushes too, ignoring errors.
#[derive(Debug)]
pub struct LogWriter {
    path: PathBuf,
    out: BufWriter<File>,
    enc: RecordEncoder,
    bytes: u64,
    records: u64,
}

fn write_frame(out: &mut BufWriter<File>, path: &Path, frame: &[u8]) -> Result<(), WriteError> {
    out.write_all(frame).map_err(|error| WriteError::Write {
        path: path.to_path_buf(),
        error,
    })
}

/// Checks that `path` can name a new file.
fn check_file_path(path: &Path) -> Result<(), CreateError> {
    let bad = |reason| {
        Err(CreateError::BadPath {
            path: path.to_path_buf(),
            reason,
        })
    };
    if path.as_os_str().is_empty() {
        return bad("empty path");
    }
    if path.file_name().is_none() {
        return bad("no file name");
    }
    if path.is_dir() {
        return bad("is a directory");
    }
    Ok(())
}

/// Creates `path` (which must not exist) with mode [`FILE_MODE`].
pub(crate) fn create_file(path: &Path) -> Result<File, CreateError> {
    let mut opts = OpenOptions::new();
    opts.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.mode(FILE_MODE);
    }
    opts.open(path).map_err(|error| CreateError::Open {
        path: path.to_path_buf(),
        error,
    })
}

impl LogWriter {
    /// Creates a new log file (refusing to overwrite an existing one) with
    /// mode 0600 and writes its header.
    ///
    /// `created_ns` is the caller's CLOCK_MONOTONIC time (the crate reads no clock).
    ///
    /// # Errors
    /// [`CreateError`]: bad path, the file exists or cannot be created, the
    /// header cannot be written, the metadata is too large.
    pub fn create(
        path: impl AsRef<Path>,
        meta: &Metadata,
        created_ns: u64,
    ) -> Result<Self, CreateError> {
        let path = path.as_ref();
        check_file_path(path)?;
        let header = encode_header(created_ns, meta)?;
        let file = create_file(path)?;
        Self::start(path.to_path_buf(), file, &header)
    }

    /// Writes the encoded `header` to `file` and flushes it.
    pub(crate) fn start(path: PathBuf, file: File, header: &[u8]) -> Result<Self, CreateError> {
        let mut out = BufWriter::with_capacity(WRITE_BUFFER, file);
        if let Err(error) = out.write_all(header).and_then(|()| out.flush()) {
            return Err(CreateError::Write { path, error });
        }
        Ok(Self {
            path,
            out,
            enc: RecordEncoder::new(),
            bytes: header.len() as u64,
            records: 0,
        })
    }

    /// Appends one record (buffered).
    ///
    /// # Errors
    /// [`WriteError::Write`] when the buffer must be flushed and the write
    /// fails; the file then still holds a prefix of whole frames plus at most
    /// one torn frame, which the reader reports.
    pub fn append(&mut self, rec: &Record) -> Result<(), WriteError> {
        let frame = self.enc.encode(rec)?;
        write_frame(&mut self.out, &self.path, frame)?;
        self.bytes += frame.len() as u64;
        self.records += 1;
        Ok(())
    }

    /// Writes an already framed record (from a [`RecordEncoder`]).
    pub(crate) fn append_frame(&mut self, frame: &[u8]) -> Result<(), WriteError> {
        write_frame(&mut self.out, &self.path, frame)?;
        self.bytes += frame.len() as u64;
        self.records += 1;
        Ok(())
    }

    /// Pushes buffered records to the file (no fsync).
    ///
    /// # Errors
    /// [`WriteError::Write`] when the write fails (kind kept, e.g. `StorageFull`).
    pub fn flush(&mut self) -> Result<(), WriteError> {
        self.out.flush().map_err(|error| WriteError::Write {
            path: self.path.clone(),
            error,
        })
    }

    /// Flushes, then fsyncs the file (data and metadata).
    ///
    /// # Errors
    /// [`WriteError::Write`] or [`WriteError::Sync`].
    pub fn sync(&mut self) -> Result<(), WriteError> {
        self.flush()?;
        self.out
            .get_ref()
            .sync_all()
            .map_err(|error| WriteError::Sync {
                path: self.path.clone(),
                error,
            })
    }

    /// Flushes and closes the file (no fsync; call [`LogWriter::sync`] first for that).
    ///
    /// # Errors
    /// [`WriteError::Write`] when the final flush fails.
    pub fn finish(mut self) -> Result<(), WriteError> {
        self.flush()
    }

    /// The file's path.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes written so far, header included (buffered bytes count).
    #[must_use]
    pub fn bytes_written(&self) -> u64 {
        self.bytes
    }

    /// Records appended so far.
    #[must_use]
    pub fn records_written(&self) -> u64 {
        self.records
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::ImuSample;

    /// /dev/full answers every write with ENOSPC.
    fn dev_full() -> Option<File> {
        OpenOptions::new().write(true).open("/dev/full").ok()
    }

    #[test]
    fn disk_full_at_create_keeps_the_kind() {
        let Some(file) = dev_full() else { return };
        let header = encode_header(0, &Metadata::new("x")).unwrap();
        let err = LogWriter::start(PathBuf::from("/dev/full"), file, &header).unwrap_err();
        assert!(matches!(err, CreateError::Write { .. }), "{err}");
        assert_eq!(err.io_kind(), Some(io::ErrorKind::StorageFull), "{err}");
    }

    #[test]
    fn disk_full_at_write_keeps_the_kind() {
        let Some(file) = dev_full() else { return };
        let mut w = LogWriter {
            path: PathBuf::from("/dev/full"),
            out: BufWriter::with_capacity(WRITE_BUFFER, file),
            enc: RecordEncoder::new(),
            bytes: 0,
            records: 0,
        };
        // Buffered: the append itself succeeds, the flush hits the disk.
        w.append(&Record::Imu(ImuSample::default())).unwrap();
        let err = w.flush().unwrap_err();
        assert!(matches!(err, WriteError::Write { .. }), "{err}");
        assert!(err.is_storage_full(), "{err}");
        // With a full buffer the append reports it.
        let rec = Record::Imu(ImuSample::default());
        let mut failed = None;
        for _ in 0..2 * WRITE_BUFFER / 60 {
            if let Err(e) = w.append(&rec) {
                failed = Some(e);
                break;
            }
        }
        assert!(failed.is_some_and(|e| e.is_storage_full()));
    }

    #[test]
    fn append_does_not_reallocate_the_frame_buffer() {
        let Some(file) = OpenOptions::new().write(true).open("/dev/null").ok() else {
            return;
        };
        let mut w = LogWriter::start(PathBuf::from("/dev/null"), file, b"").unwrap();
        let rec = Record::Imu(ImuSample::default());
        w.append(&rec).unwrap();
        let cap = w.enc.capacity();
        let ptr = w.enc.frame().as_ptr();
        for _ in 0..10_000 {
            w.append(&rec).unwrap();
        }
        assert_eq!(w.enc.capacity(), cap);
        assert_eq!(w.enc.frame().as_ptr(), ptr);
        assert_eq!(w.out.capacity(), WRITE_BUFFER);
    }
}
