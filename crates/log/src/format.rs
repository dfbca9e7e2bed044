//! Byte-level format: the file header ([`LogHeader`], [`Metadata`]) and the
//! record framing ([`RecordEncoder`]). See the crate documentation for the layout.

use std::collections::BTreeMap;
use std::fmt;
use std::io::{self, Read};

use postcard::ser_flavors::Flavor;
use serde::{Deserialize, Serialize};

use crate::record::Record;

/// The first eight bytes of every log file.
pub const MAGIC: [u8; 8] = *b"INSUWBLG";
/// Version of the file layout (header and framing) written and read by this crate.
pub const FORMAT_VERSION: u16 = 1;
/// Length of the fixed part of the file header, bytes (magic to metadata CRC).
pub const FIXED_HEADER_LEN: usize = 28;
/// Largest metadata block accepted, bytes.
pub const MAX_META_LEN: u32 = 64 * 1024;
/// Length of a record frame header (payload length + CRC), bytes.
pub const FRAME_HEADER_LEN: usize = 8;
/// Largest record payload accepted, bytes. Every current record is under 1 KiB;
/// a larger length field is corruption and is refused before any allocation.
pub const MAX_RECORD_LEN: u32 = 64 * 1024;

/// Free-form description of a log, stored postcard-encoded in the file header.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Metadata {
    /// What produced the log (e.g. `logger on robot-3`, `sim seed=7`).
    pub source: String,
    /// Free key/value pairs (kept sorted by key, so the encoding is deterministic).
    pub entries: BTreeMap<String, String>,
}

impl Metadata {
    /// Metadata with the given source description and no entries.
    #[must_use]
    pub fn new(source: impl Into<String>) -> Self {
        Self {
            source: source.into(),
            entries: BTreeMap::new(),
        }
    }

    /// Adds (or replaces) a key/value pair.
    #[must_use]
    pub fn with(mut self, key: impl Into<String>, value: impl Into<String>) -> Self {
        self.entries.insert(key.into(), value.into());
        self
    }
}

/// The decoded file header of a log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogHeader {
    /// Format version of the file ([`FORMAT_VERSION`]).
    pub format_version: u16,
    /// `insuwb_msg::LAYOUT_VERSION` of the records in the file.
    pub layout_version: u16,
    /// CLOCK_MONOTONIC nanoseconds at which the writer created the file.
    pub created_ns: u64,
    /// The metadata block.
    pub meta: Metadata,
    /// Length of the whole header in bytes: where the first record starts.
    pub header_len: u64,
}

/// Error encoding a file header.
#[derive(Debug, thiserror::Error)]
pub enum HeaderEncodeError {
    /// The encoded metadata exceeds [`MAX_META_LEN`].
    #[error("log metadata too large: encoded length exceeds the maximum of {max} bytes")]
    MetaTooLarge {
        /// The maximum ([`MAX_META_LEN`]).
        max: u32,
    },
    /// postcard refused the metadata.
    #[error("cannot encode log metadata: {0}")]
    Encode(postcard::Error),
}

/// Error decoding the file header of a log.
#[derive(Debug, thiserror::Error)]
pub enum HeaderError {
    /// The file holds no byte at all.
    #[error("empty file: not an insuwb log")]
    Empty,
    /// The first bytes are not [`MAGIC`].
    #[error("not an insuwb log: magic mismatch, expected {:?}, first bytes are {}", String::from_utf8_lossy(&MAGIC), ShowBytes(found))]
    BadMagic {
        /// The first (up to eight) bytes of the file.
        found: Vec<u8>,
    },
    /// The file ends inside its header.
    #[error("truncated log header: {have} bytes, the header needs {need}")]
    Truncated {
        /// Bytes present.
        have: u64,
        /// Bytes needed to complete the header.
        need: u64,
    },
    /// The format version is not [`FORMAT_VERSION`].
    #[error("log format version {found} not supported (this reader supports {supported})")]
    FormatVersion {
        /// Version in the file.
        found: u16,
        /// The supported version.
        supported: u16,
    },
    /// The record layout version is not `insuwb_msg::LAYOUT_VERSION`.
    #[error("log record layout version {found} not supported (this reader supports {supported})")]
    LayoutVersion {
        /// Version in the file.
        found: u16,
        /// The supported version.
        supported: u16,
    },
    /// The metadata length field exceeds [`MAX_META_LEN`].
    #[error("log metadata length {len} exceeds the maximum of {max} bytes")]
    MetaTooLarge {
        /// Length field read.
        len: u32,
        /// The maximum.
        max: u32,
    },
    /// The metadata CRC does not match.
    #[error("log metadata CRC mismatch: stored {stored:#010x}, computed {computed:#010x}")]
    MetaCrc {
        /// CRC stored in the header.
        stored: u32,
        /// CRC of the bytes read.
        computed: u32,
    },
    /// The metadata block does not decode.
    #[error("log metadata does not decode: {0}")]
    MetaDecode(postcard::Error),
    /// Reading the header failed.
    #[error("I/O error reading the log header: {0}")]
    Io(io::Error),
}

