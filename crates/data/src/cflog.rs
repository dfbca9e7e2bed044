//! Reader for the Crazyflie micro-SD binary event log, versions 1 and 2.
//!
//! This module owns the container format only: header (magic `0xBC`, version,
//! event-descriptor table), the packed records and the trailing CRC-32. It
//! knows nothing about what the events mean; [`crate::util`] turns the
//! records into samples.
//!
//! Layout (all little-endian, packed):
//! - byte 0: magic `0xBC`; u16 version (1 or 2); u16 number of event types;
//! - per event type: u16 id; NUL-terminated name; u16 number of variables;
//!   per variable a NUL-terminated `name(T)` with `T` one of `f` (f32),
//!   `B` (u8), `H` (u16), `h` (i16), `b` (i8), `I` (u32), `i` (i32);
//! - records up to the last 4 bytes: u16 event id; timestamp (version 1: u32
//!   milliseconds, version 2: u64 microseconds); the payload, packed per the
//!   variable types;
//! - last 4 bytes: u32 CRC-32 (zlib polynomial) of every byte before it.
//!
//! A log cut short (the logger lost power mid-write) has no CRC and usually
//! ends inside a record: it is read up to its last whole record, and
//! [`CfLog::integrity`] says where it stopped ([`CutReport`]). A whole log
//! whose CRC does not match is refused unless [`ParseOptions::ignore_crc`].
//!
//! The parser never panics and allocates at most in proportion to the input:
//! every count read from the file is bounded by the bytes that remain.

use std::collections::HashMap;

use thiserror::Error;

/// First byte of every Crazyflie event log.
pub const MAGIC: u8 = 0xBC;

/// Length of the trailing CRC-32.
const CRC_LEN: usize = 4;

/// Length of the fixed header: magic, version, event count.
const HEADER_LEN: usize = 5;

/// Smallest possible event descriptor: u16 id, empty name + NUL, u16 count.
const MIN_DESCRIPTOR_LEN: usize = 5;

/// Smallest possible variable spec: `(f)` + NUL.
const MIN_VARIABLE_LEN: usize = 4;

/// Largest event-type count that [`is_cflog`] considers plausible.
const MAX_PLAUSIBLE_EVENTS: u16 = 1024;

/// Longest variable spec quoted back in an error message.
const MAX_QUOTED_SPEC: usize = 64;

/// How [`CfLog::parse`] treats the input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ParseOptions {
    /// Read the records of a whole log even when its trailing CRC-32 does not
    /// match. Default `false`: a mismatch is an error. A log cut short has no
    /// CRC to check and is read up to its last whole record either way.
    pub ignore_crc: bool,
}

/// What follows the last whole record of a log cut short.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CutKind {
    /// Nothing: the file ends right after a whole record (or the header),
    /// without its trailing CRC-32.
    MissingCrc,
    /// The start of a record of a declared event, shorter than a whole record.
    Record {
        /// The record's event id.
        event: u16,
        /// The event's name.
        name: String,
        /// Bytes of the record in the file.
        have: usize,
        /// Length of a whole record of this event.
        len: usize,
    },
    /// One to three bytes that do not start a record of a declared event:
    /// the first bytes of the trailing CRC-32 (or, for a single byte, possibly
    /// half a record's event id).
    PartialCrc {
        /// Bytes present.
        have: usize,
    },
}

impl std::fmt::Display for CutKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::MissingCrc => f.write_str("the file ends after a whole record, without its CRC-32"),
            Self::Record {
                event,
                name,
                have,
                len,
            } => write!(
                f,
                "the file ends inside a record of event {event} ({name}): {have} of its {len} bytes"
            ),
            Self::PartialCrc { have: 1 } => f.write_str(
                "the file ends 1 byte after the last whole record (part of the CRC-32 or of an event id)",
            ),
            Self::PartialCrc { have } => write!(
                f,
                "the file ends inside the trailing CRC-32: {have} of its {CRC_LEN} bytes"
            ),
        }
    }
}

/// Where and why reading a log cut short stopped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CutReport {
    /// Byte offset just after the last whole record (the end of the header
    /// when there is none): every record before it was read, and the file
    /// can be truncated there.
    pub offset: usize,
    /// Bytes from `offset` to the end of the file, not read.
    pub bytes_ignored: usize,
    /// What those bytes are.
    pub kind: CutKind,
}

impl std::fmt::Display for CutReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "cut short at byte {}: {}; {} byte(s) ignored, no CRC to check",
            self.offset, self.kind, self.bytes_ignored
        )
    }
}

/// How a parsed log ends: what its CRC-32 says about the records read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Integrity {
    /// The trailing CRC-32 matches every byte before it.
    CrcOk,
    /// The log is whole but its CRC-32 does not match: some byte is wrong.
    /// Only returned with [`ParseOptions::ignore_crc`].
    CrcMismatch {
        /// CRC stored in the last 4 bytes.
        stored: u32,
        /// CRC computed over the bytes before it.
        computed: u32,
    },
    /// The log was cut short: every whole record was read, nothing checked
    /// them.
    Cut(CutReport),
}

/// Type of one logged variable, from the letter in its `name(T)` spec.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VarType {
    /// `f`: IEEE-754 f32.
    F32,
    /// `B`: u8.
    U8,
    /// `H`: u16.
    U16,
    /// `h`: i16.
    I16,
    /// `b`: i8.
    I8,
    /// `I`: u32.
    U32,
    /// `i`: i32.
    I32,
}

impl VarType {
    /// The type named by a spec letter, `None` for an unknown letter.
    #[must_use]
    pub fn from_letter(letter: u8) -> Option<Self> {
        match letter {
            b'f' => Some(Self::F32),
            b'B' => Some(Self::U8),
            b'H' => Some(Self::U16),
            b'h' => Some(Self::I16),
            b'b' => Some(Self::I8),
            b'I' => Some(Self::U32),
            b'i' => Some(Self::I32),
            _ => None,
        }
    }

