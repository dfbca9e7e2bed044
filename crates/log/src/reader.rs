//! Reading logs: [`LogReader`] (streaming, torn-tail tolerant),
//! [`read_all`] and, for a log's metadata alone, [`read_header_file`].

use std::fmt;
use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::{Path, PathBuf};

use crate::format::{
    read_full, read_header, HeaderError, LogHeader, FRAME_HEADER_LEN, MAX_RECORD_LEN,
};
use crate::record::Record;

/// Why a reader stopped before the end of the file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TailReason {
    /// The file ends inside a frame header (length + CRC).
    TruncatedFrameHeader {
        /// Bytes of the frame header present.
        have: u64,
    },
    /// The length field is zero or exceeds [`MAX_RECORD_LEN`].
    BadLength {
        /// The length field read.
        len: u32,
    },
    /// The file ends inside a payload.
    TruncatedPayload {
        /// Payload length announced.
        len: u32,
        /// Payload bytes present.
        have: u64,
    },
    /// The payload's CRC-32 does not match the frame's.
    CrcMismatch {
        /// CRC stored in the frame.
        stored: u32,
        /// CRC of the payload read.
        computed: u32,
    },
    /// The payload passed its CRC but does not decode as a record.
    Decode(postcard::Error),
    /// The payload decodes as a record but leaves bytes over.
    TrailingBytes {
        /// Bytes left over.
        extra: u64,
    },
    /// The file ends inside its file header (only reported for segments, see
    /// [`crate::read_segments`]; a single log with a bad header is an open error).
    TruncatedHeader,
}

impl fmt::Display for TailReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TruncatedFrameHeader { have } => {
                write!(
                    f,
                    "file ends inside a frame header ({have} of {FRAME_HEADER_LEN} bytes)"
                )
            }
            Self::BadLength { len } => {
                write!(f, "record length {len} outside 1..={MAX_RECORD_LEN}")
            }
            Self::TruncatedPayload { len, have } => {
                write!(f, "file ends inside a payload ({have} of {len} bytes)")
            }
            Self::CrcMismatch { stored, computed } => {
                write!(
                    f,
                    "CRC mismatch: stored {stored:#010x}, computed {computed:#010x}"
                )
            }
            Self::Decode(e) => write!(f, "payload does not decode: {e}"),
            Self::TrailingBytes { extra } => {
                write!(f, "payload has {extra} bytes after the record")
            }
            Self::TruncatedHeader => f.write_str("file ends inside its header"),
        }
    }
}

/// Where and why reading stopped before the end of the file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TailReport {
    /// Offset just after the last record read whole (the file header's end
    /// when none was): the file can be truncated there to repair it.
    pub last_good_offset: u64,
    /// Bytes from `last_good_offset` to the end of the file, skipped.
    pub bytes_ignored: u64,
    /// What was wrong at `last_good_offset`.
    pub reason: TailReason,
}

impl fmt::Display for TailReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "torn tail at byte {}: {} bytes ignored ({})",
            self.last_good_offset, self.bytes_ignored, self.reason
        )
    }
}

/// Error reading a record (an I/O failure; corruption ends the iteration with a [`TailReport`]).
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The underlying read failed.
    #[error("I/O error reading the log at byte {offset}: {error}")]
    Io {
        /// Offset of the record being read.
        offset: u64,
        /// The I/O error.
        error: io::Error,
    },
}

/// Error opening a log file and reading its header (and, for [`read_all`],
/// reading it whole); each message names the file.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The path cannot be a log file.
    #[error("bad log path {path:?}: {reason}")]
    BadPath {
        /// The path given.
        path: PathBuf,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// The file cannot be opened.
    #[error("cannot open log {path:?}: {error}")]
    Open {
        /// The path given.
        path: PathBuf,
        /// The I/O error (its kind is kept: `NotFound`, `PermissionDenied`...).
        error: io::Error,
    },
    /// The file header is invalid (not a log, unsupported version, truncated).
    #[error("{path:?}: {error}")]
    Header {
        /// The path given.
        path: PathBuf,
        /// What is wrong with the header.
        error: HeaderError,
    },
    /// Reading a record failed ([`read_all`] only).
    #[error("{path:?}: {error}")]
    Read {
        /// The path given.
        path: PathBuf,
        /// The read error.
        error: ReadError,
    },
}

/// Streaming reader: an iterator over the records of a log.
///
/// The iteration ends at the end of the file or at the first damaged frame
/// (torn tail, CRC mismatch, undecodable payload, impossible length); in the
/// latter case [`LogReader::tail`] says where and why. It never panics and
/// never allocates more than one [`MAX_RECORD_LEN`] buffer, whatever the input.
pub struct LogReader<R> {
    inner: R,
    header: LogHeader,
    offset: u64,
    payload: Box<[u8]>,
    tail: Option<TailReport>,
    done: bool,
    records: u64,
}

impl<R> fmt::Debug for LogReader<R> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LogReader")
            .field("header", &self.header)
            .field("offset", &self.offset)
            .field("records", &self.records)
            .field("tail", &self.tail)
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

impl LogReader<BufReader<File>> {
    /// Opens a log file and reads its header.
    ///
    /// # Errors
    /// [`OpenError`]: bad path (a directory), open failure, invalid header.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, OpenError> {
        let path = path.as_ref();
        let file = open_file(path)?;
        Self::from_reader(BufReader::with_capacity(64 * 1024, file)).map_err(|error| {
            OpenError::Header {
                path: path.to_path_buf(),
                error,
            }
        })
    }
}

