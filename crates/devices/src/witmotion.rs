//! The WitMotion 0x55 serial protocol (WT901, HWT901B, JY901 and kin):
//! the streaming [`Decoder`] and the encoders the emulator uses.
//!
//! Every frame is 11 bytes: `0x55`, a type byte, four little-endian `i16`
//! and a checksum (sum of bytes 0 to 9 modulo 256). Decoded types:
//!
//! | type | values 1-3                      | value 4                 |
//! |------|---------------------------------|-------------------------|
//! | 0x51 | acceleration, `v/32768*16` g    | temperature, `v/100` C  |
//! | 0x52 | angular rate, `v/32768*2000` deg/s | temperature, `v/100` C |
//! | 0x53 | roll, pitch, yaw, `v/32768*180` deg | firmware version    |
//! | 0x59 | quaternion w, x, y, z, `v/32768` (all four values) | |
//!
//! The 0x51 and 0x52 frames of one output cycle become one
//! [`Reading::Imu`]; the pair is taken only when nothing between them can
//! have been a lost frame (no checksum failure, fewer than 11 bytes skipped,
//! no other frame). A cycle with only one of the two is counted in
//! [`DecoderStats::incomplete`]. The protocol carries no device clock on
//! these frames: readings have `device_time: None`.
//!
//! ```
//! use insuwb_devices::witmotion::{encode_imu, Decoder};
//! use insuwb_devices::frame::Reading;
//!
//! let bytes = encode_imu([0.1, -0.2, 9.8], [0.01, 0.0, -0.02], 31.5);
//! let mut decoder = Decoder::new();
//! let mut got = None;
//! decoder.push(&bytes, &mut |r| got = Some(r));
//! let Some(Reading::Imu { accel_mps2, .. }) = got else { panic!() };
//! assert!((accel_mps2[2] - 9.8).abs() < 0.005);
//! assert_eq!(decoder.temperature_c(), Some(31.5));
//! ```

use crate::frame::{
    le_i16, le_u16, saturate_i16, sum8, DecoderStats, FrameFormat, Framer, Gap, Outcome, Reading,
    Scan, STANDARD_GRAVITY,
};

/// Bytes in every WitMotion frame.
pub const FRAME_LEN: usize = 11;
/// The first byte of every frame.
pub const HEADER: u8 = 0x55;
/// Frame type: acceleration and temperature.
pub const TYPE_ACCEL: u8 = 0x51;
/// Frame type: angular rate and temperature.
pub const TYPE_GYRO: u8 = 0x52;
/// Frame type: Euler angles and firmware version.
pub const TYPE_ANGLE: u8 = 0x53;
/// Frame type: quaternion.
pub const TYPE_QUATERNION: u8 = 0x59;
/// Full-scale acceleration of a raw value of 32768 (g).
pub const ACCEL_FULL_SCALE_G: f64 = 16.0;
/// Full-scale angular rate of a raw value of 32768 (deg/s).
pub const GYRO_FULL_SCALE_DPS: f64 = 2000.0;
/// Full-scale angle of a raw value of 32768 (deg).
pub const ANGLE_FULL_SCALE_DEG: f64 = 180.0;

const ACCEL_LSB_MPS2: f64 = ACCEL_FULL_SCALE_G * STANDARD_GRAVITY / 32768.0;
const GYRO_LSB_RPS: f64 = GYRO_FULL_SCALE_DPS / 32768.0 * (std::f64::consts::PI / 180.0);
const ANGLE_LSB_RAD: f64 = ANGLE_FULL_SCALE_DEG / 32768.0 * (std::f64::consts::PI / 180.0);
const QUATERNION_LSB: f64 = 1.0 / 32768.0;
const TEMPERATURE_LSB_C: f64 = 0.01;

/// WitMotion frame boundaries: `0x55`, a type in 0x50..=0x5F, 11 bytes.
#[derive(Debug, Clone, Copy)]
struct Format;