    /// The spec letter of this type.
    #[must_use]
    pub fn letter(self) -> char {
        match self {
            Self::F32 => 'f',
            Self::U8 => 'B',
            Self::U16 => 'H',
            Self::I16 => 'h',
            Self::I8 => 'b',
            Self::U32 => 'I',
            Self::I32 => 'i',
        }
    }

    /// Size of one value of this type in a record, bytes.
    #[must_use]
    pub fn size(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::F32 | Self::U32 | Self::I32 => 4,
        }
    }

    /// Decodes one little-endian value of this type from exactly `size()` bytes.
    fn decode(self, b: &[u8]) -> Option<Value> {
        Some(match self {
            Self::F32 => Value::F32(f32::from_le_bytes(b.try_into().ok()?)),
            Self::U8 => Value::U8(*b.first()?),
            Self::I8 => Value::I8(i8::from_le_bytes(b.try_into().ok()?)),
            Self::U16 => Value::U16(u16::from_le_bytes(b.try_into().ok()?)),
            Self::I16 => Value::I16(i16::from_le_bytes(b.try_into().ok()?)),
            Self::U32 => Value::U32(u32::from_le_bytes(b.try_into().ok()?)),
            Self::I32 => Value::I32(i32::from_le_bytes(b.try_into().ok()?)),
        })
    }
}

/// One decoded variable value of a record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    /// f32 value.
    F32(f32),
    /// u8 value.
    U8(u8),
    /// u16 value.
    U16(u16),
    /// i16 value.
    I16(i16),
    /// i8 value.
    I8(i8),
    /// u32 value.
    U32(u32),
    /// i32 value.
    I32(i32),
}

impl Value {
    /// The value as f64 (exact for every type).
    #[must_use]
    pub fn as_f64(self) -> f64 {
        match self {
            Self::F32(v) => f64::from(v),
            Self::U8(v) => f64::from(v),
            Self::U16(v) => f64::from(v),
            Self::I16(v) => f64::from(v),
            Self::I8(v) => f64::from(v),
            Self::U32(v) => f64::from(v),
            Self::I32(v) => f64::from(v),
        }
    }

    /// The value as an unsigned integer: `None` for floats and negative integers.
    #[must_use]
    pub fn as_u32(self) -> Option<u32> {
        match self {
            Self::F32(_) => None,
            Self::U8(v) => Some(u32::from(v)),
            Self::U16(v) => Some(u32::from(v)),
            Self::U32(v) => Some(v),
            Self::I16(v) => u32::try_from(v).ok(),
            Self::I8(v) => u32::try_from(v).ok(),
            Self::I32(v) => u32::try_from(v).ok(),
        }
    }
}

/// One variable of an event type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Variable {
    /// Variable name, e.g. `acc.x`.
    pub name: String,
    /// Its type.
    pub ty: VarType,
}

/// One event type declared in the log header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EventDescriptor {
    /// Event id used by the records.
    pub id: u16,
    /// Event name, e.g. `estAcceleration`.
    pub name: String,
    /// Variables of each record of this event, in payload order.
    pub variables: Vec<Variable>,
    /// Header byte offset where the descriptor starts.
    pub offset: usize,
}

impl EventDescriptor {
    /// Payload length of one record of this event, bytes.
    #[must_use]
    pub fn payload_len(&self) -> usize {
        self.variables.iter().map(|v| v.ty.size()).sum()
    }

    /// Index of the variable called `name`, if any.
    #[must_use]
    pub fn variable_index(&self, name: &str) -> Option<usize> {
        self.variables.iter().position(|v| v.name == name)
    }
}

/// Why a log could not be parsed. Every variant names the byte offset or the
/// value at fault.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CfLogError {
    /// The header ends before a field is complete.
    #[error("log header truncated at byte {offset}: missing {what}")]
    TruncatedHeader {
        /// Byte offset where the field should start.
        offset: usize,
        /// The field that is missing.
        what: &'static str,
    },
    /// Byte 0 is not `0xBC`.
    #[error("not a Crazyflie event log: magic byte is {found:#04x}, expected 0xbc")]
    BadMagic {
        /// The byte found.
        found: u8,
    },
    /// The version is neither 1 nor 2.
    #[error("unsupported Crazyflie log version {version} (supported: 1, 2)")]
    UnsupportedVersion {
        /// The version found.
        version: u16,
    },
    /// The trailing CRC-32 does not match the bytes before it.
    #[error("CRC mismatch: stored {stored:#010x}, computed {computed:#010x}")]
    CrcMismatch {
        /// CRC stored in the last 4 bytes.
        stored: u32,
        /// CRC computed over the bytes before it.
        computed: u32,
    },
    /// A name is not valid UTF-8.
    #[error("{what} at byte {offset} is not valid UTF-8")]
    InvalidName {
        /// Byte offset of the name.
        offset: usize,
        /// Which name (event name, variable spec).
        what: &'static str,
    },
    /// Two descriptors share an event id.
    #[error("event id {id} declared twice (second at byte {offset})")]
    DuplicateEventId {
        /// The repeated id.
        id: u16,
        /// Byte offset of the second descriptor.
        offset: usize,
    },
    /// A variable spec is not of the form `name(T)`.
    #[error("variable spec {spec:?} at byte {offset} is not of the form name(T)")]
    BadVariableSpec {
        /// Byte offset of the spec.
        offset: usize,
        /// The spec (first 64 characters).
        spec: String,
    },
    /// A variable spec names an unknown type letter.
    #[error("variable spec {spec:?} at byte {offset} has unknown type letter {letter:?} (expected one of f B H h b I i)")]
    BadVariableType {
        /// Byte offset of the spec.
        offset: usize,
        /// The unknown letter.
        letter: char,
        /// The spec (first 64 characters).
        spec: String,
    },
    /// A record uses an event id that the header does not declare.
    #[error("record at byte {offset} has undeclared event id {id}")]
    UnknownEventId {
        /// The undeclared id.
        id: u16,
        /// Byte offset of the record.
        offset: usize,
    },
    /// A record's timestamp or payload runs past the end of the record area.
    #[error("record at byte {offset} (event id {event}) is truncated")]
    TruncatedRecord {
        /// Byte offset of the record.
        offset: usize,
        /// Its event id.
        event: u16,
    },
    /// A single byte is left before the CRC, too short for a record's event id.
    #[error("{len} stray byte(s) at byte {offset} before the CRC")]
    TrailingBytes {
        /// Byte offset of the stray bytes.
        offset: usize,
        /// How many.
        len: usize,
    },
}

