//! What a device emulator sends: IMU samples and UWB position fixes turned
//! into timed byte chunks of a device protocol ([`imu_chunks`],
//! [`uwb_chunks`]) for [`crate::emulator::Player`]; `insuwb emulate` and
//! `insuwb demo --via-devices` use it with the recordings of
//! `insuwb_group::recording`.
//!
//! ```
//! use insuwb_devices::play::{imu_chunks, Encoding};
//! use insuwb_devices::Protocol;
//! use insuwb_msg::{Header, ImuSample};
//!
//! let imu: Vec<ImuSample> = (0..10)
//!     .map(|k| ImuSample {
//!         header: Header::new(0, k * 10_000_000),
//!         accel_mps2: [0.0, 0.0, 9.81],
//!         gyro_rps: [0.0; 3],
//!     })
//!     .collect();
//! let chunks = imu_chunks(&imu, &Encoding::new(Protocol::WitMotion))?;
//! // One 0x51 + 0x52 cycle per IMU sample, due when its last byte is in.
//! assert_eq!(chunks.len(), imu.len());
//! assert_eq!(chunks[0].1.len(), 22);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # The device model
//!
//! - **When bytes leave.** A sample measured at recording time `t` (ns
//!   since the start) is played at `t / speed` after the epoch. On a serial
//!   line of `baud` bauds (8N1) the frame starts then and its last byte
//!   arrives `wire_time_ns(len, baud)` later: the chunk is due then, so a
//!   driver that stamps a frame with "read time minus wire time" (at the
//!   same baud) gets the measurement time back. `baud = 0` (TCP): due at
//!   `t / speed`.
//! - **Device clocks.** MAVLink `time_usec`, NLink `system_time` (ms, wraps
//!   at 2^32) and the Eliko server's Unix time come from a [`DeviceClock`]:
//!   a start value plus the time played since the epoch, scaled by a drift
//!   in ppm. The clock runs in host time (it follows `t / speed`, not `t`),
//!   as a real device's would. WitMotion frames carry no clock.
//!
//! Pure and deterministic: the same samples and encoding give the same
//! bytes.

use crate::frame::wire_time_ns;
use crate::{eliko, mavlink, nlink, witmotion, Protocol};
use insuwb_msg::{ImuSample, UwbFix};

/// Temperature written in WitMotion frames, C.
pub const WITMOTION_TEMPERATURE_C: f64 = 25.0;

/// Default device-clock start of MAVLink (`time_usec`, since boot) and
/// NLink (`system_time`): 10 s, ns.
pub const DEFAULT_BOOT_CLOCK_START_NS: u64 = 10_000_000_000;

/// Default Eliko server Unix time at the epoch: 2023-11-14 22:13:20 UTC,
/// ns (fixed, so that runs are reproducible).
pub const DEFAULT_UNIX_CLOCK_START_NS: u64 = 1_700_000_000_000_000_000;

/// Default baud rate of the serial line modelled for serial protocols.
pub const DEFAULT_SERIAL_BAUD: u32 = 115_200;

/// A device's own clock: `start_ns` at the epoch, then running with the
/// host's clock `1 + drift_ppm * 1e-6` times as fast.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceClock {
    /// Device time at the epoch, ns.
    pub start_ns: u64,
    /// How much faster than the host the device clock runs, ppm (negative:
    /// slower).
    pub drift_ppm: f64,
}

impl DeviceClock {
    /// The protocol's default clock: 10 s since boot (MAVLink, NLink), a
    /// fixed Unix time (Eliko), no drift.
    #[must_use]
    pub fn default_for(protocol: Protocol) -> Self {
        let start_ns = match protocol {
            Protocol::Eliko => DEFAULT_UNIX_CLOCK_START_NS,
            Protocol::WitMotion | Protocol::Mavlink | Protocol::Nlink => {
                DEFAULT_BOOT_CLOCK_START_NS
            }
        };
        Self {
            start_ns,
            drift_ppm: 0.0,
        }
    }

    /// The device time when the host is `since_epoch_ns` past the epoch, ns.
    #[must_use]
    pub fn at(&self, since_epoch_ns: u64) -> u64 {
        #[allow(clippy::cast_precision_loss, clippy::cast_possible_truncation)]
        let extra = (since_epoch_ns as f64 * self.drift_ppm * 1e-6).round() as i64;
        self.start_ns
            .saturating_add(since_epoch_ns)
            .saturating_add_signed(extra)
    }
}

/// How samples become bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Encoding {
    /// The device protocol.
    pub protocol: Protocol,
    /// The device's clock (ignored by WitMotion).
    pub clock: DeviceClock,
    /// Serial line modelled for the wire time (0: none, as over TCP).
    pub baud: u32,
    /// UWB tag id (NLink: 0 to 255).
    pub tag: u32,
    /// Play speed (1: real time); finite and > 0.
    pub speed: f64,
}

