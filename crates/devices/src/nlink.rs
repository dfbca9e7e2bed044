//! The Nooploop LinkTrack NLink protocol's Tag_Frame0 (what a LinkTrack tag
//! sends on its own serial port in the LP mode): the streaming [`Decoder`]
//! and the [`TagFrame`] encoder the emulator uses.
//!
//! A Tag_Frame0 is 128 bytes, little-endian, `int24` being three bytes of a
//! two's-complement 24-bit integer:
//!
//! | offset | size | field                                   |
//! |--------|------|-----------------------------------------|
//! | 0      | 2    | header `0x55 0x01`                      |
//! | 2      | 1    | id                                      |
//! | 3      | 1    | role                                    |
//! | 4      | 9    | pos x, y, z: `int24 / 1000` m            |
//! | 13     | 9    | vel x, y, z: `int24 / 10000` m/s         |
//! | 22     | 24   | dis 0..7 (anchor ranges): `int24 / 1000` m |
//! | 46     | 12   | imu gyro x, y, z `f32` (ignored)         |
//! | 58     | 12   | imu acc x, y, z `f32` (ignored)          |
//! | 70     | 12   | reserved                                |
//! | 82     | 6    | angle `int16 / 100` deg (ignored)        |
//! | 88     | 16   | quaternion `f32` (ignored)               |
//! | 104    | 4    | reserved                                |
//! | 108    | 4    | local_time `u32` ms (ignored)            |
//! | 112    | 4    | system_time `u32` ms                     |
//! | 116    | 1    | reserved                                |
//! | 117    | 3    | eop x, y, z `u8 / 100` m (ignored)       |
//! | 120    | 2    | voltage `u16 / 1000` V (ignored)         |
//! | 122    | 5    | reserved                                |
//! | 127    | 1    | checksum: sum of bytes 0..=126 mod 256   |
//!
//! Each frame gives a [`Reading::Position`] (with velocity and the
//! `system_time` as device time, wrapping at 2^32 ms), a
//! [`Reading::Ranges`], then a [`Reading::Range`] per anchor whose
//! distance is not 0 (anchor id = its index 0..7, no anchor position, no
//! quality, the same device time), the last with `last_of_round`.
//!
//! ```
//! use insuwb_devices::nlink::{Decoder, TagFrame};
//! use insuwb_devices::frame::Reading;
//!
//! let frame = TagFrame { id: 3, pos_m: [1.0, 2.0, 0.5], ..TagFrame::default() }.encode();
//! let mut decoder = Decoder::new();
//! let mut got = Vec::new();
//! decoder.push(&frame, &mut |r| got.push(r));
//! assert!(matches!(got[0], Reading::Position { tag: 3, .. }));
//! ```

use crate::frame::{
    le_u16, le_u32, sum8, DecoderStats, DeviceTime, FrameFormat, Framer, Outcome, Reading, Scan,
};

/// Bytes of a Tag_Frame0.
pub const FRAME_LEN: usize = 128;
/// First header byte.
pub const HEADER: u8 = 0x55;
/// Second header byte: Tag_Frame0's function mark.
pub const FUNCTION_MARK: u8 = 0x01;
/// Tick of `system_time` (ns).
pub const SYSTEM_TIME_TICK_NS: u64 = 1_000_000;
/// Where `system_time` wraps (ticks).
pub const SYSTEM_TIME_WRAP: u64 = 1 << 32;

const OFF_ID: usize = 2;
const OFF_ROLE: usize = 3;
const OFF_POS: usize = 4;
const OFF_VEL: usize = 13;
const OFF_DIS: usize = 22;
const OFF_LOCAL_TIME: usize = 108;
const OFF_SYSTEM_TIME: usize = 112;
const OFF_VOLTAGE: usize = 120;
const OFF_CHECKSUM: usize = 127;
/// Raw units per metre of position and range, per m/s of velocity, per
/// volt (decoded by division, so that a value round-trips exactly).
const POS_PER_M: f64 = 1000.0;
const VEL_PER_MPS: f64 = 10000.0;
const DIS_PER_M: f64 = 1000.0;
const VOLTAGE_PER_V: f64 = 1000.0;
const INT24_MAX: i32 = (1 << 23) - 1;
const INT24_MIN: i32 = -(1 << 23);

#[derive(Debug, Clone, Copy)]
struct Format;

impl FrameFormat for Format {
    fn is_start(&self, byte: u8) -> bool {
        byte == HEADER
    }

    fn scan(&self, buf: &[u8]) -> Scan {
        match buf.get(1) {
            None => Scan::NeedMore,
            Some(&FUNCTION_MARK) => Scan::Frame(FRAME_LEN),
            Some(_) => Scan::Invalid,
        }
    }

