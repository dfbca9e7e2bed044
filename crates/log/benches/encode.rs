//! Encoding + framing one record into the writer's reused buffer.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use insuwb_log::{Record, RecordEncoder};
use insuwb_msg::{fixed_name, FusedState, Header, ImuSample};

fn imu() -> Record {
    Record::Imu(ImuSample {
        header: Header::new(123_456, 1_700_000_000_000),
        accel_mps2: [0.012, -0.034, 9.806_65],
        gyro_rps: [0.001, -0.002, 0.3],
    })
}

fn fused() -> Record {
    let mut cov = [[0.0; 6]; 6];
    for (i, row) in cov.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = if i == j { 0.01 * (i + 1) as f64 } else { 1e-4 };
        }
    }
    Record::Fused(FusedState {
        header: Header::new(9_876, 1_700_000_000_000),
        pos_m: [3.2, -1.5, 0.9],
        vel_mps: [0.4, 0.1, 0.0],
        quat: [0.995, 0.0, 0.0, 0.0998],
        yaw_rad: 0.2,
        cov,
        frame_id: fixed_name("map"),
        uwb_seq: 4_321,
        uwb_meas_time_ns: 1_699_999_990_000,
        uwb_pub_time_ns: 1_699_999_995_000,
        ins_seq: 123_456,
        ins_meas_time_ns: 1_700_000_000_000,
        ins_pub_time_ns: 1_700_000_000_500,
        filter_kind: 4,
        reserved: 0,
    })
}

fn bench(c: &mut Criterion) {
    let mut enc = RecordEncoder::new();
    for (name, rec) in [("encode_frame_imu", imu()), ("encode_frame_fused", fused())] {
        c.bench_function(name, |b| {
            b.iter(|| enc.encode(black_box(&rec)).map(<[u8]>::len).unwrap_or(0))
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
