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
    /// Read the records even when the trailing CRC-32 does not match (for
    /// logs cut short by a power loss). Default `false`: a mismatch is an error.
    pub ignore_crc: bool,
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

/// A parsed Crazyflie event log: descriptors and every record, in file order.
#[derive(Debug, Clone)]
pub struct CfLog {
    version: u16,
    events: Vec<EventDescriptor>,
    records: Vec<RawRecord>,
    values: Vec<Value>,
    crc_stored: u32,
    crc_computed: u32,
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
    /// Parses a whole log file.
    ///
    /// Checks, in order: the magic, the version, the CRC (unless
    /// `opts.ignore_crc`), the event descriptors (unique ids, UTF-8 names,
    /// `name(T)` specs with known type letters) and every record (declared
    /// event id, complete timestamp and payload).
    ///
    /// # Errors
    /// A [`CfLogError`] naming the first problem found and its byte offset.
    pub fn parse(bytes: &[u8], opts: &ParseOptions) -> Result<Self, CfLogError> {
        let magic = *bytes.first().ok_or(CfLogError::TruncatedHeader {
            offset: 0,
            what: "magic byte",
        })?;
        if magic != MAGIC {
            return Err(CfLogError::BadMagic { found: magic });
        }
        let mut head = Cursor { buf: bytes, pos: 1 };
        let version = head.u16().ok_or(CfLogError::TruncatedHeader {
            offset: 1,
            what: "version",
        })?;
        if version != 1 && version != 2 {
            return Err(CfLogError::UnsupportedVersion { version });
        }
        let n_events = head.u16().ok_or(CfLogError::TruncatedHeader {
            offset: 3,
            what: "event count",
        })?;
        let body_len = bytes
            .len()
            .checked_sub(CRC_LEN)
            .filter(|&n| n >= HEADER_LEN)
            .ok_or(CfLogError::TruncatedHeader {
                offset: bytes.len(),
                what: "CRC-32",
            })?;
        let (body, crc_bytes) = bytes.split_at(body_len);
        let crc_stored =
            u32::from_le_bytes(
                crc_bytes
                    .try_into()
                    .map_err(|_| CfLogError::TruncatedHeader {
                        offset: body_len,
                        what: "CRC-32",
                    })?,
            );
        let crc_computed = crc32fast::hash(body);
        if !opts.ignore_crc && crc_stored != crc_computed {
            return Err(CfLogError::CrcMismatch {
                stored: crc_stored,
                computed: crc_computed,
            });
        }

        let mut cur = Cursor {
            buf: body,
            pos: HEADER_LEN,
        };
        let (events, index_of) = Self::parse_descriptors(&mut cur, n_events)?;
        let (records, values) = Self::parse_records(&mut cur, version, &events, &index_of)?;
        Ok(Self {
            version,
            events,
            records,
            values,
            crc_stored,
            crc_computed,
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

    /// Parses the records from the cursor to the end of the body.
    fn parse_records(
        cur: &mut Cursor<'_>,
        version: u16,
        events: &[EventDescriptor],
        index_of: &HashMap<u16, usize>,
    ) -> Result<(Vec<RawRecord>, Vec<Value>), CfLogError> {
        let mut records = Vec::new();
        let mut values = Vec::new();
        while cur.remaining() > 0 {
            let offset = cur.pos;
            let id = cur.u16().ok_or(CfLogError::TrailingBytes {
                offset,
                len: cur.remaining(),
            })?;
            let event = *index_of
                .get(&id)
                .ok_or(CfLogError::UnknownEventId { id, offset })?;
            let truncated = CfLogError::TruncatedRecord { offset, event: id };
            let time_us = if version == 1 {
                u64::from(cur.u32().ok_or_else(|| truncated.clone())?) * 1000
            } else {
                cur.u64().ok_or_else(|| truncated.clone())?
            };
            let desc = events.get(event).ok_or_else(|| truncated.clone())?;
            let payload = cur.take(desc.payload_len()).ok_or(truncated)?;
            let first_value = values.len();
            let mut at = 0usize;
            for var in &desc.variables {
                let size = var.ty.size();
                let value = payload
                    .get(at..at + size)
                    .and_then(|b| var.ty.decode(b))
                    .ok_or(CfLogError::TruncatedRecord { offset, event: id })?;
                values.push(value);
                at += size;
            }
            records.push(RawRecord {
                event,
                time_us,
                offset,
                first_value,
            });
        }
        Ok((records, values))
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

    /// CRC-32 stored in the last 4 bytes.
    #[must_use]
    pub fn crc_stored(&self) -> u32 {
        self.crc_stored
    }

    /// CRC-32 computed over the bytes before it.
    #[must_use]
    pub fn crc_computed(&self) -> u32 {
        self.crc_computed
    }

    /// Whether the stored and computed CRCs agree (false is only possible
    /// with [`ParseOptions::ignore_crc`]).
    #[must_use]
    pub fn crc_ok(&self) -> bool {
        self.crc_stored == self.crc_computed
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

    #[test]
    fn every_truncation_is_an_error_or_a_prefix() {
        for version in [1, 2] {
            let full = sample(version);
            let reference = CfLog::parse(&full, &ParseOptions::default()).unwrap();
            for cut in 0..full.len() {
                let part = &full[..cut];
                assert!(
                    CfLog::parse(part, &ParseOptions::default()).is_err(),
                    "cut at {cut} accepted with CRC check"
                );
                if let Ok(log) = CfLog::parse(part, &ParseOptions { ignore_crc: true }) {
                    assert!(log.len() < reference.len(), "cut {cut}");
                    for (a, b) in log.records().zip(reference.records()) {
                        assert_eq!(a.time_us, b.time_us);
                        assert_eq!(a.values, b.values);
                    }
                }
                let _ = is_cflog(part);
            }
        }
    }

    #[test]
    fn random_corruption_never_panics() {
        // Deterministic xorshift; flips bytes of a valid log and parses.
        let full = sample(2);
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..20_000 {
            let mut b = full.clone();
            let flips = 1 + next() % 4;
            for _ in 0..flips {
                let i = (next() % b.len() as u64) as usize;
                b[i] = next() as u8;
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
