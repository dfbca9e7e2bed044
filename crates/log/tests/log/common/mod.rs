//! Shared test helpers: sample records of every type and scratch directories.
#![allow(dead_code, clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

use insuwb_log::Record;
use insuwb_msg::{
    fixed_name, BodyVelocity, DeviceCounters, FilterDiag, FusedState, GroundTruth, Header, Health,
    HealthState, Height, ImuSample, InsCorrection, NavState, StageCounters, UwbFix, UwbRange,
    UwbTdoa,
};

/// A scratch directory under the system temp dir, removed on drop.
pub struct Scratch(pub PathBuf);

impl Scratch {
    pub fn new(name: &str) -> Self {
        static N: AtomicU32 = AtomicU32::new(0);
        let n = N.fetch_add(1, Ordering::Relaxed);
        let p =
            std::env::temp_dir().join(format!("insuwb-log-test-{}-{name}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }

    pub fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A header whose every field is distinct and non-zero.
pub fn header(seq: u64) -> Header {
    Header {
        layout_version: insuwb_msg::LAYOUT_VERSION,
        source_id: 0x1234,
        flags: 0x8000_0001,
        generation: 7,
        reserved: 0,
        seq,
        meas_time_ns: 1_000_000_000 + seq * 5_000_000,
        pub_time_ns: 1_000_000_000 + seq * 5_000_000 + 12_345,
    }
}

/// Fills an array with `base + i * 0.25` (distinct values, exactly representable).
pub fn ramp<const N: usize>(base: f64) -> [f64; N] {
    let mut a = [0.0; N];
    for (i, v) in a.iter_mut().enumerate() {
        *v = base + i as f64 * 0.25;
    }
    a
}

/// One record of each type, in variant-index order, every field set to a
/// distinct value.
pub fn one_of_each(seq: u64) -> Vec<Record> {
    let h = header(seq);
    vec![
        Record::Imu(ImuSample {
            header: h,
            accel_mps2: [0.1, -0.2, 9.81],
            gyro_rps: [0.01, -0.02, 0.5],
        }),
        Record::Tdoa(UwbTdoa {
            header: h,
            anchor_a: 3,
            anchor_b: 70_000,
            diff_m: -1.25,
            anchor_a_pos_m: [0.0, 5.0, 2.5],
            anchor_b_pos_m: [8.0, -5.0, 2.75],
        }),
        Record::Fix(UwbFix {
            header: h,
            pos_m: ramp(1.0),
            vel_mps: ramp(-2.0),
            pos_cov_m2: [ramp(0.5), ramp(0.75), ramp(1.5)],
            vel_cov: [ramp(2.5), ramp(3.5), ramp(4.5)],
            gdop: 1.75,
            n_meas: 7,
            iterations: 4,
        }),
        Record::Nav(NavState {
            header: h,
            correction_id: 42,
            imu_seq: 41,
            imu_generation: 3,
            reserved: 0,
            pos_m: ramp(10.0),
            vel_mps: ramp(0.5),
            quat: [0.5, 0.5, -0.5, 0.5],
            accel_nav_mps2: ramp(-0.125),
            omega_nav_rps: ramp(0.0625),
            accel_bias_mps2: ramp(0.001),
            gyro_bias_rps: ramp(-0.0001),
        }),
        Record::Correction(InsCorrection {
            header: h,
            correction_id: 43,
            apply_at_seq: u64::MAX,
            imu_generation: u32::MAX,
            reserved: 0,
            d_pos_m: ramp(0.1),
            d_vel_mps: ramp(0.2),
            d_att_rad: ramp(0.3),
            d_accel_bias_mps2: ramp(0.4),
            d_gyro_bias_rps: ramp(0.5),
            reset_pos_m: ramp(0.6),
            reset_vel_mps: ramp(0.7),
            reset_quat: [1.0, 0.0, 0.0, 0.0],
        }),
        Record::Fused(FusedState {
            header: h,
            pos_m: ramp(1.0),
            vel_mps: ramp(2.0),
            quat: ramp(0.125),
            yaw_rad: -3.0,
            cov: [
                ramp(1.0),
                ramp(2.0),
                ramp(3.0),
                ramp(4.0),
                ramp(5.0),
                ramp(6.0),
            ],
            frame_id: fixed_name("map"),
            uwb_seq: 11,
            uwb_meas_time_ns: 12,
            uwb_pub_time_ns: 13,
            ins_seq: 14,
            ins_meas_time_ns: 15,
            ins_pub_time_ns: 16,
            filter_kind: 4,
            reserved: 0,
        }),
        Record::Diag(FilterDiag {
            header: h,
            innovation: ramp(-1.0),
            innovation_var: ramp(1.0),
            lambda: ramp(0.5),
            r_diag: ramp(0.01),
            nis: 3.5,
            fading: 1.25,
            dim: 6,
            filter_kind: 4,
        }),
        Record::Truth(GroundTruth {
            header: h,
            pos_m: ramp(3.0),
            vel_mps: [f64::INFINITY, f64::NEG_INFINITY, -0.0],
            quat: [0.0, 0.0, 0.0, 1.0],
        }),
        Record::Health(Health {
            header: h,
            stage: fixed_name("fusion"),
            pid: 4242,
            state: HealthState::Degraded.into(),
            received: 1,
            published: 2,
            dropped_version: 3,
            dropped_invalid: 4,
            dropped_time: 5,
            seq_gaps: 6,
            counters: StageCounters::Device(DeviceCounters {
                decoder_errors: 7,
                reconnects: u64::MAX,
                clock_offset_ns: Some(-9),
                clock_drift_ppb: None,
            })
            .into(),
        }),
        Record::BodyVel(BodyVelocity {
            header: h,
            vel_mps: [0.75, -0.125, 0.0],
            sigma_mps: [0.05, 0.0625, 0.0],
            source: BodyVelocity::SOURCE_FLOW,
            range_mm: 0,
        }),
        Record::Range(UwbRange {
            header: h,
            anchor: 7,
            quality: 42,
            range_m: 4.375,
            anchor_pos_m: ramp(-1.5),
        }),
        Record::Height(Height {
            header: h,
            range_m: 1.375,
            source: Height::SOURCE_RANGE_FINDER,
        }),
    ]
}

/// `n` records cycling through every type.
pub fn mixed(n: usize) -> Vec<Record> {
    let kinds = Record::TOPICS.len();
    (0..n).map(|i| one_of_each(i as u64)[i % kinds]).collect()
}

/// `n` IMU records with increasing sequence numbers.
pub fn imu_run(n: u64) -> Vec<Record> {
    (0..n)
        .map(|i| {
            Record::Imu(ImuSample {
                header: header(i),
                accel_mps2: [0.0, 0.0, 9.81 + i as f64 * 1e-3],
                gyro_rps: [0.0, 0.0, 0.1],
            })
        })
        .collect()
}