/// Where a record sits and which event it belongs to (internal).
#[derive(Debug, Clone, Copy)]
struct RawRecord {
    /// Index into `CfLog::events`.
    event: usize,
    /// Timestamp, microseconds.
    time_us: u64,
    /// Byte offset of the record.
    offset: usize,
    /// Index of its first value in `CfLog::values`.
    first_value: usize,
}

/// The header of a log, as needed to walk its records (internal).
struct Layout<'a> {
    /// Format version (1: u32 ms timestamps, 2: u64 us).
    version: u16,
    /// Byte offset of the first record: the end of the header.
    records_at: usize,
    /// The event descriptors.
    events: &'a [EventDescriptor],
    /// Event id to index into `events`.
    index_of: &'a HashMap<u16, usize>,
}

/// Where a walk over the records stopped (internal).
#[derive(Debug, Clone, Copy)]
enum Stop {
    /// At the end of the input, after a whole record (or the header).
    End,
    /// One byte left: not even an event id.
    ShortId,
    /// A record of an event id the header does not declare.
    Unknown {
        /// The id.
        id: u16,
    },
    /// A record of a declared event that runs past the end of the input.
    Partial {
        /// Index into the descriptors.
        event: usize,
        /// The event id.
        id: u16,
        /// Length of a whole record of this event.
        len: usize,
    },
}

/// The whole records found from the header's end, and why the walk stopped (internal).
struct Walk {
    records: Vec<RawRecord>,
    values: Vec<Value>,
    /// Byte offset just after the last whole record: where the walk stopped.
    end: usize,
    /// The input's length.
    input_len: usize,
    stop: Stop,
}

impl Layout<'_> {
    /// Length of one record of the event `desc`: id, timestamp, payload.
    fn record_len(&self, desc: &EventDescriptor) -> usize {
        let time_len = if self.version == 1 { 4 } else { 8 };
        2 + time_len + desc.payload_len()
    }

    /// Reads the records of a whole log or of one cut short (see [`CfLog::parse`]).
    fn read(&self, bytes: &[u8], opts: &ParseOptions) -> Result<(Walk, Integrity), CfLogError> {
        // A whole log: records, then the CRC-32 of every byte before them.
        let crc = bytes
            .len()
            .checked_sub(CRC_LEN)
            .filter(|&n| n >= self.records_at)
            .and_then(|n| {
                let (body, tail) = bytes.split_at(n);
                let stored = u32::from_le_bytes(tail.try_into().ok()?);
                Some((body, stored, crc32fast::hash(body)))
            });
        if let Some((body, stored, computed)) = crc {
            if stored == computed {
                let walk = self.walk(body);
                walk.check_whole()?;
                return Ok((walk, Integrity::CrcOk));
            }
        }
        // No CRC that matches: a log cut short runs its records to its end.
        let walk = self.walk(bytes);
        if let Some(cut) = walk.cut_report(self.events) {
            return Ok((walk, Integrity::Cut(cut)));
        }
        // Not cut: a whole log with a wrong byte, or garbled records.
        let Some((body, stored, computed)) = crc else {
            // Not reached: with no room for a CRC, fewer than 4 bytes follow
            // the last whole record, which reads as a cut.
            walk.check_whole()?;
            return Err(CfLogError::TruncatedHeader {
                offset: bytes.len(),
                what: "CRC-32",
            });
        };
        if !opts.ignore_crc {
            return Err(CfLogError::CrcMismatch { stored, computed });
        }
        let walk = self.walk(body);
        walk.check_whole()?;
        Ok((walk, Integrity::CrcMismatch { stored, computed }))
    }

    /// Decodes the records of `buf` from the header's end while they are whole
    /// and declared. Never fails: [`Walk::stop`] says why it ended.
    fn walk(&self, buf: &[u8]) -> Walk {
        let mut cur = Cursor {
            buf,
            pos: self.records_at,
        };
        let mut records = Vec::new();
        let mut values = Vec::new();
        let mut end = self.records_at;
        let stop = loop {
            let offset = cur.pos;
            if cur.remaining() == 0 {
                break Stop::End;
            }
            let Some(id) = cur.u16() else {
                break Stop::ShortId;
            };
            let Some(event) = self.index_of.get(&id).copied() else {
                break Stop::Unknown { id };
            };
            let Some(desc) = self.events.get(event) else {
                break Stop::Unknown { id };
            };
            let len = self.record_len(desc);
            let time_us = if self.version == 1 {
                cur.u32().map(|ms| u64::from(ms) * 1000)
            } else {
                cur.u64()
            };
            let payload = cur.take(desc.payload_len());
            let partial = Stop::Partial { event, id, len };
            let (Some(time_us), Some(payload)) = (time_us, payload) else {
                break partial;
            };
            let first_value = values.len();
            let mut at = 0usize;
            for var in &desc.variables {
                let size = var.ty.size();
                // Always decodes: the payload holds exactly the variables' sizes.
                let Some(value) = payload.get(at..at + size).and_then(|b| var.ty.decode(b)) else {
                    break;
                };
                values.push(value);
                at += size;
            }
            if values.len() - first_value != desc.variables.len() {
                values.truncate(first_value);
                break partial;
            }
            records.push(RawRecord {
                event,
                time_us,
                offset,
                first_value,
            });
            end = cur.pos;
        };
        Walk {
            records,
            values,
            end,
            input_len: buf.len(),
            stop,
        }
    }
}

