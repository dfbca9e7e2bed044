//! The insuwb log format: `insuwb-msg` samples as postcard [`Record`]s framed
//! with length and CRC-32 after a versioned file header; [`LogWriter`] for one
//! file, [`SegmentWriter`] for the logger's rotating run directory, and
//! [`LogReader`] / [`read_all`] / [`read_segments`], which stop cleanly at a
//! torn or corrupted tail and say where ([`TailReport`]); [`read_header_file`]
//! reads a file's header (its metadata) alone.
//!
//! ```
//! use insuwb_log::{read_all, LogWriter, Metadata, Record};
//! use insuwb_msg::{Header, ImuSample};
//! let path = std::env::temp_dir().join(format!("insuwb-log-doc-{}.iulog", std::process::id()));
//! let _ = std::fs::remove_file(&path);
//! let meta = Metadata::new("doc example").with("seed", "7");
//! let mut w = LogWriter::create(&path, &meta, 0)?; // 0: the caller's monotonic ns
//! let imu = Record::Imu(ImuSample {
//!     header: Header::new(0, 5_000_000),
//!     accel_mps2: [0.0, 0.0, 9.81],
//!     gyro_rps: [0.0; 3],
//! });
//! w.append(&imu)?;
//! w.finish()?;
//! let (records, tail, header) = read_all(&path)?;
//! assert_eq!(records, vec![imu]);
//! assert!(tail.is_none());
//! assert_eq!(header.meta, meta);
//! std::fs::remove_file(&path)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Errors: every message is whole (what failed, the file, the cause), and
//! no error exposes its cause as [`std::error::Error::source`], so a report
//! that prints the chain (`anyhow`'s `{:#}`) shows each cause once, and
//! `to_string()` loses nothing. The I/O errors stay in the variants' `error`
//! fields (see `io_kind`).
//!
//! The byte-level specification follows (the same text as `docs/LOG_FORMAT.md`).
//!
#![doc = include_str!("../../../docs/LOG_FORMAT.md")]
#![warn(missing_docs)]

mod format;
mod reader;
mod record;
mod segment;
mod writer;

pub use format::{
    encode_header, is_log, read_header, EncodeError, HeaderEncodeError, HeaderError, LogHeader,
    Metadata, RecordEncoder, FIXED_HEADER_LEN, FORMAT_VERSION, FRAME_HEADER_LEN, MAGIC,
    MAX_META_LEN, MAX_RECORD_LEN,
};
pub use reader::{
    read_all, read_header_file, LogReader, OpenError, ReadError, TailReason, TailReport,
};
pub use record::Record;
pub use segment::{
    list_segments, parse_segment_name, read_segments, segment_file_name, FlushPolicy,
    ReadSegmentsError, SegmentConfig, SegmentConfigError, SegmentFile, SegmentSummary,
    SegmentWriter, SegmentsRead, MIN_SEGMENT_BYTES, SEGMENT_EXT,
};
pub use writer::{CreateError, LogWriter, WriteError, DIR_MODE, FILE_MODE};