    fn checksum_ok(&self, frame: &[u8]) -> bool {
        match (frame.get(..OFF_CHECKSUM), frame.get(OFF_CHECKSUM)) {
            (Some(body), Some(sum)) => sum8(body) == *sum,
            _ => false,
        }
    }
}

/// The fields of a Tag_Frame0 this codec reads and writes, in SI units.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TagFrame {
    /// Tag id.
    pub id: u8,
    /// Role (2: tag).
    pub role: u8,
    /// Position (m); encoded with 1 mm resolution, saturated at +-8388 m.
    pub pos_m: [f64; 3],
    /// Velocity (m/s); 0.1 mm/s resolution, saturated at +-838 m/s.
    pub vel_mps: [f64; 3],
    /// Ranges to anchors 0..7 (m); 1 mm resolution.
    pub ranges_m: [f64; 8],
    /// Tag-local time (ms).
    pub local_time_ms: u32,
    /// Network system time (ms).
    pub system_time_ms: u32,
    /// Supply voltage (V).
    pub voltage_v: f64,
}

fn int24(bytes: &[u8], at: usize) -> i32 {
    match bytes.get(at..at + 3) {
        // Sign-extend by placing the 24 bits at the top of an i32.
        Some(&[b0, b1, b2]) => i32::from_le_bytes([0, b0, b1, b2]) >> 8,
        _ => 0,
    }
}

fn put_int24(bytes: &mut [u8], at: usize, value: f64, per_unit: f64) {
    let raw = (value * per_unit)
        .round()
        .clamp(f64::from(INT24_MIN), f64::from(INT24_MAX)) as i32;
    let [b0, b1, b2, _] = raw.to_le_bytes();
    if let Some(dst) = bytes.get_mut(at..at + 3) {
        dst.copy_from_slice(&[b0, b1, b2]);
    }
}

impl TagFrame {
    /// Reads a Tag_Frame0 (header and checksum not checked: the decoder
    /// did); `None` if `frame` is shorter than 128 bytes.
    pub fn decode(frame: &[u8]) -> Option<TagFrame> {
        let frame = frame.get(..FRAME_LEN)?;
        let triple =
            |at: usize, per: f64| [0, 1, 2].map(|i| f64::from(int24(frame, at + 3 * i)) / per);
        Some(TagFrame {
            id: *frame.get(OFF_ID)?,
            role: *frame.get(OFF_ROLE)?,
            pos_m: triple(OFF_POS, POS_PER_M),
            vel_mps: triple(OFF_VEL, VEL_PER_MPS),
            ranges_m: std::array::from_fn(|i| f64::from(int24(frame, OFF_DIS + 3 * i)) / DIS_PER_M),
            local_time_ms: le_u32(frame, OFF_LOCAL_TIME)?,
            system_time_ms: le_u32(frame, OFF_SYSTEM_TIME)?,
            voltage_v: f64::from(le_u16(frame, OFF_VOLTAGE)?) / VOLTAGE_PER_V,
        })
    }

    /// The 128-byte frame, checksum filled in; fields the codec does not
    /// model are zero. Out-of-range values saturate.
    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let mut f = [0u8; FRAME_LEN];
        f[0] = HEADER;
        f[1] = FUNCTION_MARK;
        f[OFF_ID] = self.id;
        f[OFF_ROLE] = self.role;
        for i in 0..3 {
            put_int24(&mut f, OFF_POS + 3 * i, self.pos_m[i], POS_PER_M);
            put_int24(&mut f, OFF_VEL + 3 * i, self.vel_mps[i], VEL_PER_MPS);
        }
        for (i, r) in self.ranges_m.iter().enumerate() {
            put_int24(&mut f, OFF_DIS + 3 * i, *r, DIS_PER_M);
        }
        f[OFF_LOCAL_TIME..OFF_LOCAL_TIME + 4].copy_from_slice(&self.local_time_ms.to_le_bytes());
        f[OFF_SYSTEM_TIME..OFF_SYSTEM_TIME + 4].copy_from_slice(&self.system_time_ms.to_le_bytes());
        // `as` saturates at 0 and 65535 V/1000 and maps NaN to 0.
        let mv = (self.voltage_v * VOLTAGE_PER_V).round() as u16;
        f[OFF_VOLTAGE..OFF_VOLTAGE + 2].copy_from_slice(&mv.to_le_bytes());
        f[OFF_CHECKSUM] = sum8(&f[..OFF_CHECKSUM]);
        f
    }

    /// The device time of `system_time`.
    pub fn device_time(&self) -> DeviceTime {
        DeviceTime {
            ticks: u64::from(self.system_time_ms),
            tick_ns: SYSTEM_TIME_TICK_NS,
            wrap: Some(SYSTEM_TIME_WRAP),
        }
    }
}