/// Opens `path` for reading, refusing an empty path and a directory.
fn open_file(path: &Path) -> Result<File, OpenError> {
    if path.as_os_str().is_empty() {
        return Err(OpenError::BadPath {
            path: path.to_path_buf(),
            reason: "empty path",
        });
    }
    if path.is_dir() {
        return Err(OpenError::BadPath {
            path: path.to_path_buf(),
            reason: "is a directory",
        });
    }
    File::open(path).map_err(|error| OpenError::Open {
        path: path.to_path_buf(),
        error,
    })
}

/// Reads a log file's header (format, creation time, metadata) and
/// nothing after it: the records are neither read nor checked, so a log of
/// any size, even one whose body is damaged, costs two reads of its first
/// bytes.
///
/// # Errors
/// [`OpenError`] naming the file: a bad path, an open failure, an invalid
/// or truncated header.
pub fn read_header_file(path: impl AsRef<Path>) -> Result<LogHeader, OpenError> {
    let path = path.as_ref();
    let mut file = open_file(path)?;
    read_header(&mut file).map_err(|error| OpenError::Header {
        path: path.to_path_buf(),
        error,
    })
}

impl<R: Read> LogReader<R> {
    /// Reads the header from `inner` (positioned at the start of a log).
    ///
    /// # Errors
    /// [`HeaderError`] when the header is invalid.
    pub fn from_reader(mut inner: R) -> Result<Self, HeaderError> {
        let header = read_header(&mut inner)?;
        Ok(Self {
            inner,
            offset: header.header_len,
            header,
            payload: vec![0u8; MAX_RECORD_LEN as usize].into_boxed_slice(),
            tail: None,
            done: false,
            records: 0,
        })
    }

    /// The file header.
    #[must_use]
    pub fn header(&self) -> &LogHeader {
        &self.header
    }

    /// Where and why reading stopped early; `None` while reading and after a clean end.
    #[must_use]
    pub fn tail(&self) -> Option<&TailReport> {
        self.tail.as_ref()
    }

    /// Offset just after the last record returned.
    #[must_use]
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// Records returned so far.
    #[must_use]
    pub fn records_read(&self) -> u64 {
        self.records
    }

    /// Ends the iteration with a tail report; `consumed` bytes of the damaged
    /// frame were already read, the rest of the input is counted and skipped.
    fn stop(&mut self, reason: TailReason, consumed: u64) -> Option<Result<Record, ReadError>> {
        self.done = true;
        let mut ignored = consumed;
        let mut failure = None;
        loop {
            match self.inner.read(&mut self.payload) {
                Ok(0) => break,
                Ok(k) => ignored += k as u64,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            }
        }
        self.tail = Some(TailReport {
            last_good_offset: self.offset,
            bytes_ignored: ignored,
            reason,
        });
        failure.map(|error| {
            Err(ReadError::Io {
                offset: self.offset,
                error,
            })
        })
    }

    fn io_error(&mut self, error: io::Error) -> Option<Result<Record, ReadError>> {
        self.done = true;
        Some(Err(ReadError::Io {
            offset: self.offset,
            error,
        }))
    }
}

impl<R: Read> Iterator for LogReader<R> {
    type Item = Result<Record, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let mut head = [0u8; FRAME_HEADER_LEN];
        let n = match read_full(&mut self.inner, &mut head) {
            Ok(n) => n,
            Err(e) => return self.io_error(e),
        };
        if n == 0 {
            self.done = true;
            return None;
        }
        if n < FRAME_HEADER_LEN {
            return self.stop(
                TailReason::TruncatedFrameHeader { have: n as u64 },
                n as u64,
            );
        }
        let [l0, l1, l2, l3, c0, c1, c2, c3] = head;
        let len = u32::from_le_bytes([l0, l1, l2, l3]);
        let stored = u32::from_le_bytes([c0, c1, c2, c3]);
        let frame_head = FRAME_HEADER_LEN as u64;
        if len == 0 || len > MAX_RECORD_LEN {
            return self.stop(TailReason::BadLength { len }, frame_head);
        }
        let Some(buf) = self.payload.get_mut(..len as usize) else {
            return self.stop(TailReason::BadLength { len }, frame_head);
        };
        let got = match read_full(&mut self.inner, buf) {
            Ok(n) => n,
            Err(e) => return self.io_error(e),
        };
        if got < buf.len() {
            return self.stop(
                TailReason::TruncatedPayload {
                    len,
                    have: got as u64,
                },
                frame_head + got as u64,
            );
        }
        let consumed = frame_head + u64::from(len);
        let computed = crc32fast::hash(buf);
        if computed != stored {
            return self.stop(TailReason::CrcMismatch { stored, computed }, consumed);
        }
        match postcard::take_from_bytes::<Record>(buf) {
            Ok((rec, [])) => {
                self.offset += consumed;
                self.records += 1;
                Some(Ok(rec))
            }
            Ok((_, rest)) => {
                let extra = rest.len() as u64;
                self.stop(TailReason::TrailingBytes { extra }, consumed)
            }
            Err(e) => self.stop(TailReason::Decode(e), consumed),
        }
    }
}

/// Reads a whole log file: its records, the tail report if it ends damaged, and its header.
///
/// # Errors
/// [`OpenError`] when the file cannot be opened, its header is invalid, or a read fails.
pub fn read_all(
    path: impl AsRef<Path>,
) -> Result<(Vec<Record>, Option<TailReport>, LogHeader), OpenError> {
    let path = path.as_ref();
    let mut reader = LogReader::open(path)?;
    let mut records = Vec::new();
    for rec in reader.by_ref() {
        records.push(rec.map_err(|error| OpenError::Read {
            path: path.to_path_buf(),
            error,
        })?);
    }
    let tail = reader.tail.take();
    Ok((records, tail, reader.header))
}
