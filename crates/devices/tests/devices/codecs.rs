#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The protocol codecs against frames built by hand from the specifications
//! (and, for MAVLink, by pymavlink 2.4.50 as an independent reference; for
//! the DWM1001, the example lines of Qorvo's API guide), encoder to decoder
//! round trips, resynchronisation after garbage and corruption, and frames
//! split across `push` calls at every point.

use std::f64::consts::PI;

use insuwb_devices::frame::{
    wire_time_ns, AnyDecoder, DecoderStats, DeviceTime, Protocol, Reading, STANDARD_GRAVITY,
};
use insuwb_devices::{dwm1001, eliko, mavlink, nlink, witmotion};
use rand::{RngExt as _, SeedableRng as _};
use rand_xoshiro::Xoshiro256StarStar;

const DEG: f64 = PI / 180.0;

fn decode(protocol: Protocol, bytes: &[u8]) -> (Vec<Reading>, DecoderStats) {
    decode_with(AnyDecoder::new(protocol), &[bytes])
}

fn decode_with(mut decoder: AnyDecoder, chunks: &[&[u8]]) -> (Vec<Reading>, DecoderStats) {
    let mut readings = Vec::new();
    for chunk in chunks {
        decoder.push(chunk, &mut |r| readings.push(r));
    }
    let stats = decoder.stats();
    assert_eq!(
        stats.bytes_in,
        stats.bytes_framed + stats.bytes_skipped + decoder.buffered() as u64,
        "byte accounting: {stats:?}"
    );
    (readings, stats)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

fn assert_close3(got: [f64; 3], want: [f64; 3], tol: f64) {
    for (g, w) in got.iter().zip(want) {
        assert!(close(*g, w, tol), "got {got:?}, want {want:?}");
    }
}

// ---------------------------------------------------------------- by hand

/// 0x51: ax 0x0800 = 2048 -> 2048/32768*16 g = 1 g; ay 0xFC00 = -1024 ->
/// -0.5 g; az 0; T 0x0A28 = 2600 -> 26.00 C.
/// Checksum 55+51+00+08+00+FC+00+00+28+0A = 0x1DC -> 0xDC.
const WIT_ACCEL: [u8; 11] = [
    0x55, 0x51, 0x00, 0x08, 0x00, 0xFC, 0x00, 0x00, 0x28, 0x0A, 0xDC,
];
/// 0x52: wx 0x0190 = 400 -> 400/32768*2000 = 24.4140625 deg/s; wy -400;
/// wz 0; T 26.00 C. Checksum 55+52+90+01+70+FE+00+00+28+0A = 0x2D8 -> 0xD8.
const WIT_GYRO: [u8; 11] = [
    0x55, 0x52, 0x90, 0x01, 0x70, 0xFE, 0x00, 0x00, 0x28, 0x0A, 0xD8,
];
/// 0x53: roll 0x2000 = 8192 -> 45 deg; pitch 0xE000 -> -45 deg; yaw 0x4000
/// -> 90 deg; version 0x0123. Checksum 55+53+00+20+00+E0+00+40+23+01 =
/// 0x20C -> 0x0C.
const WIT_ANGLE: [u8; 11] = [
    0x55, 0x53, 0x00, 0x20, 0x00, 0xE0, 0x00, 0x40, 0x23, 0x01, 0x0C,
];
/// 0x59: w 0x7FFF = 32767/32768; x 0; y 0xC000 = -0.5; z 0x4000 = 0.5.
/// Checksum 55+59+FF+7F+00+00+00+C0+00+40 = 0x32C -> 0x2C.
const WIT_QUAT: [u8; 11] = [
    0x55, 0x59, 0xFF, 0x7F, 0x00, 0x00, 0x00, 0xC0, 0x00, 0x40, 0x2C,
];

#[test]
fn witmotion_frames_built_by_hand() {
    let stream = [WIT_ACCEL, WIT_GYRO, WIT_ANGLE, WIT_QUAT].concat();
    let mut decoder = witmotion::Decoder::new();
    let mut readings = Vec::new();
    decoder.push(&stream, &mut |r| readings.push(r));
    let [imu, angle, quat] = readings.as_slice() else {
        panic!("{readings:?}")
    };
    let Reading::Imu {
        accel_mps2,
        gyro_rps,
        device_time,
    } = imu
    else {
        panic!("{imu:?}")
    };
    assert_close3(
        *accel_mps2,
        [STANDARD_GRAVITY, -0.5 * STANDARD_GRAVITY, 0.0],
        1e-12,
    );
    assert_close3(*gyro_rps, [24.4140625 * DEG, -24.4140625 * DEG, 0.0], 1e-12);
    assert_eq!(*device_time, None);
    let Reading::Attitude { rpy_rad, .. } = angle else {
        panic!("{angle:?}")
    };
    assert_close3(*rpy_rad, [45.0 * DEG, -45.0 * DEG, 90.0 * DEG], 1e-12);
    let Reading::Quaternion { wxyz, .. } = quat else {
        panic!("{quat:?}")
    };
    assert_eq!(*wxyz, [32767.0 / 32768.0, 0.0, -0.5, 0.5]);
    assert_eq!(decoder.temperature_c(), Some(26.0));
    assert_eq!(decoder.version(), Some(0x0123));
    let stats = decoder.stats();
    assert_eq!(
        (stats.frames_ok, stats.checksum_errors, stats.bytes_skipped),
        (4, 0, 0)
    );
    // The encoders write exactly these bytes.
    let imu = witmotion::encode_imu(
        [STANDARD_GRAVITY, -0.5 * STANDARD_GRAVITY, 0.0],
        [24.4140625 * DEG, -24.4140625 * DEG, 0.0],
        26.0,
    );
    assert_eq!(imu, [WIT_ACCEL, WIT_GYRO].concat().as_slice());
    assert_eq!(
        witmotion::encode_attitude([45.0 * DEG, -45.0 * DEG, 90.0 * DEG], 0x0123),
        WIT_ANGLE
    );
}

/// SCALED_IMU, MAVLink 1, seq 7, sys 1, comp 1: time_boot_ms 1000, xacc
/// 1000 mG, yacc -500 mG, zacc 0, xgyro 100 mrad/s, ygyro 0, zgyro -100,
/// mag 0. Header FE 16(22) 07 01 01 1A(26). CRC over bytes 1..=27 then
/// CRC_EXTRA 170: 0x3379 (pymavlink 2.4.50 wrote the same frame).
const MAV_V1_SCALED: [u8; 30] = [
    0xFE, 0x16, 0x07, 0x01, 0x01, 0x1A, // header
    0xE8, 0x03, 0x00, 0x00, // time_boot_ms 1000
    0xE8, 0x03, 0x0C, 0xFE, 0x00, 0x00, // xacc 1000, yacc -500, zacc 0
    0x64, 0x00, 0x00, 0x00, 0x9C, 0xFF, // xgyro 100, ygyro 0, zgyro -100
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // xmag ymag zmag
    0x79, 0x33, // CRC
];

/// HIGHRES_IMU, MAVLink 2, signed (incompat 0x01), seq 200, sys 1, comp 1:
/// time_usec 0x0102030405, acc (1, -2, 9.5), gyro (0.5, 0, -0.25), all else
/// 0 but fields_updated 0x3F; id 0 and the high byte of fields_updated
/// truncated: 61 payload bytes. CRC 0xC7BE then a 13-byte signature
/// (link 0, timestamp 0x010203040506, 6 bytes of HMAC), as pymavlink
/// 2.4.50 wrote it.
const MAV_V2_HIGHRES_SIGNED: [u8; 86] = [
    0xFD, 0x3D, 0x01, 0x00, 0xC8, 0x01, 0x01, 0x69, 0x00, 0x00, // header, msgid 105
    0x05, 0x04, 0x03, 0x02, 0x01, 0x00, 0x00, 0x00, // time_usec
    0x00, 0x00, 0x80, 0x3F, 0x00, 0x00, 0x00, 0xC0, 0x00, 0x00, 0x18, 0x41, // acc
    0x00, 0x00, 0x00, 0x3F, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0xBE, // gyro
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // mag
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // pressures
    0x00, 0x00, 0x00, 0x00, // temperature
    0x3F, // fields_updated low byte (payload byte 60)
    0xBE, 0xC7, // CRC
    0x00, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01, 0x49, 0x04, 0x7A, 0x6E, 0x77, 0x08, // signature
];

/// The same HIGHRES_IMU unsigned, as pymavlink 2.4.50 wrote it: CRC 0x5F9C.
const MAV_V2_HIGHRES_UNSIGNED_CRC: [u8; 2] = [0x9C, 0x5F];

#[test]
fn mavlink_frames_from_the_reference_implementation() {
    let stream = [&MAV_V1_SCALED[..], &MAV_V2_HIGHRES_SIGNED].concat();
    let (readings, stats) = decode(Protocol::Mavlink, &stream);
    let [scaled, highres] = readings.as_slice() else {
        panic!("{readings:?}")
    };
    let Reading::Imu {
        accel_mps2,
        gyro_rps,
        device_time,
    } = scaled
    else {
        panic!()
    };
    assert_close3(
        *accel_mps2,
        [STANDARD_GRAVITY, -0.5 * STANDARD_GRAVITY, 0.0],
        1e-12,
    );
    assert_close3(*gyro_rps, [0.1, 0.0, -0.1], 1e-12);
    assert_eq!(
        *device_time,
        Some(DeviceTime {
            ticks: 1000,
            tick_ns: 1_000_000,
            wrap: Some(1 << 32)
        })
    );
    let Reading::Imu {
        accel_mps2,
        gyro_rps,
        device_time,
    } = highres
    else {
        panic!()
    };
    assert_eq!(*accel_mps2, [1.0, -2.0, 9.5]);
    assert_eq!(*gyro_rps, [0.5, 0.0, -0.25]);
    assert_eq!(
        *device_time,
        Some(DeviceTime {
            ticks: 0x01_0203_0405,
            tick_ns: 1_000,
            wrap: None
        })
    );
    assert_eq!(
        (stats.frames_ok, stats.checksum_errors, stats.bytes_skipped),
        (2, 0, 0)
    );

    // Our encoders write the reference bytes.
    let mut buf = [0u8; mavlink::MAX_FRAME_LEN];
    let n = mavlink::encode_scaled_imu(
        &mavlink::Header::v1(7),
        1000,
        [STANDARD_GRAVITY, -0.5 * STANDARD_GRAVITY, 0.0],
        [0.1, 0.0, -0.1],
        &mut buf,
    );
    assert_eq!(&buf[..n], &MAV_V1_SCALED);
    let n = mavlink::encode_highres_imu(
        &mavlink::Header::v2(200),
        0x01_0203_0405,
        [1.0, -2.0, 9.5],
        [0.5, 0.0, -0.25],
        0,
        &mut buf,
    );
    assert_eq!(n, 73);
    assert_eq!(&buf[..2], &[0xFD, 0x3D]);
    assert_eq!(&buf[3..71], &MAV_V2_HIGHRES_SIGNED[3..71]);
    assert_eq!(&buf[71..73], &MAV_V2_HIGHRES_UNSIGNED_CRC);
}

/// Tag_Frame0: id 5, role 2; pos (1234, -2500, 800) mm = D2 04 00, 3C F6 FF,
/// 20 03 00; vel (1500, 0, -100) x 0.1 mm/s = DC 05 00, 00 00 00, 9C FF FF;
/// dis0 3000 mm = B8 0B 00, dis1 4500 mm = 94 11 00, others 0;
/// system_time 0x00012345 ms at byte 112 = 45 23 01 00; all else 0.
/// Checksum 55+01+05+02+D2+04+3C+F6+FF+20+03+DC+05+9C+FF+FF+B8+0B+94+11+45
/// +23+01 = 0x8D3 -> 0xD3.
fn nlink_hand_frame() -> [u8; 128] {
    let mut f = [0u8; 128];
    let set = |f: &mut [u8; 128], at: usize, bytes: &[u8]| {
        f[at..at + bytes.len()].copy_from_slice(bytes);
    };
    set(&mut f, 0, &[0x55, 0x01, 0x05, 0x02]);
    set(
        &mut f,
        4,
        &[0xD2, 0x04, 0x00, 0x3C, 0xF6, 0xFF, 0x20, 0x03, 0x00],
    );
    set(
        &mut f,
        13,
        &[0xDC, 0x05, 0x00, 0x00, 0x00, 0x00, 0x9C, 0xFF, 0xFF],
    );
    set(&mut f, 22, &[0xB8, 0x0B, 0x00, 0x94, 0x11, 0x00]);
    set(&mut f, 112, &[0x45, 0x23, 0x01, 0x00]);
    f[127] = 0xD3;
    f
}

#[test]
fn nlink_frame_built_by_hand() {
    let (readings, stats) = decode(Protocol::Nlink, &nlink_hand_frame());
    let time = Some(DeviceTime {
        ticks: 0x12345,
        tick_ns: 1_000_000,
        wrap: Some(1 << 32),
    });
    assert_eq!(
        readings,
        vec![
            Reading::Position {
                tag: 5,
                pos_m: [1.234, -2.5, 0.8],
                vel_mps: Some([0.15, 0.0, -0.01]),
                device_time: time,
                seq: None,
            },
            Reading::Ranges {
                tag: 5,
                ranges_m: [3.0, 4.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                device_time: time,
            },
            Reading::Range {
                anchor: 0,
                range_m: 3.0,
                anchor_pos_m: None,
                quality: None,
                last_of_round: false,
                device_time: time,
            },
            Reading::Range {
                anchor: 1,
                range_m: 4.5,
                anchor_pos_m: None,
                quality: None,
                last_of_round: true,
                device_time: time,
            },
        ]
    );
    assert_eq!((stats.frames_ok, stats.checksum_errors), (1, 0));
    let tf = nlink::TagFrame {
        id: 5,
        role: 2,
        pos_m: [1.234, -2.5, 0.8],
        vel_mps: [0.15, 0.0, -0.01],
        ranges_m: [3.0, 4.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        system_time_ms: 0x12345,
        ..nlink::TagFrame::default()
    };
    assert_eq!(tf.encode(), nlink_hand_frame());
}

#[test]
fn eliko_lines_written_by_hand() {
    assert_eq!(
        eliko::HANDSHAKE,
        ["$PEKIO,EULA,ACCEPT\r\n", "$PEKIO,SET_REPORT_LIST,COORD\r\n"]
    );
    let long = format!("$PEKIO,COORD,{}\r\n", "9".repeat(300));
    let stream = [
        "$PEKIO,COORD,255,0x00ABCD,1.250,-3.500,0.750,0x0,1700000000.123456\r\n",
        "$PEKIO,RR_L,3,0x00ABCD,0x000001,1200,0x000000,0,123,0,0\r\n",
        "$PEKIO,COORD,1,0x00ABCD,,,,0x4,1700000000.3\r\n", // no fix; seq 0 missed
        "$PEKIO,COORD,9,77,1.0,2.0,3.0,,1700000000\r\n",   // another tag
        long.as_str(),                                     // oversize
        "$PEKIO,COORD,2,0x00ABCD,1.0,nan,3.0,,1\r\n",      // malformed
        "$PEKIO,COORD,3,0x00ABCD,2,3,4,,1700000001\n",     // LF only
    ]
    .concat();
    let mut decoder = eliko::Decoder::with_tags([0xABCD]);
    let mut readings = Vec::new();
    decoder.push(stream.as_bytes(), &mut |r| readings.push(r));
    assert_eq!(
        readings,
        vec![
            Reading::Position {
                tag: 0xABCD,
                pos_m: [1.25, -3.5, 0.75],
                vel_mps: None,
                device_time: Some(DeviceTime {
                    ticks: 1_700_000_000_123_456,
                    tick_ns: 1_000,
                    wrap: None
                }),
                seq: Some(255),
            },
            Reading::Position {
                tag: 0xABCD,
                pos_m: [2.0, 3.0, 4.0],
                vel_mps: None,
                device_time: Some(DeviceTime {
                    ticks: 1_700_000_001_000_000,
                    tick_ns: 1_000,
                    wrap: None
                }),
                seq: Some(3),
            },
        ]
    );
    let s = decoder.stats();
    assert_eq!(s.frames_ok, 2);
    assert_eq!(s.unknown, 1);
    assert_eq!(s.no_fix, 1);
    assert_eq!(s.filtered, 1);
    assert_eq!(s.oversize, 1);
    assert_eq!(s.malformed, 1);
    // 255 -> 1 misses 0; the malformed seq 2 line is not counted; 1 -> 3
    // therefore misses one more.
    assert_eq!(s.seq_gaps, 2);
    assert_eq!(s.bytes_skipped, long.len() as u64);
    assert_eq!(s.bytes_in, stream.len() as u64);
}

/// The `lec` and `les` examples of Qorvo's "DWM1001 Firmware API Guide".
const DWM_LEC: &str = "DIST,4,AN0,0C2B,0.00,0.00,0.00,1.38,AN1,9825,3.00,0.00,0.00,2.26,\
AN2,14D0,3.00,3.00,0.00,2.86,AN3,18A9,0.00,3.00,0.00,2.76,POS,1.45,1.45,0.82,64\r\n";
const DWM_LES: &str = "1151[5.00,8.00,2.25]=6.48 0CA8[0.00,8.00,2.25]=6.51 \
111C[5.00,0.00,2.25]=3.18 1150[0.00,0.00,2.25]=3.16 le_us=2576 est[2.57,1.98,1.68,100]\r\n";

fn dwm_range(anchor: u32, pos: [f64; 3], range_m: f64, last: bool) -> Reading {
    Reading::Range {
        anchor,
        range_m,
        anchor_pos_m: Some(pos),
        quality: None,
        last_of_round: last,
        device_time: None,
    }
}

fn dwm_position(tag: u32, pos_m: [f64; 3]) -> Reading {
    Reading::Position {
        tag,
        pos_m,
        vel_mps: None,
        device_time: None,
        seq: None,
    }
}

#[test]
fn dwm1001_lines_of_the_api_guide() {
    assert_eq!(DWM_LEC.len(), dwm1001::NOMINAL_LINE_LEN);
    assert_eq!(Protocol::Dwm1001.nominal_frame_len(), DWM_LEC.len());
    let stream = ["dwm> lec\r\n", DWM_LEC, "\r\n", "dwm> les\n", DWM_LES].concat();
    let mut decoder = dwm1001::Decoder::with_tag(7);
    let mut readings = Vec::new();
    decoder.push(stream.as_bytes(), &mut |r| readings.push(r));
    assert_eq!(
        readings,
        vec![
            dwm_range(0x0C2B, [0.0, 0.0, 0.0], 1.38, false),
            dwm_range(0x9825, [3.0, 0.0, 0.0], 2.26, false),
            dwm_range(0x14D0, [3.0, 3.0, 0.0], 2.86, false),
            dwm_range(0x18A9, [0.0, 3.0, 0.0], 2.76, true),
            dwm_position(7, [1.45, 1.45, 0.82]),
            dwm_range(0x1151, [5.0, 8.0, 2.25], 6.48, false),
            dwm_range(0x0CA8, [0.0, 8.0, 2.25], 6.51, false),
            dwm_range(0x111C, [5.0, 0.0, 2.25], 3.18, false),
            dwm_range(0x1150, [0.0, 0.0, 2.25], 3.16, true),
            dwm_position(7, [2.57, 1.98, 1.68]),
        ]
    );
    let s = decoder.stats();
    assert_eq!((s.frames_ok, s.unknown, s.malformed), (2, 3, 0), "{s:?}");
    assert_eq!((s.bytes_framed, s.bytes_skipped), (stream.len() as u64, 0));
    assert_eq!(decoder.bytes_since_last_valid_frame(), 0);
}

#[test]
fn dwm1001_lines_without_a_position_and_positions_alone() {
    let stream = concat!(
        "DIST,2,AN0,0001,1.00,2.00,3.00,4.00,AN1,ABCD,-1.50,0.00,10.25,0.05\n",
        "POS,-1.45,2.00,0.82,64\r\n",
        "POS,1.00,1.00,1.00,0\r\n", // quality 0: no position
        "0001[1.00,2.00,3.00]=4.00 le_us=12\r\n",
        "est[1.00,2.00,3.00,5]\r\n",
        "DIST,0\r\n", // no anchor: nothing
    );
    let (readings, s) = decode(Protocol::Dwm1001, stream.as_bytes());
    assert_eq!(
        readings,
        vec![
            dwm_range(1, [1.0, 2.0, 3.0], 4.0, false),
            dwm_range(0xABCD, [-1.5, 0.0, 10.25], 0.05, true),
            dwm_position(0, [-1.45, 2.0, 0.82]),
            dwm_range(1, [1.0, 2.0, 3.0], 4.0, true),
            dwm_position(0, [1.0, 2.0, 3.0]),
        ]
    );
    assert_eq!((s.frames_ok, s.no_fix, s.malformed), (4, 2, 0), "{s:?}");
}

#[test]
fn dwm1001_malformed_lines_give_nothing() {
    let good = "DIST,1,AN0,0001,1.00,2.00,3.00,4.00\r\n";
    let anchors = |n: usize| -> String {
        (0..n)
            .map(|i| format!(",AN{i},{i:04X},1.00,2.00,3.00,4.00"))
            .collect()
    };
    let les_anchors = |n: usize| -> String {
        (0..n)
            .map(|i| format!("{i:04X}[1.00,2.00,3.00]=4.00 "))
            .collect()
    };
    let malformed = [
        "DIST,2,AN0,0001,1.00,2.00,3.00,4.00\r\n".to_owned(), // count too high
        "DIST,0,AN0,0001,1.00,2.00,3.00,4.00\r\n".to_owned(), // count too low
        "DIST,1,AN1,0001,1.00,2.00,3.00,4.00\r\n".to_owned(), // wrong index
        "DIST,1,AN0,001,1.00,2.00,3.00,4.00\r\n".to_owned(),  // id of 3 digits
        "DIST,1,AN0,0001,1.00,2.00,3.00,nan\r\n".to_owned(),
        "DIST,1,AN0,0001,1.00,x,3.00,4.00\r\n".to_owned(),
        "DIST,1,AN0,0001,1.00,2.00,3.00\r\n".to_owned(),
        "DIST,1,AN0,0001,1.00,2.00,3.00,4.00,\r\n".to_owned(),
        "DIST,1,AN0,0001,1.00,2.00,3.00,4.00,POS,1,2,3\r\n".to_owned(),
        "DIST,1,AN0,0001,1.00,2.00,3.00,4.00,POS,1,2,3,101\r\n".to_owned(),
        "DIST,1,AN0,0001,1.00,2.00,3.00,4.00,POS,1,2,3,50,7\r\n".to_owned(),
        "DIST,x\r\n".to_owned(),
        format!("DIST,17{}\r\n", anchors(17)),
        "POS,1.00,2.00,inf,50\r\n".to_owned(),
        "POS,1.00,2.00,3.00\r\n".to_owned(),
        "0001[1.00,2.00,3.00]=NaN\r\n".to_owned(),
        "0001[1.00,2.00]=4.00\r\n".to_owned(),
        "0001[1.00,2.00,3.00,4.00]=4.00\r\n".to_owned(),
        "0001[1.00,2.00,3.00]=4.00 est[1,2,3,50] 0002[1.00,2.00,3.00]=4.00\r\n".to_owned(),
        "0001[1.00,2.00,3.00]=4.00 le_us=x\r\n".to_owned(),
        "0001[1.00,2.00,3.00]=4.00 est[1,2,3]\r\n".to_owned(),
        format!("{}\r\n", les_anchors(17)),
        "DIST,1,AN0,0001,1.00,2.00,3.00,4.é\r\n".to_owned(),
    ];
    for line in &malformed {
        let stream = [line.as_str(), good].concat();
        let (readings, s) = decode(Protocol::Dwm1001, stream.as_bytes());
        assert_eq!(readings.len(), 1, "{line:?} gave {readings:?}");
        assert_eq!((s.malformed, s.frames_ok), (1, 1), "{line:?}: {s:?}");
    }
    // An over-long line is dropped whole, up to its end.
    let long = format!("DIST,1{}\r\n", "9".repeat(dwm1001::MAX_LINE_LEN));
    let (readings, s) = decode(Protocol::Dwm1001, [long.as_str(), good].concat().as_bytes());
    assert_eq!((readings.len(), s.oversize, s.malformed), (1, 1, 0));
    assert_eq!(s.bytes_skipped, long.len() as u64);
}

// ------------------------------------------------------------- round trips

#[test]
fn witmotion_round_trip_within_one_lsb() {
    let accel_lsb = 16.0 * STANDARD_GRAVITY / 32768.0;
    let gyro_lsb = 2000.0 / 32768.0 * DEG;
    for k in 0..50 {
        let x = f64::from(k) - 25.0;
        let accel = [x * 3.1, -x * 1.7, 9.81 + x * 0.05];
        let gyro = [x * 0.13, x * -0.29, x * 0.011];
        let (readings, _) = decode(
            Protocol::WitMotion,
            &witmotion::encode_imu(accel, gyro, 20.0),
        );
        let [Reading::Imu {
            accel_mps2,
            gyro_rps,
            ..
        }] = readings.as_slice()
        else {
            panic!("{readings:?}")
        };
        assert_close3(*accel_mps2, accel, accel_lsb / 2.0 + 1e-12);
        assert_close3(*gyro_rps, gyro, gyro_lsb / 2.0 + 1e-12);
    }
}

#[test]
fn mavlink_round_trip_both_versions_and_messages() {
    let mut buf = [0u8; mavlink::MAX_FRAME_LEN];
    for k in 0..50u8 {
        let x = f64::from(k) - 25.0;
        let accel = [x * 0.37, -x * 1.1, -9.81 + x];
        let gyro = [x * 0.01, x * -0.2, 0.0];
        for header in [mavlink::Header::v1(k), mavlink::Header::v2(k)] {
            let n =
                mavlink::encode_highres_imu(&header, u64::from(k) * 5000, accel, gyro, 0, &mut buf);
            let (readings, stats) = decode(Protocol::Mavlink, &buf[..n]);
            let [Reading::Imu {
                accel_mps2,
                gyro_rps,
                device_time,
            }] = readings.as_slice()
            else {
                panic!("{readings:?}")
            };
            assert_eq!(*accel_mps2, accel.map(|v| f64::from(v as f32)));
            assert_eq!(*gyro_rps, gyro.map(|v| f64::from(v as f32)));
            assert_eq!(device_time.map(|t| t.ticks), Some(u64::from(k) * 5000));
            assert_eq!(stats.frames_ok, 1);

            let n = mavlink::encode_scaled_imu(&header, u32::from(k), accel, gyro, &mut buf);
            let (readings, _) = decode(Protocol::Mavlink, &buf[..n]);
            let [Reading::Imu {
                accel_mps2,
                gyro_rps,
                ..
            }] = readings.as_slice()
            else {
                panic!("{readings:?}")
            };
            assert_close3(*accel_mps2, accel, STANDARD_GRAVITY / 2000.0 + 1e-12);
            assert_close3(*gyro_rps, gyro, 0.0005 + 1e-12);
        }
    }
}

#[test]
fn nlink_and_eliko_round_trip_to_the_millimetre() {
    let mut line = [0u8; eliko::MAX_LINE_LEN];
    for k in 0..50u32 {
        let x = f64::from(k) * 0.731 - 12.0;
        let pos = [x, -2.0 * x, 0.5 + x / 10.0];
        let reading = Reading::Position {
            tag: k,
            pos_m: pos,
            vel_mps: Some([x / 100.0, 0.0, -x / 50.0]),
            device_time: Some(DeviceTime {
                ticks: u64::from(k) * 37,
                tick_ns: 1_000_000,
                wrap: Some(1 << 32),
            }),
            seq: Some(k),
        };
        let (readings, _) = decode(Protocol::Nlink, &nlink::encode(&reading).unwrap());
        let Some(Reading::Position {
            tag,
            pos_m,
            vel_mps,
            device_time,
            ..
        }) = readings.first()
        else {
            panic!("{readings:?}")
        };
        assert_eq!(*tag, k);
        assert_close3(*pos_m, pos, 0.0005 + 1e-12);
        assert_close3(
            vel_mps.unwrap(),
            [x / 100.0, 0.0, -x / 50.0],
            0.00005 + 1e-12,
        );
        assert_eq!(device_time.map(|t| t.ticks), Some(u64::from(k) * 37));

        let n = eliko::encode(&reading, &mut line).unwrap();
        let (readings, _) = decode(Protocol::Eliko, &line[..n]);
        let Some(Reading::Position {
            tag,
            pos_m,
            device_time,
            seq,
            ..
        }) = readings.first()
        else {
            panic!("{readings:?}")
        };
        assert_eq!((*tag, *seq), (k, Some(k)));
        assert_close3(*pos_m, pos, 0.0005 + 1e-12);
        // 37 ms steps written as microseconds of Unix time.
        assert_eq!(device_time.map(|t| t.ticks), Some(u64::from(k) * 37_000));
    }
}

#[test]
fn dwm1001_lines_round_trip_to_the_centimetre() {
    let mut out = Vec::new();
    for k in 0..50u32 {
        let x = f64::from(k) * 0.731 - 12.0;
        let anchors: Vec<dwm1001::AnchorRange> = (0..k % 17)
            .map(|i| dwm1001::AnchorRange {
                id: (k * 977 + i * 131) & 0xFFFF,
                pos_m: [x + f64::from(i), -x, 2.5],
                range_m: f64::from(i) * 1.37 + 0.004,
            })
            .collect();
        let pos = (k % 3 != 0).then_some(([x, 2.0 * x, 0.5], (k * 7 % 101) as u8));
        for les in [false, true] {
            out.clear();
            let n = if les {
                let le_us = (k % 2 == 0).then_some(k * 100);
                match dwm1001::encode_les(&anchors, pos, le_us, &mut out) {
                    Err(dwm1001::EncodeError::Empty) => continue,
                    other => other.unwrap(),
                }
            } else {
                dwm1001::encode_lec(&anchors, pos, &mut out).unwrap()
            };
            assert_eq!(n, out.len());
            let (readings, s) = decode(Protocol::Dwm1001, &out);
            let mut want: Vec<Reading> = anchors
                .iter()
                .enumerate()
                .map(|(i, a)| dwm_range(a.id, a.pos_m, a.range_m, i + 1 == anchors.len()))
                .collect();
            if let Some((p, q)) = pos.filter(|(_, q)| *q > 0) {
                assert!(q <= 100);
                want.push(dwm_position(0, p));
            }
            assert_eq!(
                readings.len(),
                want.len(),
                "{}",
                String::from_utf8_lossy(&out)
            );
            for (got, want) in readings.iter().zip(&want) {
                match (got, want) {
                    (
                        Reading::Range {
                            anchor,
                            range_m,
                            anchor_pos_m: Some(p),
                            last_of_round,
                            ..
                        },
                        Reading::Range {
                            anchor: a,
                            range_m: r,
                            anchor_pos_m: Some(wp),
                            last_of_round: l,
                            ..
                        },
                    ) => {
                        assert_eq!((anchor, last_of_round), (a, l));
                        assert!(close(*range_m, *r, 0.005 + 1e-9), "{got:?} {want:?}");
                        assert_close3(*p, *wp, 0.005 + 1e-9);
                    }
                    (Reading::Position { pos_m, .. }, Reading::Position { pos_m: w, .. }) => {
                        assert_close3(*pos_m, *w, 0.005 + 1e-9);
                    }
                    _ => panic!("{got:?} for {want:?}"),
                }
            }
            assert_eq!(s.malformed, 0);
        }
    }
    out.clear();
    dwm1001::encode_lep([1.0, -2.0, 0.125], 64, &mut out).unwrap();
    assert_eq!(out, b"POS,1.00,-2.00,0.12,64\r\n");
}

// --------------------------------------------------- streams of many frames

/// `count` units of `protocol`, each carrying one distinct reading (a
/// WitMotion unit is a 0x51/0x52 pair): the bytes and where each unit starts.
fn units(protocol: Protocol, count: u32) -> Vec<Vec<u8>> {
    let mut buf = [0u8; mavlink::MAX_FRAME_LEN];
    (0..count)
        .map(|k| {
            let x = f64::from(k);
            match protocol {
                Protocol::WitMotion => {
                    witmotion::encode_imu([x * 0.1, 1.0, 9.8], [0.0, x * 0.01, 0.0], 20.0).to_vec()
                }
                Protocol::Mavlink => {
                    let header = if k % 2 == 0 {
                        mavlink::Header::v2(k as u8)
                    } else {
                        mavlink::Header::v1(k as u8)
                    };
                    let n = mavlink::encode_highres_imu(
                        &header,
                        u64::from(k) * 1000,
                        [x, 0.0, -9.8],
                        [0.0; 3],
                        0,
                        &mut buf,
                    );
                    buf[..n].to_vec()
                }
                Protocol::Nlink => nlink::TagFrame {
                    id: 1,
                    pos_m: [x, 2.0, 1.0],
                    system_time_ms: k * 10,
                    ..nlink::TagFrame::default()
                }
                .encode()
                .to_vec(),
                Protocol::Eliko => {
                    let mut line = [0u8; eliko::MAX_LINE_LEN];
                    let n = eliko::encode_coord(
                        k as u8,
                        0xAB,
                        Some([x, 2.0, 1.0]),
                        1_700_000_000_000_000 + u64::from(k) * 100_000,
                        &mut line,
                    )
                    .unwrap();
                    line[..n].to_vec()
                }
                Protocol::Dwm1001 => {
                    // lec and les lines in turn.
                    let anchors = [0x0C2B, 0x9825].map(|id| dwm1001::AnchorRange {
                        id,
                        pos_m: [3.0, 0.0, 1.5],
                        range_m: 2.0 + x * 0.01,
                    });
                    let pos = Some(([x, 2.0, 1.0], 90));
                    let mut line = Vec::new();
                    if k % 2 == 0 {
                        dwm1001::encode_lec(&anchors, pos, &mut line).unwrap();
                    } else {
                        dwm1001::encode_les(&anchors, pos, Some(k), &mut line).unwrap();
                    }
                    line
                }
            }
        })
        .collect()
}

/// Readings of each unit decoded on its own.
fn unit_readings(protocol: Protocol, units: &[Vec<u8>]) -> Vec<Vec<Reading>> {
    units.iter().map(|u| decode(protocol, u).0).collect()
}

/// Garbage that holds every protocol's start bytes and a few plausible
/// headers, so that resynchronisation has to reject false starts.
const GARBAGE: [u8; 23] = [
    0x55, 0x00, 0x13, 0xFD, 0x02, 0x00, 0xFE, 0x55, 0x51, 0x01, 0x24, 0x0A, 0x55, 0x01, 0x07, 0xFE,
    0x16, 0x00, b'$', b'P', b'E', b'\r', 0x99,
];

#[test]
fn garbage_between_frames_loses_nothing() {
    for protocol in Protocol::ALL {
        let units = units(protocol, 12);
        let expected: Vec<Reading> = unit_readings(protocol, &units).concat();
        let mut stream = GARBAGE.to_vec();
        for u in &units {
            stream.extend_from_slice(u);
            stream.extend_from_slice(&GARBAGE);
        }
        let (readings, stats) = decode(protocol, &stream);
        assert_eq!(readings, expected, "{protocol}");
        assert!(
            stats.bytes_skipped >= GARBAGE.len() as u64,
            "{protocol}: {stats:?}"
        );
        assert!(stats.resyncs >= 1, "{protocol}: {stats:?}");
    }
}

#[test]
fn a_corrupted_frame_loses_exactly_that_frame() {
    for protocol in Protocol::ALL {
        let units = units(protocol, 5);
        let per_unit = unit_readings(protocol, &units);
        let victim = 2;
        for at in 0..units[victim].len() {
            let mut corrupted = units.clone();
            corrupted[victim][at] ^= 0xFF;
            let stream = corrupted.concat();
            let (readings, _) = decode(protocol, &stream);
            let expected: Vec<Reading> = per_unit
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != victim)
                .flat_map(|(_, r)| r.clone())
                .collect();
            assert_eq!(readings, expected, "{protocol}: byte {at} flipped");
        }
    }
}

#[test]
fn frames_split_at_every_point_decode_the_same() {
    for protocol in Protocol::ALL {
        let stream = units(protocol, 3).concat();
        let whole = decode(protocol, &stream);
        for at in 0..=stream.len() {
            let (a, b) = stream.split_at(at);
            let split = decode_with(AnyDecoder::new(protocol), &[a, b]);
            assert_eq!(split, whole, "{protocol}: split at {at}");
        }
        let bytes: Vec<&[u8]> = stream.chunks(1).collect();
        assert_eq!(
            decode_with(AnyDecoder::new(protocol), &bytes),
            whole,
            "{protocol}"
        );
    }
}

// -------------------------------------------------------------- the rest

#[test]
fn protocols_by_name() {
    for (name, p) in Protocol::NAMES.iter().zip(Protocol::ALL) {
        assert_eq!(name.parse::<Protocol>(), Ok(p));
        assert_eq!(p.to_string(), *name);
        assert_eq!(AnyDecoder::new(p).protocol(), p);
    }
    assert_eq!("MAVLink".parse::<Protocol>(), Ok(Protocol::Mavlink));
    let err = "ubx".parse::<Protocol>().unwrap_err().to_string();
    assert_eq!(
        err,
        "unknown device protocol \"ubx\"; known: witmotion, mavlink, nlink, eliko, dwm1001"
    );
}

#[test]
fn time_on_the_wire() {
    // 11 bytes x 10 bits at 115200 baud: 110/115200 s = 954861.1 us.
    assert_eq!(wire_time_ns(11, 115_200), 954_861);
    // 128 bytes at 921600 baud: 1280/921600 s = 1388888.9 ns.
    assert_eq!(wire_time_ns(128, 921_600), 1_388_888);
    assert_eq!(wire_time_ns(64, 0), 0);
    assert_eq!(Protocol::Nlink.nominal_frame_len(), 128);
    assert_eq!(Protocol::Mavlink.nominal_frame_len(), 75);
}

#[test]
fn noise_counts_towards_the_wrong_baud_alarm() {
    // A stream at the wrong baud rate looks like this: bytes, never a frame.
    let mut rng = Xoshiro256StarStar::seed_from_u64(1);
    let noise: Vec<u8> = (0..5000).map(|_| rng.random::<u8>()).collect();
    for protocol in Protocol::ALL {
        let mut decoder = AnyDecoder::new(protocol);
        decoder.push(&noise, &mut |r| panic!("{protocol} decoded noise: {r:?}"));
        assert!(decoder.bytes_since_last_valid_frame() >= 4000, "{protocol}");
        let valid = units(protocol, 1).concat();
        decoder.push(&valid, &mut |_| {});
        assert_eq!(decoder.bytes_since_last_valid_frame(), 0, "{protocol}");
    }
}

#[test]
fn clear_drops_a_partial_frame() {
    for protocol in Protocol::ALL {
        let unit = units(protocol, 1).concat();
        let mut decoder = AnyDecoder::new(protocol);
        decoder.push(&unit[..5], &mut |_| {});
        assert!(decoder.buffered() > 0, "{protocol}");
        decoder.clear();
        assert_eq!(decoder.buffered(), 0);
        let mut n = 0;
        decoder.push(&unit, &mut |_| n += 1);
        assert!(n >= 1, "{protocol}");
    }
}