impl Walk {
    /// The error of a walk over a log that should be whole up to the CRC:
    /// anything but [`Stop::End`].
    fn check_whole(&self) -> Result<(), CfLogError> {
        let offset = self.end;
        match self.stop {
            Stop::End => Ok(()),
            Stop::ShortId => Err(CfLogError::TrailingBytes {
                offset,
                len: self.input_len - offset,
            }),
            Stop::Unknown { id } => Err(CfLogError::UnknownEventId { id, offset }),
            Stop::Partial { id, .. } => Err(CfLogError::TruncatedRecord { offset, event: id }),
        }
    }

    /// The report of a log cut short, if the walk over the whole file reads
    /// as one: it ran to the end of the file, or stopped at its last bytes,
    /// fewer than a whole record (of a declared event) or than a CRC.
    fn cut_report(&self, events: &[EventDescriptor]) -> Option<CutReport> {
        let have = self.input_len - self.end;
        let kind = match self.stop {
            Stop::End => CutKind::MissingCrc,
            Stop::Partial { event, len, .. } => {
                let desc = events.get(event)?;
                CutKind::Record {
                    event: desc.id,
                    name: desc.name.clone(),
                    have,
                    len,
                }
            }
            Stop::ShortId => CutKind::PartialCrc { have },
            Stop::Unknown { .. } if have < CRC_LEN => CutKind::PartialCrc { have },
            Stop::Unknown { .. } => return None,
        };
        Some(CutReport {
            offset: self.end,
            bytes_ignored: have,
            kind,
        })
    }
}

/// A parsed Crazyflie event log: descriptors and every record, in file order.
#[derive(Debug, Clone)]
pub struct CfLog {
    version: u16,
    events: Vec<EventDescriptor>,
    records: Vec<RawRecord>,
    values: Vec<Value>,
    integrity: Integrity,
}

/// One record of a [`CfLog`].
#[derive(Debug, Clone, Copy)]
pub struct Record<'a> {
    /// The record's event type.
    pub event: &'a EventDescriptor,
    /// Timestamp in microseconds of the logger's clock (version 1 milliseconds
    /// are multiplied by 1000, exactly).
    pub time_us: u64,
    /// Byte offset of the record in the file.
    pub offset: usize,
    /// Decoded values, in the order of `event.variables`.
    pub values: &'a [Value],
}

impl Record<'_> {
    /// The value of the variable called `name`, if the event has one.
    #[must_use]
    pub fn value(&self, name: &str) -> Option<Value> {
        self.values.get(self.event.variable_index(name)?).copied()
    }
}

/// Byte cursor over a slice; every read is checked.
struct Cursor<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.buf.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }

    fn u16(&mut self) -> Option<u16> {
        Some(u16::from_le_bytes(self.take(2)?.try_into().ok()?))
    }

    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }

    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }

    /// A NUL-terminated string (without the NUL).
    fn cstr(&mut self) -> Option<&'a [u8]> {
        let rest = self.buf.get(self.pos..)?;
        let len = rest.iter().position(|&b| b == 0)?;
        let s = rest.get(..len)?;
        self.pos += len + 1;
        Some(s)
    }

    fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }
}

/// Quotes at most [`MAX_QUOTED_SPEC`] characters of a spec for an error message.
fn quote(spec: &[u8]) -> String {
    String::from_utf8_lossy(spec)
        .chars()
        .take(MAX_QUOTED_SPEC)
        .collect()
}

/// Parses one `name(T)` variable spec found at `offset`.
fn parse_variable(spec: &[u8], offset: usize) -> Result<Variable, CfLogError> {
    let bad = || CfLogError::BadVariableSpec {
        offset,
        spec: quote(spec),
    };
    let (name, tail) = match spec.len().checked_sub(3) {
        Some(n) => spec.split_at(n),
        None => return Err(bad()),
    };
    let (open, letter, close) = match tail {
        [o, l, c] => (*o, *l, *c),
        _ => return Err(bad()),
    };
    if open != b'(' || close != b')' {
        return Err(bad());
    }
    let ty = VarType::from_letter(letter).ok_or_else(|| CfLogError::BadVariableType {
        offset,
        letter: char::from(letter),
        spec: quote(spec),
    })?;
    let name = std::str::from_utf8(name).map_err(|_| CfLogError::InvalidName {
        offset,
        what: "variable spec",
    })?;
    Ok(Variable {
        name: name.to_owned(),
        ty,
    })
}

/// Whether `bytes` looks like a Crazyflie event log: magic `0xBC`, version 1
/// or 2, and an event-type count between 1 and 1024 that fits the file. A
/// cheap test for format detection; [`CfLog::parse`] does the full check.
#[must_use]
pub fn is_cflog(bytes: &[u8]) -> bool {
    let (Some(&magic), Some(v), Some(n)) = (bytes.first(), bytes.get(1..3), bytes.get(3..5)) else {
        return false;
    };
    let version = u16::from_le_bytes([v[0], v[1]]);
    let n_events = u16::from_le_bytes([n[0], n[1]]);
    let room = bytes.len().saturating_sub(HEADER_LEN + CRC_LEN);
    magic == MAGIC
        && (version == 1 || version == 2)
        && (1..=MAX_PLAUSIBLE_EVENTS).contains(&n_events)
        && usize::from(n_events) * MIN_DESCRIPTOR_LEN <= room
}