impl FrameFormat for Format {
    fn is_start(&self, byte: u8) -> bool {
        byte == HEADER
    }

    fn scan(&self, buf: &[u8]) -> Scan {
        match buf.get(1) {
            None => Scan::NeedMore,
            Some(0x50..=0x5F) => Scan::Frame(FRAME_LEN),
            Some(_) => Scan::Invalid,
        }
    }

    fn checksum_ok(&self, frame: &[u8]) -> bool {
        match (frame.get(..FRAME_LEN - 1), frame.get(FRAME_LEN - 1)) {
            (Some(body), Some(sum)) => sum8(body) == *sum,
            _ => false,
        }
    }
}

/// Streaming decoder of a WitMotion byte stream.
#[derive(Debug, Clone)]
pub struct Decoder {
    framer: Framer<FRAME_LEN>,
    /// The acceleration of the current cycle, waiting for its 0x52.
    pending_accel: Option<[f64; 3]>,
    incomplete: u64,
    temperature_c: Option<f64>,
    version: Option<u16>,
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
            pending_accel: None,
            incomplete: 0,
            temperature_c: None,
            version: None,
        }
    }

    /// Feeds bytes as they came off the link; calls `out` for each reading.
    pub fn push(&mut self, bytes: &[u8], out: &mut impl FnMut(Reading)) {
        let Decoder {
            framer,
            pending_accel,
            incomplete,
            temperature_c,
            version,
        } = self;
        let mut pair = Pairing {
            pending_accel,
            incomplete,
            temperature_c,
            version,
        };
        framer.push(&Format, bytes, &mut |frame, gap| {
            pair.frame(frame, gap, out)
        });
    }

    /// What the decoder has counted.
    pub fn stats(&self) -> DecoderStats {
        DecoderStats {
            incomplete: self.incomplete,
            ..self.framer.stats
        }
    }

    crate::frame::framer_accessors!();

    /// Forgets a partial frame and an unpaired 0x51 (after a reconnect).
    pub fn clear(&mut self) {
        self.framer.clear();
        if self.pending_accel.take().is_some() {
            self.incomplete = self.incomplete.saturating_add(1);
        }
    }

    /// The last temperature a 0x51 or 0x52 frame carried (deg C).
    pub fn temperature_c(&self) -> Option<f64> {
        self.temperature_c
    }

    /// The last firmware version a 0x53 frame carried.
    pub fn version(&self) -> Option<u16> {
        self.version
    }
}

/// The decoder's state a frame can change, borrowed apart from the framer.
struct Pairing<'a> {
    pending_accel: &'a mut Option<[f64; 3]>,
    incomplete: &'a mut u64,
    temperature_c: &'a mut Option<f64>,
    version: &'a mut Option<u16>,
}

impl Pairing<'_> {
    fn frame(&mut self, frame: &[u8], gap: Gap, out: &mut impl FnMut(Reading)) -> Outcome {
        let ty = frame.get(1).copied().unwrap_or(0);
        let raw = |i: usize| le_i16(frame, 2 + 2 * i).unwrap_or(0);
        let triple = |lsb: f64| [0, 1, 2].map(|i| f64::from(raw(i)) * lsb);
        if gap.checksum_errors > 0 || gap.skipped >= FRAME_LEN as u64 || ty != TYPE_GYRO {
            // A frame may have been lost since the 0x51: do not pair across it.
            self.drop_pending();
        }
        match ty {
            TYPE_ACCEL => {
                *self.pending_accel = Some(triple(ACCEL_LSB_MPS2));
                *self.temperature_c = Some(f64::from(raw(3)) * TEMPERATURE_LSB_C);
            }
            TYPE_GYRO => {
                *self.temperature_c = Some(f64::from(raw(3)) * TEMPERATURE_LSB_C);
                match self.pending_accel.take() {
                    Some(accel_mps2) => out(Reading::Imu {
                        accel_mps2,
                        gyro_rps: triple(GYRO_LSB_RPS),
                        device_time: None,
                    }),
                    None => *self.incomplete = self.incomplete.saturating_add(1),
                }
            }
            TYPE_ANGLE => {
                *self.version = le_u16(frame, 8);
                out(Reading::Attitude {
                    rpy_rad: triple(ANGLE_LSB_RAD),
                    device_time: None,
                });
            }
            TYPE_QUATERNION => out(Reading::Quaternion {
                wxyz: [0, 1, 2, 3].map(|i| f64::from(raw(i)) * QUATERNION_LSB),
                device_time: None,
            }),
            _ => return Outcome::Unknown,
        }
        Outcome::Decoded
    }

    fn drop_pending(&mut self) {
        if self.pending_accel.take().is_some() {
            *self.incomplete = self.incomplete.saturating_add(1);
        }
    }
}