/// Streaming decoder of an NLink byte stream (Tag_Frame0 only; other NLink
/// frames are skipped as noise).
#[derive(Debug, Clone)]
pub struct Decoder {
    framer: Framer<FRAME_LEN>,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// A decoder that has seen nothing.
    pub fn new() -> Self {
        Decoder {
            framer: Framer::new(),
        }
    }

    /// Feeds bytes as they came off the link; calls `out` with a
    /// [`Reading::Position`], a [`Reading::Ranges`] and a [`Reading::Range`]
    /// per heard anchor for each frame.
    pub fn push(&mut self, bytes: &[u8], out: &mut impl FnMut(Reading)) {
        self.framer.push(&Format, bytes, &mut |frame, _gap| {
            let Some(tf) = TagFrame::decode(frame) else {
                return Outcome::Malformed;
            };
            let device_time = Some(tf.device_time());
            out(Reading::Position {
                tag: u32::from(tf.id),
                pos_m: tf.pos_m,
                vel_mps: Some(tf.vel_mps),
                device_time,
                seq: None,
            });
            out(Reading::Ranges {
                tag: u32::from(tf.id),
                ranges_m: tf.ranges_m,
                device_time,
            });
            let last = tf.ranges_m.iter().rposition(|d| *d != 0.0);
            for ((anchor, i), range_m) in (0_u32..).zip(0_usize..).zip(tf.ranges_m) {
                if range_m != 0.0 {
                    out(Reading::Range {
                        anchor,
                        range_m,
                        anchor_pos_m: None,
                        quality: None,
                        last_of_round: Some(i) == last,
                        device_time,
                    });
                }
            }
            Outcome::Decoded
        });
    }

    /// What the decoder has counted.
    pub fn stats(&self) -> DecoderStats {
        self.framer.stats
    }

    crate::frame::framer_accessors!();

    /// Forgets a partial frame (after a reconnect); keeps counts.
    pub fn clear(&mut self) {
        self.framer.clear();
    }
}

/// What [`encode`] cannot do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// Only position readings have a Tag_Frame0.
    #[error("nlink::EncodeError::Unsupported: only position readings are encoded")]
    Unsupported,
}

/// A Tag_Frame0 of a position reading: tag id saturated into `u8`, no
/// ranges, `system_time` from its device time (taken in ms, modulo 2^32).
pub fn encode(reading: &Reading) -> Result<[u8; FRAME_LEN], EncodeError> {
    let Reading::Position {
        tag,
        pos_m,
        vel_mps,
        device_time,
        ..
    } = reading
    else {
        return Err(EncodeError::Unsupported);
    };
    let system_time_ms = device_time.map_or(0, |t| {
        let ms = u128::from(t.ticks) * u128::from(t.tick_ns) / u128::from(SYSTEM_TIME_TICK_NS);
        (ms % u128::from(SYSTEM_TIME_WRAP)) as u32
    });
    Ok(TagFrame {
        id: u8::try_from(*tag).unwrap_or(u8::MAX),
        role: 2,
        pos_m: *pos_m,
        vel_mps: vel_mps.unwrap_or_default(),
        system_time_ms,
        ..TagFrame::default()
    }
    .encode())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn int24_sign_extends_and_saturates() {
        let mut b = [0u8; 3];
        put_int24(&mut b, 0, -0.001, POS_PER_M);
        assert_eq!(b, [0xFF, 0xFF, 0xFF]);
        assert_eq!(int24(&b, 0), -1);
        put_int24(&mut b, 0, 1e9, POS_PER_M);
        assert_eq!(int24(&b, 0), INT24_MAX);
        put_int24(&mut b, 0, -1e9, POS_PER_M);
        assert_eq!(int24(&b, 0), INT24_MIN);
    }

    #[test]
    fn tag_frame_round_trips() {
        let tf = TagFrame {
            id: 7,
            role: 2,
            pos_m: [1.234, -5.678, 0.9],
            vel_mps: [0.1234, -0.5, 0.0],
            ranges_m: [1.0, 2.0, 3.0, 4.0, 0.0, 0.0, 0.0, 8.388],
            local_time_ms: 5,
            system_time_ms: u32::MAX,
            voltage_v: 4.2,
        };
        let back = TagFrame::decode(&tf.encode());
        assert_eq!(back, Some(tf));
    }

    #[test]
    fn other_function_marks_are_skipped() {
        let mut f = TagFrame::default().encode();
        f[1] = 0x02;
        let mut d = Decoder::new();
        d.push(&f, &mut |_| panic!("not a Tag_Frame0"));
        assert_eq!(d.stats().bytes_skipped, FRAME_LEN as u64);
    }
}