impl CfLog {
    /// Parses a log file: a whole one, or one cut short.
    ///
    /// Checks, in order: the magic, the version, the event descriptors
    /// (unique ids, UTF-8 names, `name(T)` specs with known type letters),
    /// then the records and the CRC:
    /// - when the last 4 bytes are the CRC-32 of the bytes before them, every
    ///   record up to them must be whole and declared ([`Integrity::CrcOk`]);
    /// - otherwise, when the records run to the end of the file and only the
    ///   last one (or the CRC) is incomplete, the log was cut short: its whole
    ///   records are returned with a [`CutReport`] ([`Integrity::Cut`]),
    ///   whatever `opts.ignore_crc`;
    /// - otherwise the log is whole with a wrong byte somewhere: an error
    ///   unless `opts.ignore_crc`, which reads its records anyway
    ///   ([`Integrity::CrcMismatch`]).
    ///
    /// A whole log whose CRC is wrong and starts with a declared event id
    /// reads the same as a log cut 4 bytes into a record: it is returned as
    /// cut (the same records, with a report), a chance of about one in
    /// 65536 / (number of event types) for a damaged file.
    ///
    /// # Errors
    /// A [`CfLogError`] naming the first problem found and its byte offset:
    /// a damaged header, a record of an undeclared event id, a CRC mismatch.
    pub fn parse(bytes: &[u8], opts: &ParseOptions) -> Result<Self, CfLogError> {
        let magic = *bytes.first().ok_or(CfLogError::TruncatedHeader {
            offset: 0,
            what: "magic byte",
        })?;
        if magic != MAGIC {
            return Err(CfLogError::BadMagic { found: magic });
        }
        let mut cur = Cursor { buf: bytes, pos: 1 };
        let version = cur.u16().ok_or(CfLogError::TruncatedHeader {
            offset: 1,
            what: "version",
        })?;
        if version != 1 && version != 2 {
            return Err(CfLogError::UnsupportedVersion { version });
        }
        let n_events = cur.u16().ok_or(CfLogError::TruncatedHeader {
            offset: 3,
            what: "event count",
        })?;
        let (events, index_of) = Self::parse_descriptors(&mut cur, n_events)?;
        let layout = Layout {
            version,
            records_at: cur.pos,
            events: &events,
            index_of: &index_of,
        };
        let (walk, integrity) = layout.read(bytes, opts)?;
        Ok(Self {
            version,
            events,
            records: walk.records,
            values: walk.values,
            integrity,
        })
    }

    /// Parses the event-descriptor table; returns the descriptors and a map
    /// from event id to descriptor index.
    fn parse_descriptors(
        cur: &mut Cursor<'_>,
        n_events: u16,
    ) -> Result<(Vec<EventDescriptor>, HashMap<u16, usize>), CfLogError> {
        let cap = usize::from(n_events).min(cur.remaining() / MIN_DESCRIPTOR_LEN);
        let mut events = Vec::with_capacity(cap);
        let mut index_of = HashMap::with_capacity(cap);
        for _ in 0..n_events {
            let offset = cur.pos;
            let id = cur.u16().ok_or(CfLogError::TruncatedHeader {
                offset,
                what: "event id",
            })?;
            let name_at = cur.pos;
            let name = cur.cstr().ok_or(CfLogError::TruncatedHeader {
                offset: name_at,
                what: "NUL-terminated event name",
            })?;
            let name = std::str::from_utf8(name).map_err(|_| CfLogError::InvalidName {
                offset: name_at,
                what: "event name",
            })?;
            let count_at = cur.pos;
            let n_vars = cur.u16().ok_or(CfLogError::TruncatedHeader {
                offset: count_at,
                what: "variable count",
            })?;
            let mut variables =
                Vec::with_capacity(usize::from(n_vars).min(cur.remaining() / MIN_VARIABLE_LEN));
            for _ in 0..n_vars {
                let spec_at = cur.pos;
                let spec = cur.cstr().ok_or(CfLogError::TruncatedHeader {
                    offset: spec_at,
                    what: "NUL-terminated variable spec",
                })?;
                variables.push(parse_variable(spec, spec_at)?);
            }
            if index_of.insert(id, events.len()).is_some() {
                return Err(CfLogError::DuplicateEventId { id, offset });
            }
            events.push(EventDescriptor {
                id,
                name: name.to_owned(),
                variables,
                offset,
            });
        }
        Ok((events, index_of))
    }

    /// Format version of the log (1: u32 ms timestamps, 2: u64 us).
    #[must_use]
    pub fn version(&self) -> u16 {
        self.version
    }

    /// Event types declared in the header, in header order.
    #[must_use]
    pub fn events(&self) -> &[EventDescriptor] {
        &self.events
    }

    /// The event type called `name`, if declared.
    #[must_use]
    pub fn event_by_name(&self, name: &str) -> Option<&EventDescriptor> {
        self.events.iter().find(|e| e.name == name)
    }

    /// Number of records.
    #[must_use]
    pub fn len(&self) -> usize {
        self.records.len()
    }

    /// Whether the log holds no record.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// What the CRC-32 says: it matches, it does not (read because of
    /// [`ParseOptions::ignore_crc`]), or the log was cut short.
    #[must_use]
    pub fn integrity(&self) -> &Integrity {
        &self.integrity
    }