impl Encoding {
    /// The protocol with its default clock, tag 1, real time, and a
    /// [`DEFAULT_SERIAL_BAUD`] line for the serial protocols (none for
    /// Eliko, which is TCP).
    #[must_use]
    pub fn new(protocol: Protocol) -> Self {
        Self {
            protocol,
            clock: DeviceClock::default_for(protocol),
            baud: if protocol == Protocol::Eliko {
                0
            } else {
                DEFAULT_SERIAL_BAUD
            },
            tag: 1,
            speed: 1.0,
        }
    }

    /// Host time since the epoch at which a sample of recording time `t_ns`
    /// is measured: `t / speed`.
    #[must_use]
    pub fn played_at(&self, t_ns: u64) -> u64 {
        #[allow(
            clippy::cast_precision_loss,
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss
        )]
        let ns = (t_ns as f64 / self.speed).round() as u64;
        ns
    }
}

/// Why samples could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The protocol does not carry this kind of sample (IMU: witmotion or
    /// mavlink; UWB: nlink or eliko).
    #[error("EncodeError::WrongProtocol: {protocol} does not carry {what}")]
    WrongProtocol {
        /// The protocol asked for.
        protocol: Protocol,
        /// `IMU samples` or `UWB positions`.
        what: &'static str,
    },
    /// The speed is not a finite number > 0.
    #[error("EncodeError::BadSpeed: the speed must be a finite number > 0")]
    BadSpeed,
    /// An NLink tag id is 8 bits.
    #[error("EncodeError::TagTooLarge: NLink tag ids are 0 to 255, got {0}")]
    TagTooLarge(u32),
    /// An encoder refused a sample (a buffer too small: a bug).
    #[error("EncodeError::Encoder: {0}")]
    Encoder(&'static str),
}

fn check_speed(enc: &Encoding) -> Result<(), EncodeError> {
    if enc.speed.is_finite() && enc.speed > 0.0 {
        Ok(())
    } else {
        Err(EncodeError::BadSpeed)
    }
}

/// One chunk per IMU sample: a WitMotion 0x51 + 0x52 cycle or a MAVLink v2
/// HIGHRES_IMU (IMU id 0, `time_usec` from the device clock, sequence
/// numbers counting up). Each is due, in ns after the epoch, when its last
/// byte arrives (see the module doc).
///
/// # Errors
/// [`EncodeError::WrongProtocol`], [`EncodeError::BadSpeed`].
pub fn imu_chunks(
    samples: &[ImuSample],
    enc: &Encoding,
) -> Result<Vec<(u64, Vec<u8>)>, EncodeError> {
    check_speed(enc)?;
    let mut out = Vec::with_capacity(samples.len());
    let mut buf = [0_u8; mavlink::MAX_FRAME_LEN];
    let mut seq = 0_u8;
    for s in samples {
        let at = enc.played_at(s.header.meas_time_ns);
        let bytes: Vec<u8> = match enc.protocol {
            Protocol::WitMotion => {
                witmotion::encode_imu(s.accel_mps2, s.gyro_rps, WITMOTION_TEMPERATURE_C).to_vec()
            }
            Protocol::Mavlink => {
                let time_usec = enc.clock.at(at) / 1_000;
                let n = mavlink::encode_highres_imu(
                    &mavlink::Header::v2(seq),
                    time_usec,
                    s.accel_mps2,
                    s.gyro_rps,
                    0,
                    &mut buf,
                );
                seq = seq.wrapping_add(1);
                buf.get(..n)
                    .ok_or(EncodeError::Encoder("mavlink frame length"))?
                    .to_vec()
            }
            protocol @ (Protocol::Nlink | Protocol::Eliko) => {
                return Err(EncodeError::WrongProtocol {
                    protocol,
                    what: "IMU samples",
                })
            }
        };
        let due = at.saturating_add(wire_time_ns(bytes.len(), enc.baud));
        out.push((due, bytes));
    }
    Ok(out)
}