/// One frame of type `ty` carrying `values`, checksum filled in.
pub fn encode_frame(ty: u8, values: [i16; 4]) -> [u8; FRAME_LEN] {
    let mut frame = [0u8; FRAME_LEN];
    frame[0] = HEADER;
    frame[1] = ty;
    for (chunk, v) in frame[2..10].chunks_exact_mut(2).zip(values) {
        chunk.copy_from_slice(&v.to_le_bytes());
    }
    frame[10] = sum8(&frame[..10]);
    frame
}

/// A 0x51 frame: acceleration (m/s^2, saturated at +-16 g) and temperature.
pub fn encode_accel(accel_mps2: [f64; 3], temperature_c: f64) -> [u8; FRAME_LEN] {
    let [x, y, z] = accel_mps2.map(|a| saturate_i16(a, ACCEL_LSB_MPS2));
    encode_frame(
        TYPE_ACCEL,
        [x, y, z, saturate_i16(temperature_c, TEMPERATURE_LSB_C)],
    )
}

/// A 0x52 frame: angular rate (rad/s, saturated at +-2000 deg/s) and
/// temperature.
pub fn encode_gyro(gyro_rps: [f64; 3], temperature_c: f64) -> [u8; FRAME_LEN] {
    let [x, y, z] = gyro_rps.map(|w| saturate_i16(w, GYRO_LSB_RPS));
    encode_frame(
        TYPE_GYRO,
        [x, y, z, saturate_i16(temperature_c, TEMPERATURE_LSB_C)],
    )
}

/// One output cycle's 0x51 then 0x52 frame.
pub fn encode_imu(
    accel_mps2: [f64; 3],
    gyro_rps: [f64; 3],
    temperature_c: f64,
) -> [u8; 2 * FRAME_LEN] {
    let mut out = [0u8; 2 * FRAME_LEN];
    out[..FRAME_LEN].copy_from_slice(&encode_accel(accel_mps2, temperature_c));
    out[FRAME_LEN..].copy_from_slice(&encode_gyro(gyro_rps, temperature_c));
    out
}

/// A 0x53 frame: roll, pitch, yaw (rad, saturated at +-180 deg) and the
/// firmware version.
pub fn encode_attitude(rpy_rad: [f64; 3], version: u16) -> [u8; FRAME_LEN] {
    let [r, p, y] = rpy_rad.map(|a| saturate_i16(a, ANGLE_LSB_RAD));
    encode_frame(
        TYPE_ANGLE,
        [r, p, y, i16::from_le_bytes(version.to_le_bytes())],
    )
}

/// A 0x59 frame: quaternion `[w, x, y, z]`, each saturated into +-1.
pub fn encode_quaternion(wxyz: [f64; 4]) -> [u8; FRAME_LEN] {
    encode_frame(
        TYPE_QUATERNION,
        wxyz.map(|q| saturate_i16(q, QUATERNION_LSB)),
    )
}

/// What [`encode`] cannot do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// WitMotion has no frame for this kind of reading.
    #[error("witmotion::EncodeError::Unsupported: WitMotion carries IMU, attitude and quaternion readings only")]
    Unsupported,
    /// The output buffer is shorter than the frames.
    #[error("witmotion::EncodeError::BufferTooSmall: {needed} bytes needed")]
    BufferTooSmall {
        /// Bytes the frames take.
        needed: usize,
    },
}