    /// Where the log was cut short, if it was.
    #[must_use]
    pub fn cut(&self) -> Option<&CutReport> {
        match &self.integrity {
            Integrity::Cut(cut) => Some(cut),
            Integrity::CrcOk | Integrity::CrcMismatch { .. } => None,
        }
    }

    /// Whether the trailing CRC-32 matches (false for a log cut short, or
    /// one read with [`ParseOptions::ignore_crc`] whose CRC does not match).
    #[must_use]
    pub fn crc_ok(&self) -> bool {
        self.integrity == Integrity::CrcOk
    }

    /// The record at index `i` (file order).
    #[must_use]
    pub fn record(&self, i: usize) -> Option<Record<'_>> {
        let raw = self.records.get(i)?;
        self.view(raw)
    }

    /// Every record, in file order.
    pub fn records(&self) -> impl Iterator<Item = Record<'_>> + '_ {
        self.records.iter().filter_map(|raw| self.view(raw))
    }

    fn view(&self, raw: &RawRecord) -> Option<Record<'_>> {
        let event = self.events.get(raw.event)?;
        let end = raw.first_value.checked_add(event.variables.len())?;
        Some(Record {
            event,
            time_us: raw.time_us,
            offset: raw.offset,
            values: self.values.get(raw.first_value..end)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testlog::build;

    const ALL: &[&str] = &["a(f)", "b(B)", "c(H)", "d(h)", "e(b)", "f(I)", "g(i)"];

    fn all_payload(k: u8) -> Vec<u8> {
        let mut p = Vec::new();
        p.extend_from_slice(&(1.5f32 + f32::from(k)).to_le_bytes());
        p.push(200 + k);
        p.extend_from_slice(&(60_000u16 + u16::from(k)).to_le_bytes());
        p.extend_from_slice(&(-30_000i16 - i16::from(k)).to_le_bytes());
        p.extend_from_slice(&(-100i8 - k as i8).to_le_bytes());
        p.extend_from_slice(&(4_000_000_000u32 + u32::from(k)).to_le_bytes());
        p.extend_from_slice(&(-2_000_000_000i32 - i32::from(k)).to_le_bytes());
        p
    }

    fn sample(version: u16) -> Vec<u8> {
        build(
            version,
            &[(7, "all", ALL), (2, "empty", &[]), (300, "one", &["x(f)"])],
            &[
                (7, 10, all_payload(0)),
                (2, 11, vec![]),
                (300, 12, (-0.25f32).to_le_bytes().to_vec()),
                (7, 13, all_payload(1)),
            ],
        )
    }

    #[test]
    fn reads_every_type_v2() {
        let bytes = sample(2);
        assert!(is_cflog(&bytes));
        let log = CfLog::parse(&bytes, &ParseOptions::default()).unwrap();
        assert_eq!(log.version(), 2);
        assert_eq!(log.events().len(), 3);
        assert_eq!(log.len(), 4);
        assert!(log.crc_ok());
        let r0 = log.record(0).unwrap();
        assert_eq!(r0.event.name, "all");
        assert_eq!(r0.time_us, 10);
        assert_eq!(
            r0.offset,
            5 + (2 + 4 + 2 + 5 * 7) + (2 + 6 + 2) + (2 + 4 + 2 + 5)
        );
        assert_eq!(
            r0.values,
            &[
                Value::F32(1.5),
                Value::U8(200),
                Value::U16(60_000),
                Value::I16(-30_000),
                Value::I8(-100),
                Value::U32(4_000_000_000),
                Value::I32(-2_000_000_000),
            ]
        );
        let r1 = log.record(1).unwrap();
        assert_eq!(r1.event.name, "empty");
        assert!(r1.values.is_empty());
        // record 1 starts after record 0: 2 (id) + 8 (ts) + 4+1+2+2+1+4+4 payload.
        assert_eq!(r1.offset, r0.offset + 10 + 18);
        assert_eq!(log.record(2).unwrap().value("x"), Some(Value::F32(-0.25)));
        let r3 = log.record(3).unwrap();
        assert_eq!(r3.value("g"), Some(Value::I32(-2_000_000_001)));
        assert_eq!(r3.value("b").unwrap().as_u32(), Some(201));
        assert_eq!(r3.value("e").unwrap().as_u32(), None);
        assert_eq!(r3.value("d").unwrap().as_f64(), -30_001.0);
        assert_eq!(r3.value("nope"), None);
        assert!(log.record(4).is_none());
        assert_eq!(log.records().count(), 4);
    }

    #[test]
    fn reads_v1_millisecond_timestamps() {
        let bytes = sample(1);
        let log = CfLog::parse(&bytes, &ParseOptions::default()).unwrap();
        assert_eq!(log.version(), 1);
        let times: Vec<u64> = log.records().map(|r| r.time_us).collect();
        assert_eq!(times, vec![10_000, 11_000, 12_000, 13_000]);
        assert_eq!(
            log.record(3).unwrap().value("f"),
            Some(Value::U32(4_000_000_001))
        );
        // v1 records are 4 bytes shorter than v2 ones.
        assert_eq!(
            log.record(1).unwrap().offset - log.record(0).unwrap().offset,
            6 + 18
        );
    }

    #[test]
    fn crc_mismatch_refused_unless_ignored() {
        let mut bytes = sample(2);
        let n = bytes.len();
        bytes[n - 6] ^= 0x40; // flip a payload bit of the last record
        let err = CfLog::parse(&bytes, &ParseOptions::default()).unwrap_err();
        let CfLogError::CrcMismatch { stored, computed } = err else {
            panic!("expected CRC mismatch, got {err:?}");
        };
        assert_eq!(stored, crc32fast::hash(&sample(2)[..n - 4]));
        assert_ne!(stored, computed);
        assert!(err.to_string().contains("CRC mismatch"));
        let log = CfLog::parse(&bytes, &ParseOptions { ignore_crc: true }).unwrap();
        assert!(!log.crc_ok());
        assert!(log.cut().is_none());
        assert_eq!(
            log.integrity(),
            &Integrity::CrcMismatch { stored, computed }
        );
        assert_eq!(log.len(), 4);
    }

    #[test]
    fn header_errors_name_the_problem() {
        let opts = ParseOptions { ignore_crc: true };
        assert_eq!(
            CfLog::parse(&[], &opts).unwrap_err(),
            CfLogError::TruncatedHeader {
                offset: 0,
                what: "magic byte"
            }
        );
        let mut b = sample(2);
        b[0] = 0xBD;
        assert_eq!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::BadMagic { found: 0xBD }
        );
        assert!(!is_cflog(&b));
        let mut b = sample(2);
        b[1] = 3;
        assert_eq!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::UnsupportedVersion { version: 3 }
        );
        assert!(!is_cflog(&b));
        // duplicate id
        let b = build(2, &[(1, "a", &[]), (1, "b", &[])], &[]);
        assert_eq!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::DuplicateEventId { id: 1, offset: 11 }
        );
        // unknown type letter, offset of the spec: 5 + 2 + "e\0" + 2 = 11
        let b = build(2, &[(1, "e", &["v(d)"])], &[]);
        let err = CfLog::parse(&b, &opts).unwrap_err();
        assert_eq!(
            err,
            CfLogError::BadVariableType {
                offset: 11,
                letter: 'd',
                spec: "v(d)".into()
            }
        );
        assert!(err.to_string().contains("byte 11"), "{err}");
        let b = build(2, &[(1, "e", &["v[f]"])], &[]);
        assert!(matches!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::BadVariableSpec { offset: 11, .. }
        ));
        let b = build(2, &[(1, "e", &["f)"])], &[]);
        assert!(matches!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::BadVariableSpec { offset: 11, .. }
        ));
        let b = build(2, &[(1, "\u{0}", &[])], &[]); // name "" then stray byte
        assert!(CfLog::parse(&b, &opts).is_err());
        let b = build(2, &[(1, "\u{ff}", &[])], &[]);
        assert!(CfLog::parse(&b, &opts).is_ok()); // valid UTF-8 (two bytes)
        let mut b = build(2, &[(1, "ab", &[])], &[]);
        b[7] = 0xFF; // invalid UTF-8 in the name
        assert_eq!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::InvalidName {
                offset: 7,
                what: "event name"
            }
        );
    }

    #[test]
    fn record_errors_name_the_offset() {
        let opts = ParseOptions::default();
        let b = build(
            2,
            &[(1, "e", &["v(B)"])],
            &[(1, 5, vec![9]), (4, 6, vec![])],
        );
        // header 5 + 2 + 2 + 2 + 5 = 16; first record 2 + 8 + 1 = 11.
        assert_eq!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::UnknownEventId { id: 4, offset: 27 }
        );
        let b = build(2, &[(1, "e", &["v(I)"])], &[(1, 5, vec![9, 9])]);
        assert_eq!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::TruncatedRecord {
                offset: 16,
                event: 1
            }
        );
        let mut b = build(2, &[(1, "e", &[])], &[]);
        let crc_at = b.len() - 4;
        b.insert(crc_at, 1);
        let crc = crc32fast::hash(&b[..b.len() - 4]);
        let n = b.len();
        b[n - 4..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(
            CfLog::parse(&b, &opts).unwrap_err(),
            CfLogError::TrailingBytes { offset: 11, len: 1 }
        );
    }

    /// Offsets of the records of a whole log and of its CRC: record `i`
    /// spans `bounds[i]..bounds[i + 1]`, the CRC starts at the last one.
    fn record_bounds(full: &[u8]) -> Vec<usize> {
        let whole = CfLog::parse(full, &ParseOptions::default()).unwrap();
        let mut bounds: Vec<usize> = whole.records().map(|r| r.offset).collect();
        bounds.push(full.len() - CRC_LEN);
        bounds
    }

    #[test]
    fn every_cut_reads_the_whole_records_before_it() {
        for version in [1, 2] {
            let full = sample(version);
            let whole = CfLog::parse(&full, &ParseOptions::default()).unwrap();
            assert_eq!(whole.integrity(), &Integrity::CrcOk);
            assert!(whole.cut().is_none());
            let bounds = record_bounds(&full);
            let (header_end, crc_at) = (bounds[0], full.len() - CRC_LEN);
            // The CRC's first bytes do not name a declared event (7, 2, 300).
            let crc_id = u16::from_le_bytes([full[crc_at], full[crc_at + 1]]);
            assert!(![7, 2, 300].contains(&crc_id), "pick another sample");
            for cut in 0..full.len() {
                for ignore_crc in [false, true] {
                    let res = CfLog::parse(&full[..cut], &ParseOptions { ignore_crc });
                    if cut < header_end {
                        assert!(
                            matches!(res, Err(CfLogError::TruncatedHeader { .. })),
                            "v{version} cut at {cut}: {res:?}"
                        );
                        continue;
                    }
                    let log = res.unwrap_or_else(|e| panic!("v{version} cut at {cut}: {e}"));
                    // Whole records: those that end at or before the cut.
                    let n = bounds[1..].iter().filter(|&&end| end <= cut).count();
                    let stop = bounds[n];
                    assert_eq!(log.len(), n, "v{version} cut at {cut}");
                    for (a, b) in log.records().zip(whole.records()) {
                        assert_eq!(
                            (a.offset, a.time_us, a.values, &a.event.name),
                            (b.offset, b.time_us, b.values, &b.event.name)
                        );
                    }
                    assert!(!log.crc_ok());
                    let report = log.cut().expect("a cut log has a report");
                    let have = cut - stop;
                    let kind = if have == 0 {
                        CutKind::MissingCrc
                    } else if stop == crc_at || have == 1 {
                        CutKind::PartialCrc { have }
                    } else {
                        let next = whole.record(n).unwrap();
                        CutKind::Record {
                            event: next.event.id,
                            name: next.event.name.clone(),
                            have,
                            len: bounds[n + 1] - stop,
                        }
                    };
                    assert_eq!(
                        report,
                        &CutReport {
                            offset: stop,
                            bytes_ignored: have,
                            kind
                        },
                        "v{version} cut at {cut}"
                    );
                    let msg = report.to_string();
                    assert!(
                        msg.starts_with(&format!("cut short at byte {stop}: ")),
                        "{msg}"
                    );
                }
            }
        }
    }

    #[test]
    fn cut_reports_say_what_was_cut() {
        let full = sample(2);
        let bounds = record_bounds(&full);
        let opts = ParseOptions::default();
        // Inside record 3 (event 7 "all", 28 bytes): 5 of its bytes.
        let log = CfLog::parse(&full[..bounds[3] + 5], &opts).unwrap();
        assert_eq!(log.len(), 3);
        assert_eq!(
            log.cut().unwrap().to_string(),
            format!(
                "cut short at byte {}: the file ends inside a record of event 7 (all): \
                 5 of its 28 bytes; 5 byte(s) ignored, no CRC to check",
                bounds[3]
            )
        );
        // At a record boundary: only the CRC is missing.
        let log = CfLog::parse(&full[..bounds[2]], &opts).unwrap();
        assert_eq!(log.len(), 2);
        assert_eq!(
            log.cut().unwrap().to_string(),
            format!(
                "cut short at byte {}: the file ends after a whole record, without its CRC-32; \
                 0 byte(s) ignored, no CRC to check",
                bounds[2]
            )
        );
        // Inside the CRC: every record is there.
        let log = CfLog::parse(&full[..full.len() - 1], &opts).unwrap();
        assert_eq!(log.len(), 4);
        assert_eq!(
            log.cut().unwrap().kind,
            CutKind::PartialCrc { have: CRC_LEN - 1 }
        );
        assert!(log
            .cut()
            .unwrap()
            .to_string()
            .contains("inside the trailing CRC-32: 3 of its 4 bytes"));
    }

    #[test]
    fn garbled_records_are_not_a_cut() {
        // An undeclared event id in the middle: a CRC mismatch, not a cut.
        let mut b = sample(2);
        let bounds = record_bounds(&b);
        b[bounds[1]] = 99;
        let err = CfLog::parse(&b, &ParseOptions::default()).unwrap_err();
        assert!(matches!(err, CfLogError::CrcMismatch { .. }), "{err:?}");
        assert_eq!(
            CfLog::parse(&b, &ParseOptions { ignore_crc: true }).unwrap_err(),
            CfLogError::UnknownEventId {
                id: 99,
                offset: bounds[1]
            }
        );
        // Cut short after the garbled record: still garbled, not a cut.
        let err = CfLog::parse(&b[..bounds[3] + 3], &ParseOptions { ignore_crc: true });
        assert_eq!(
            err.unwrap_err(),
            CfLogError::UnknownEventId {
                id: 99,
                offset: bounds[1]
            }
        );
    }

    #[test]
    fn a_wrong_crc_that_starts_like_a_record_reads_as_a_cut() {
        // The ambiguous case: 4 bytes after the last whole record, starting
        // with a declared event id, are a cut record or a wrong CRC. Read as
        // a cut: the same records, with a report instead of an error.
        let mut b = sample(2);
        let n = b.len();
        b[n - 4..n - 2].copy_from_slice(&300u16.to_le_bytes());
        let log = CfLog::parse(&b, &ParseOptions::default()).unwrap();
        assert_eq!(log.len(), 4);
        assert_eq!(
            log.cut().unwrap().kind,
            CutKind::Record {
                event: 300,
                name: "one".into(),
                have: 4,
                len: 14
            }
        );
    }

    #[test]
    fn random_corruption_never_panics() {
        // Seeded (xoshiro256**); flips bytes of a valid log and parses.
        use rand::{RngExt as _, SeedableRng as _};
        let full = sample(2);
        let mut rng = rand_xoshiro::Xoshiro256StarStar::seed_from_u64(0x5EED);
        for _ in 0..20_000 {
            let mut b = full.clone();
            let flips = rng.random_range(1..=4);
            for _ in 0..flips {
                let i = rng.random_range(0..b.len());
                b[i] = rng.random::<u8>();
            }
            let _ = CfLog::parse(&b, &ParseOptions { ignore_crc: true });
            let _ = is_cflog(&b);
        }
        // A huge declared event count over a tiny file is refused without a huge allocation.
        let mut b = vec![MAGIC, 2, 0, 0xFF, 0xFF, 0, 0, 0, 0];
        assert!(!is_cflog(&b));
        assert!(CfLog::parse(&b, &ParseOptions { ignore_crc: true }).is_err());
        b.extend_from_slice(&[1, 0, b'x', 0, 0xFF, 0xFF]);
        assert!(CfLog::parse(&b, &ParseOptions { ignore_crc: true }).is_err());
    }

    #[test]
    fn detection() {
        assert!(is_cflog(&sample(1)));
        assert!(is_cflog(&sample(2)));
        assert!(!is_cflog(b"an0_p,1,2,3\n"));
        assert!(!is_cflog(&[MAGIC, 2, 0]));
        // zero event types is not plausible
        assert!(!is_cflog(&build(2, &[], &[])));
    }
}