/// One chunk per fix: an NLink Tag_Frame0 (tag id, role 2 (tag), position,
/// velocity when the fix has one (else zero), no anchor ranges, both clocks
/// from the device clock in ms) or an Eliko COORD line (8-bit sequence
/// counting up, the tag, position, the server's Unix time). Each is due, in
/// ns after the epoch, when its last byte arrives (see the module doc).
///
/// # Errors
/// [`EncodeError::WrongProtocol`], [`EncodeError::BadSpeed`],
/// [`EncodeError::TagTooLarge`].
pub fn uwb_chunks(fixes: &[UwbFix], enc: &Encoding) -> Result<Vec<(u64, Vec<u8>)>, EncodeError> {
    check_speed(enc)?;
    let mut out = Vec::with_capacity(fixes.len());
    let mut line = [0_u8; eliko::MAX_LINE_LEN];
    let mut seq = 0_u8;
    for f in fixes {
        let at = enc.played_at(f.header.meas_time_ns);
        let device_ns = enc.clock.at(at);
        let bytes: Vec<u8> = match enc.protocol {
            Protocol::Nlink => {
                let id = u8::try_from(enc.tag).map_err(|_| EncodeError::TagTooLarge(enc.tag))?;
                // The counter wraps at 2^32 ms: keep the low 32 bits.
                let ms = (device_ns / 1_000_000).to_le_bytes();
                let ms = u32::from_le_bytes([ms[0], ms[1], ms[2], ms[3]]);
                let vel_valid = f.header.flags & UwbFix::FLAG_VEL_VALID != 0;
                nlink::TagFrame {
                    id,
                    role: 2,
                    pos_m: f.pos_m,
                    vel_mps: if vel_valid { f.vel_mps } else { [0.0; 3] },
                    ranges_m: [0.0; 8],
                    local_time_ms: ms,
                    system_time_ms: ms,
                    voltage_v: 5.0,
                }
                .encode()
                .to_vec()
            }
            Protocol::Eliko => {
                let n =
                    eliko::encode_coord(seq, enc.tag, Some(f.pos_m), device_ns / 1_000, &mut line)
                        .map_err(|_| EncodeError::Encoder("eliko line length"))?;
                seq = seq.wrapping_add(1);
                line.get(..n)
                    .ok_or(EncodeError::Encoder("eliko line length"))?
                    .to_vec()
            }
            protocol @ (Protocol::WitMotion | Protocol::Mavlink) => {
                return Err(EncodeError::WrongProtocol {
                    protocol,
                    what: "UWB positions",
                })
            }
        };
        let due = at.saturating_add(wire_time_ns(bytes.len(), enc.baud));
        out.push((due, bytes));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;
    use crate::frame::{AnyDecoder, Reading};
    use insuwb_msg::Header;

    fn imu(t_ns: u64, a: f64) -> ImuSample {
        ImuSample {
            header: Header::new(0, t_ns),
            accel_mps2: [a, -a, 9.81],
            gyro_rps: [0.01, -0.02, a / 10.0],
        }
    }

    fn fix(t_ns: u64, x: f64, vel: bool) -> UwbFix {
        let mut f = UwbFix {
            header: Header::new(0, t_ns),
            pos_m: [x, -x, 0.3],
            vel_mps: [0.5, -0.25, 0.0],
            ..UwbFix::default()
        };
        if vel {
            f.header.flags |= UwbFix::FLAG_VEL_VALID;
        }
        f
    }

    fn decode(protocol: Protocol, chunks: &[(u64, Vec<u8>)]) -> Vec<Reading> {
        let mut d = AnyDecoder::new(protocol);
        let mut out = Vec::new();
        for (_, b) in chunks {
            d.push(b, &mut |r| out.push(r));
        }
        out
    }

    #[test]
    fn device_clock_adds_drift_in_ppm() {
        let c = DeviceClock {
            start_ns: 5,
            drift_ppm: 100.0,
        };
        assert_eq!(c.at(0), 5);
        assert_eq!(c.at(10_000_000_000), 5 + 10_000_000_000 + 1_000_000);
        let slow = DeviceClock {
            start_ns: 0,
            drift_ppm: -50.0,
        };
        assert_eq!(slow.at(1_000_000_000), 1_000_000_000 - 50_000);
    }

    #[test]
    fn witmotion_chunks_are_due_after_their_wire_time_and_decode_back() {
        let samples: Vec<ImuSample> = (0..5)
            .map(|k| imu(10_000_000 * (k + 1), k as f64))
            .collect();
        let enc = Encoding::new(Protocol::WitMotion);
        let chunks = imu_chunks(&samples, &enc).unwrap();
        // 22 bytes at 115200 baud, 8N1: 220 bits = 1_909_722 ns.
        assert_eq!(chunks[0].0, 10_000_000 + 1_909_722);
        assert_eq!(chunks[4].0, 50_000_000 + 1_909_722);
        let got = decode(Protocol::WitMotion, &chunks);
        assert_eq!(got.len(), 5);
        for (r, s) in got.iter().zip(&samples) {
            let Reading::Imu {
                accel_mps2,
                gyro_rps,
                device_time: None,
            } = r
            else {
                panic!("{r:?}")
            };
            for i in 0..3 {
                // Half an LSB: 16 g / 32768 / 2 and 2000 deg/s / 32768 / 2.
                assert!((accel_mps2[i] - s.accel_mps2[i]).abs() <= 0.0024, "{r:?}");
                assert!((gyro_rps[i] - s.gyro_rps[i]).abs() <= 5.4e-4, "{r:?}");
            }
        }
    }

    #[test]
    fn mavlink_time_usec_follows_the_device_clock_at_the_play_speed() {
        let samples = [imu(1_000_000_000, 0.0), imu(3_000_000_000, 1.0)];
        let enc = Encoding {
            clock: DeviceClock {
                start_ns: 7_000_000_000,
                drift_ppm: 100.0,
            },
            baud: 0,
            speed: 2.0,
            ..Encoding::new(Protocol::Mavlink)
        };
        let chunks = imu_chunks(&samples, &enc).unwrap();
        assert_eq!(chunks[0].0, 500_000_000);
        assert_eq!(chunks[1].0, 1_500_000_000);
        let got = decode(Protocol::Mavlink, &chunks);
        let times: Vec<u64> = got
            .iter()
            .map(|r| match r {
                Reading::Imu {
                    device_time: Some(t),
                    ..
                } => t.ticks * t.tick_ns,
                _ => panic!("{r:?}"),
            })
            .collect();
        // 7 s + 0.5 s * (1 + 100e-6) and 7 s + 1.5 s * (1 + 100e-6).
        assert_eq!(times, vec![7_500_050_000, 8_500_150_000]);
    }

    #[test]
    fn nlink_frames_carry_position_velocity_tag_and_wrapping_ms() {
        let fixes = [fix(100_000_000, 1.25, true), fix(200_000_000, 2.5, false)];
        let enc = Encoding {
            clock: DeviceClock {
                start_ns: (u64::from(u32::MAX) - 50) * 1_000_000,
                drift_ppm: 0.0,
            },
            tag: 7,
            ..Encoding::new(Protocol::Nlink)
        };
        let chunks = uwb_chunks(&fixes, &enc).unwrap();
        // 128 bytes at 115200 baud: 11_111_111 ns on the wire.
        assert_eq!(chunks[0].0, 100_000_000 + 11_111_111);
        let positions: Vec<Reading> = decode(Protocol::Nlink, &chunks)
            .into_iter()
            .filter(|r| matches!(r, Reading::Position { .. }))
            .collect();
        assert_eq!(positions.len(), 2);
        let Reading::Position {
            tag: 7,
            pos_m,
            vel_mps: Some(v),
            device_time: Some(t),
            ..
        } = positions[0]
        else {
            panic!("{:?}", positions[0])
        };
        assert!((pos_m[0] - 1.25).abs() < 1e-9 && (v[0] - 0.5).abs() < 1e-9);
        // 2^32 - 50 ms + 100 ms wraps to 49 ms.
        assert_eq!(t.ticks, 49);
        let Reading::Position {
            vel_mps: Some(v2), ..
        } = positions[1]
        else {
            panic!()
        };
        assert_eq!(v2, [0.0; 3]);
        let too_big = Encoding { tag: 256, ..enc };
        assert_eq!(
            uwb_chunks(&fixes, &too_big),
            Err(EncodeError::TagTooLarge(256))
        );
    }

    #[test]
    fn eliko_lines_carry_seq_tag_and_unix_time_without_wire_time() {
        let fixes: Vec<UwbFix> = (1..=300).map(|k| fix(k * 100_000_000, 0.5, true)).collect();
        let enc = Encoding {
            tag: 0x1A2B,
            ..Encoding::new(Protocol::Eliko)
        };
        let chunks = uwb_chunks(&fixes, &enc).unwrap();
        assert_eq!(chunks[0].0, 100_000_000);
        let text = String::from_utf8(chunks[0].1.clone()).unwrap();
        assert_eq!(
            text,
            "$PEKIO,COORD,0,0x001A2B,0.500,-0.500,0.300,,1700000000.100000\r\n"
        );
        let mut d = crate::eliko::Decoder::with_tags([0x1A2B]);
        let mut n = 0;
        for (_, b) in &chunks {
            d.push(b, &mut |_| n += 1);
        }
        // 300 lines, sequence wrapping at 256 without a gap.
        assert_eq!(n, 300);
        assert_eq!(d.stats().seq_gaps, 0);
    }

    #[test]
    fn protocols_refuse_the_other_kind_of_sample_and_bad_speeds() {
        let imu_enc = Encoding::new(Protocol::Eliko);
        assert!(matches!(
            imu_chunks(&[imu(0, 0.0)], &imu_enc),
            Err(EncodeError::WrongProtocol { .. })
        ));
        let uwb_enc = Encoding::new(Protocol::WitMotion);
        assert!(matches!(
            uwb_chunks(&[fix(0, 0.0, false)], &uwb_enc),
            Err(EncodeError::WrongProtocol { .. })
        ));
        for speed in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let enc = Encoding {
                speed,
                ..Encoding::new(Protocol::WitMotion)
            };
            assert_eq!(imu_chunks(&[], &enc), Err(EncodeError::BadSpeed));
        }
    }
}
