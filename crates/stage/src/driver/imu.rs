//! The IMU driver over a recorded source: publishes `imu` (checked),
//! `body_vel` and `height` (checked, where the recording holds them) and
//! `truth` (simulation and replay only).

use anyhow::Result;
use insuwb_msg::check::{HeightGate, ImuGate, VelocityGate};
use insuwb_msg::{topics, BodyVelocity, GroundTruth, Header, Height, ImuSample};
use insuwb_runtime::{HealthCounters, Pub, Stage};

use super::pacing::{self, Paced, Progress};
use crate::source::{self, Item, Want};
use insuwb_group::robot::RobotConfig;
use insuwb_group::sources::Source;

/// In lockstep the IMU stays this far ahead of fusion, ns: enough to cover
/// the next fixes, little to re-propagate after a correction.
const LEAD_NS: u64 = 250_000_000;

/// The IMU driver's part of the pacing loop.
struct ImuDriver {
    imu: Pub<ImuSample>,
    truth: Pub<GroundTruth>,
    /// Body velocities of the recording (a flow deck, odometry): a
    /// publisher only when it holds some.
    velocity: Option<Pub<BodyVelocity>>,
    vel_gate: VelocityGate,
    /// Heights of the recording (a range finder): a publisher only when it
    /// holds some.
    height: Option<Pub<Height>>,
    height_gate: HeightGate,
    generation: u32,
    source_id: u16,
    /// Values and time order ([`insuwb_msg::check`]), as `insuwb eval`.
    gate: ImuGate,
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
        // The recording's time on this run's clock, this process's stamps.
        let stamp = |h: &mut Header| {
            h.meas_time_ns = t_ns;
            h.generation = self.generation;
            h.source_id = self.source_id;
        };
        // Each sample is refused and counted by its stream's gate (the
        // heartbeat reports it), as `insuwb eval` does.
        match item {
            Item::Truth(mut s) => {
                stamp(&mut s.header);
                self.truth.publish_raw(s)?;
            }
            Item::Imu(mut s) => {
                stamp(&mut s.header);
                if self.gate.check(&s).is_ok() {
                    self.imu.publish_raw(s)?;
                    self.counters.published += 1;
                }
            }
            Item::Velocity(mut s) => {
                stamp(&mut s.header);
                if let (Ok(()), Some(p)) = (self.vel_gate.check(&s), self.velocity.as_mut()) {
                    p.publish_raw(s)?;
                }
            }
            Item::Height(mut s) => {
                stamp(&mut s.header);
                if let (Ok(()), Some(p)) = (self.height_gate.check(&s), self.height.as_mut()) {
                    p.publish_raw(s)?;
                }
            }
            Item::Tdoa(_) | Item::Range(_) => {}
        }
        Ok(())
    }

    fn heartbeat(&mut self) -> Result<HealthCounters> {
        let refused = self.gate.refusals();
        let vel = self.vel_gate.refusals();
        let height = self.height_gate.refusals();
        self.counters.dropped_invalid = refused.invalid() + vel.invalid() + height.invalid();
        self.counters.dropped_time = refused.time() + vel.time() + height.time();
        // Late subscribers get history only when the publisher acts.
        self.imu.update_connections()?;
        if let Some(p) = self.velocity.as_mut() {
            p.update_connections()?;
        }
        if let Some(p) = self.height.as_mut() {
            p.update_connections()?;
        }
        Ok(self.counters)
    }

    fn published(&self) -> u64 {
        self.counters.published
    }
}

/// Runs the IMU driver on the recorded source `source` (`sim` or
/// `replay:FILE`) until SIGINT/SIGTERM.
///
/// # Errors
/// The source cannot be opened, a port or the waiter fails.
pub fn run(cfg: &RobotConfig, source: &Source, speed: f64, epoch_ns: u64) -> Result<()> {
    let name = Want::Imu.role().name();
    let stage = Stage::new(cfg.runtime(name))?;
    let src = source::open(source, &cfg.sources.scenario, cfg.sources.seed, Want::Imu)?;
    tracing::info!("{name} driver: source {source}");
    let mut driver = ImuDriver {
        imu: stage.publisher(topics::IMU)?,
        truth: stage.publisher(topics::TRUTH)?,
        velocity: if src.has_velocity() {
            Some(stage.publisher(topics::BODY_VEL)?)
        } else {
            None
        },
        vel_gate: VelocityGate::new(),
        height: if src.has_height() {
            Some(stage.publisher(topics::HEIGHT)?)
        } else {
            None
        },
        height_gate: HeightGate::new(),
        generation: stage.generation(),
        source_id: stage.source_id(),
        gate: ImuGate::new(),
        counters: HealthCounters::default(),
    };
    pacing::run(&stage, name, src, speed, epoch_ns, &mut driver)
}