/// Writes the frames of `reading` into `out` (an IMU reading: 0x51 then
/// 0x52 at `temperature_c`); returns the bytes written.
pub fn encode(reading: &Reading, temperature_c: f64, out: &mut [u8]) -> Result<usize, EncodeError> {
    let mut put = |bytes: &[u8]| {
        let dst = out
            .get_mut(..bytes.len())
            .ok_or(EncodeError::BufferTooSmall {
                needed: bytes.len(),
            })?;
        dst.copy_from_slice(bytes);
        Ok(bytes.len())
    };
    match reading {
        Reading::Imu {
            accel_mps2,
            gyro_rps,
            ..
        } => put(&encode_imu(*accel_mps2, *gyro_rps, temperature_c)),
        Reading::Attitude { rpy_rad, .. } => put(&encode_attitude(*rpy_rad, 0)),
        Reading::Quaternion { wxyz, .. } => put(&encode_quaternion(*wxyz)),
        _ => Err(EncodeError::Unsupported),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8]) -> (Vec<Reading>, Decoder) {
        let mut d = Decoder::new();
        let mut v = Vec::new();
        d.push(bytes, &mut |r| v.push(r));
        (v, d)
    }

    #[test]
    fn encoders_saturate_out_of_range_values() {
        let f = encode_accel([1e9, -1e9, f64::NAN], 1e9);
        assert_eq!(le_i16(&f, 2), Some(i16::MAX));
        assert_eq!(le_i16(&f, 4), Some(i16::MIN));
        assert_eq!(le_i16(&f, 6), Some(0));
        assert_eq!(le_i16(&f, 8), Some(i16::MAX));
    }

    #[test]
    fn lone_gyro_and_lone_accel_count_as_incomplete() {
        let g = encode_gyro([0.0; 3], 20.0);
        let a = encode_accel([0.0; 3], 20.0);
        let angle = encode_attitude([0.0; 3], 7);
        // gyro alone; accel followed by angle (its gyro lost); accel, gyro.
        let stream: Vec<u8> = [&g[..], &a, &angle, &a, &g].concat();
        let (readings, d) = decode(&stream);
        let imus = readings
            .iter()
            .filter(|r| matches!(r, Reading::Imu { .. }))
            .count();
        assert_eq!(imus, 1);
        assert_eq!(d.stats().incomplete, 2);
        assert_eq!(d.version(), Some(7));
    }

    #[test]
    fn a_corrupted_gyro_does_not_pair_the_accel_with_the_next_cycle() {
        let a = encode_accel([1.0, 0.0, 0.0], 20.0);
        let mut g_bad = encode_gyro([0.0; 3], 20.0);
        g_bad[4] ^= 0x10;
        let a2 = encode_accel([2.0, 0.0, 0.0], 20.0);
        let g2 = encode_gyro([0.5, 0.0, 0.0], 20.0);
        let stream: Vec<u8> = [&a[..], &g_bad, &a2, &g2].concat();
        let (readings, d) = decode(&stream);
        assert_eq!(readings.len(), 1);
        let Some(Reading::Imu { accel_mps2, .. }) = readings.first() else {
            panic!("{readings:?}")
        };
        assert!((accel_mps2[0] - 2.0).abs() < 0.01);
        assert_eq!(d.stats().checksum_errors, 1);
        assert_eq!(d.stats().incomplete, 1);
    }

    #[test]
    fn unknown_types_are_counted_not_decoded() {
        let mag = encode_frame(0x54, [1, 2, 3, 4]);
        let (readings, d) = decode(&mag);
        assert!(readings.is_empty());
        assert_eq!(d.stats().unknown, 1);
        assert_eq!(d.stats().bytes_framed, FRAME_LEN as u64);
        assert_eq!(d.bytes_since_last_valid_frame(), 0);
    }
}
