//! The IMU driver over a recorded source: publishes `imu` (checked) and
//! `truth` (simulation and replay only).

use anyhow::Result;
use insuwb_msg::{topics, GroundTruth, ImuSample};
use insuwb_runtime::{HealthCounters, Pub, Stage};

use super::pacing::{self, Paced, Progress};
use crate::source::{self, Item, Want};
use insuwb_group::robot::RobotConfig;

/// Largest plausible accelerometer (m/s^2) and gyro (rad/s) magnitudes.
const MAX_ACCEL_MPS2: f64 = 400.0;
const MAX_RATE_RPS: f64 = 70.0;

/// In lockstep the IMU stays this far ahead of fusion, ns: enough to cover
/// the next fixes, little to re-propagate after a correction.
const LEAD_NS: u64 = 250_000_000;

/// Whether an IMU sample's values are finite and plausible.
#[must_use]
pub fn imu_ok(s: &ImuSample) -> bool {
    s.accel_mps2
        .iter()
        .all(|v| v.is_finite() && v.abs() < MAX_ACCEL_MPS2)
        && s.gyro_rps
            .iter()
            .all(|v| v.is_finite() && v.abs() < MAX_RATE_RPS)
}

/// The IMU driver's part of the pacing loop.
struct ImuDriver {
    imu: Pub<ImuSample>,
    truth: Pub<GroundTruth>,
    generation: u32,
    source_id: u16,
    last_t: Option<u64>,
    counters: HealthCounters,
}

impl Paced for ImuDriver {
    const FOLLOWS_FIXES: bool = true;
    const GIVES_WAY: bool = false;

    fn held(&self, t_ns: u64, p: &Progress) -> bool {
        // Before the first fused state, follow the fixes (the INS may still
        // be aligning); then follow fusion itself.
        t_ns > p.fused_time_ns.unwrap_or(p.fix_time_ns) + LEAD_NS
    }

    fn publish(&mut self, item: Item, t_ns: u64) -> Result<()> {
        match item {
            Item::Truth(mut s) => {
                s.header.meas_time_ns = t_ns;
                s.header.generation = self.generation;
                s.header.source_id = self.source_id;
                self.truth.publish_raw(s)?;
            }
            Item::Imu(mut s) => {
                if !imu_ok(&s) {
                    self.counters.dropped_invalid += 1;
                    return Ok(());
                }
                if self.last_t.is_some_and(|l| t_ns <= l) {
                    self.counters.dropped_time += 1;
                    return Ok(());
                }
                self.last_t = Some(t_ns);
                s.header.meas_time_ns = t_ns;
                s.header.generation = self.generation;
                s.header.source_id = self.source_id;
                self.imu.publish_raw(s)?;
                self.counters.published += 1;
            }
            Item::Tdoa(_) => {}
        }
        Ok(())
    }

    fn heartbeat(&mut self) -> Result<HealthCounters> {
        // Late subscribers get history only when the publisher acts.
        self.imu.update_connections()?;
        Ok(self.counters)
    }

    fn published(&self) -> u64 {
        self.counters.published
    }
}

/// Runs the IMU driver on the recorded source `source_spec` (`sim` or
/// `replay:FILE`) until SIGINT/SIGTERM.
///
/// # Errors
/// The source cannot be opened, a port or the waiter fails.
pub fn run(cfg: &RobotConfig, source_spec: &str, speed: f64, epoch_ns: u64) -> Result<()> {
    let name = Want::Imu.role().name();
    let stage = Stage::new(cfg.runtime(name))?;
    let src = source::open(
        source_spec,
        &cfg.sources.scenario,
        cfg.sources.seed,
        Want::Imu,
    )?;
    tracing::info!("{name} driver: source {source_spec}");
    let mut driver = ImuDriver {
        imu: stage.publisher(topics::IMU)?,
        truth: stage.publisher(topics::TRUTH)?,
        generation: stage.generation(),
        source_id: stage.source_id(),
        last_t: None,
        counters: HealthCounters::default(),
    };
    pacing::run(&stage, name, src, speed, epoch_ns, &mut driver)
}