/// Not `#[from]`: that would also expose the I/O error as the source, and a
/// report printing the chain would show it twice (see the crate doc on errors).
impl From<io::Error> for HeaderError {
    fn from(e: io::Error) -> Self {
        Self::Io(e)
    }
}

/// Hex + escaped-ASCII rendering of a few bytes, for error messages.
struct ShowBytes<'a>(&'a [u8]);

impl fmt::Display for ShowBytes<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, b) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{b:02x}")?;
        }
        f.write_str(" (\"")?;
        for b in self.0 {
            write!(f, "{}", b.escape_ascii())?;
        }
        f.write_str("\")")
    }
}

/// Encodes the complete file header (fixed part + metadata block).
///
/// # Errors
/// [`HeaderEncodeError::MetaTooLarge`] when the encoded metadata exceeds [`MAX_META_LEN`].
pub fn encode_header(created_ns: u64, meta: &Metadata) -> Result<Vec<u8>, HeaderEncodeError> {
    let limit = FIXED_HEADER_LEN + MAX_META_LEN as usize;
    let mut out = Vec::with_capacity(FIXED_HEADER_LEN + 64);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&insuwb_msg::LAYOUT_VERSION.to_le_bytes());
    out.extend_from_slice(&created_ns.to_le_bytes());
    out.extend_from_slice(&[0u8; 8]); // length + CRC, filled below
    postcard::serialize_with_flavor(meta, BoundedVec::new(&mut out, limit)).map_err(
        |e| match e {
            postcard::Error::SerializeBufferFull => {
                HeaderEncodeError::MetaTooLarge { max: MAX_META_LEN }
            }
            other => HeaderEncodeError::Encode(other),
        },
    )?;
    let Some((fixed, meta_bytes)) = out.split_first_chunk_mut::<FIXED_HEADER_LEN>() else {
        return Err(HeaderEncodeError::Encode(
            postcard::Error::SerializeBufferFull,
        ));
    };
    // meta_bytes.len() <= MAX_META_LEN by the flavor's limit, so it fits a u32.
    let meta_len = u32::try_from(meta_bytes.len())
        .map_err(|_| HeaderEncodeError::MetaTooLarge { max: MAX_META_LEN })?;
    let crc = crc32fast::hash(meta_bytes);
    put_u32(&mut fixed[20..24], meta_len);
    put_u32(&mut fixed[24..28], crc);
    Ok(out)
}

fn put_u32(dst: &mut [u8], v: u32) {
    for (d, s) in dst.iter_mut().zip(v.to_le_bytes()) {
        *d = s;
    }
}

/// Reads until `buf` is full or the input ends; returns the bytes read.
pub(crate) fn read_full<R: Read + ?Sized>(r: &mut R, buf: &mut [u8]) -> io::Result<usize> {
    let mut n = 0;
    while let Some(rest) = buf.get_mut(n..) {
        if rest.is_empty() {
            break;
        }
        match r.read(rest) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// Reads and checks the file header from the start of `r`.
///
/// # Errors
/// A [`HeaderError`] naming what is wrong: empty input, magic mismatch (with
/// the bytes found), truncation, unsupported versions, bad metadata.
pub fn read_header<R: Read + ?Sized>(r: &mut R) -> Result<LogHeader, HeaderError> {
    let mut fixed = [0u8; FIXED_HEADER_LEN];
    let n = read_full(r, &mut fixed)?;
    if n == 0 {
        return Err(HeaderError::Empty);
    }
    let magic_part = fixed.get(..MAGIC.len().min(n)).unwrap_or(&[]);
    if !MAGIC.starts_with(magic_part) {
        return Err(HeaderError::BadMagic {
            found: magic_part.to_vec(),
        });
    }
    if n < FIXED_HEADER_LEN {
        return Err(HeaderError::Truncated {
            have: n as u64,
            need: FIXED_HEADER_LEN as u64,
        });
    }
    let [_, _, _, _, _, _, _, _, v0, v1, l0, l1, c0, c1, c2, c3, c4, c5, c6, c7, m0, m1, m2, m3, k0, k1, k2, k3] =
        fixed;
    let format_version = u16::from_le_bytes([v0, v1]);
    let layout_version = u16::from_le_bytes([l0, l1]);
    let created_ns = u64::from_le_bytes([c0, c1, c2, c3, c4, c5, c6, c7]);
    let meta_len = u32::from_le_bytes([m0, m1, m2, m3]);
    let meta_crc = u32::from_le_bytes([k0, k1, k2, k3]);
    if format_version != FORMAT_VERSION {
        return Err(HeaderError::FormatVersion {
            found: format_version,
            supported: FORMAT_VERSION,
        });
    }
    if layout_version != insuwb_msg::LAYOUT_VERSION {
        return Err(HeaderError::LayoutVersion {
            found: layout_version,
            supported: insuwb_msg::LAYOUT_VERSION,
        });
    }
    if meta_len > MAX_META_LEN {
        return Err(HeaderError::MetaTooLarge {
            len: meta_len,
            max: MAX_META_LEN,
        });
    }
    let mut meta_bytes = vec![0u8; meta_len as usize];
    let got = read_full(r, &mut meta_bytes)?;
    let header_len = FIXED_HEADER_LEN as u64 + u64::from(meta_len);
    if got < meta_bytes.len() {
        return Err(HeaderError::Truncated {
            have: FIXED_HEADER_LEN as u64 + got as u64,
            need: header_len,
        });
    }
    let computed = crc32fast::hash(&meta_bytes);
    if computed != meta_crc {
        return Err(HeaderError::MetaCrc {
            stored: meta_crc,
            computed,
        });
    }
    let meta = match postcard::take_from_bytes::<Metadata>(&meta_bytes) {
        Ok((m, [])) => m,
        Ok(_) => {
            return Err(HeaderError::MetaDecode(
                postcard::Error::DeserializeBadEncoding,
            ))
        }
        Err(e) => return Err(HeaderError::MetaDecode(e)),
    };
    Ok(LogHeader {
        format_version,
        layout_version,
        created_ns,
        meta,
        header_len,
    })
}

/// `true` when `bytes` starts with the log [`MAGIC`] (format sniffing).
#[must_use]
pub fn is_log(bytes: &[u8]) -> bool {
    bytes.starts_with(&MAGIC)
}

/// postcard output into a borrowed `Vec`, refusing to grow past `limit` bytes.
struct BoundedVec<'a> {
    buf: &'a mut Vec<u8>,
    limit: usize,
}

impl<'a> BoundedVec<'a> {
    fn new(buf: &'a mut Vec<u8>, limit: usize) -> Self {
        Self { buf, limit }
    }
}

impl Flavor for BoundedVec<'_> {
    type Output = ();

    fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
        if self.buf.len().saturating_add(data.len()) > self.limit {
            return Err(postcard::Error::SerializeBufferFull);
        }
        self.buf.extend_from_slice(data);
        Ok(())
    }

    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        if self.buf.len() >= self.limit {
            return Err(postcard::Error::SerializeBufferFull);
        }
        self.buf.push(data);
        Ok(())
    }

    fn finalize(self) -> postcard::Result<()> {
        Ok(())
    }
}

/// Error encoding a record.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The payload would exceed [`MAX_RECORD_LEN`].
    #[error("record too large: payload exceeds the maximum of {max} bytes")]
    TooLarge {
        /// The maximum ([`MAX_RECORD_LEN`]).
        max: u32,
    },
    /// postcard refused the record.
    #[error("cannot encode record: {0}")]
    Encode(postcard::Error),
}

/// Encodes and frames records into a reused buffer.
///
/// After the first record of each size the buffer does not grow: encoding
/// allocates nothing in the steady state.
#[derive(Debug, Clone)]
pub struct RecordEncoder {
    buf: Vec<u8>,
}

impl Default for RecordEncoder {
    fn default() -> Self {
        Self::new()
    }
}

impl RecordEncoder {
    /// Initial buffer capacity: larger than any current record's frame.
    const INITIAL_CAPACITY: usize = 1024;

    /// An encoder with a buffer large enough for every current record type.
    #[must_use]
    pub fn new() -> Self {
        Self {
            buf: Vec::with_capacity(Self::INITIAL_CAPACITY),
        }
    }

    /// Encodes `rec` and returns the complete frame: u32 LE payload length,
    /// u32 LE CRC-32 of the payload, the postcard payload.
    ///
    /// # Errors
    /// [`EncodeError::TooLarge`] when the payload exceeds [`MAX_RECORD_LEN`].
    pub fn encode(&mut self, rec: &Record) -> Result<&[u8], EncodeError> {
        self.buf.clear();
        self.buf.extend_from_slice(&[0u8; FRAME_HEADER_LEN]);
        let limit = FRAME_HEADER_LEN + MAX_RECORD_LEN as usize;
        postcard::serialize_with_flavor(rec, BoundedVec::new(&mut self.buf, limit)).map_err(
            |e| match e {
                postcard::Error::SerializeBufferFull => EncodeError::TooLarge {
                    max: MAX_RECORD_LEN,
                },
                other => EncodeError::Encode(other),
            },
        )?;
        let Some((head, payload)) = self.buf.split_first_chunk_mut::<FRAME_HEADER_LEN>() else {
            return Err(EncodeError::TooLarge {
                max: MAX_RECORD_LEN,
            });
        };
        let len = u32::try_from(payload.len()).map_err(|_| EncodeError::TooLarge {
            max: MAX_RECORD_LEN,
        })?;
        let crc = crc32fast::hash(payload);
        put_u32(&mut head[0..4], len);
        put_u32(&mut head[4..8], crc);
        Ok(&self.buf)
    }

    /// The frame produced by the last successful [`RecordEncoder::encode`].
    pub(crate) fn frame(&self) -> &[u8] {
        &self.buf
    }

    /// Capacity of the internal buffer, bytes (for allocation checks).
    #[must_use]
    pub fn capacity(&self) -> usize {
        self.buf.capacity()
    }
}
