//! How a robot's controller consumes the fused pose.
//!
//! Run a group (`insuwb launch config/robot.toml`), then
//! `cargo run -p insuwb-stage --example consumer -- config/robot.toml`.
//!
//! The controller opens the group's `fused` topic with the same prefix and
//! root as the stages (from the robot config), sleeps in the runtime's
//! `Waiter` until a pose arrives, and acts only on poses it can trust:
//! - `FLAG_VALID` set, `FLAG_STALE` clear: built on fresh INS data;
//! - `FLAG_DEGRADED`: INS-only coasting (no UWB for 150 ms): usable for a
//!   short while, with a covariance that grows;
//! - `FLAG_UWB_ONLY`: the INS cannot serve, the pose is the UWB fix's
//!   (valid, with the fix's covariance; attitude as last known);
//! - the covariance (`cov`, 6 x 6 over east, north, up position and velocity)
//!   says how much: here the controller slows down when the horizontal
//!   position sigma exceeds 0.2 m;
//! - `frame_id` names the frame of the pose (`map`: the anchors' ENU frame);
//! - `header.layout_version` must be `insuwb_msg::LAYOUT_VERSION` (the
//!   runtime drops other versions and counts them);
//! - the age of a pose is `monotonic_ns() - header.pub_time_ns`, and
//!   `pub_time_ns - uwb_meas_time_ns` is the sensor-to-pose latency.

use std::time::Duration;

use insuwb_group::robot::RobotConfig;
use insuwb_msg::{name_str, topics, FusedState};
use insuwb_runtime::{monotonic_ns, Stage, Wake};

fn main() -> anyhow::Result<()> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "config/robot.toml".into());
    let cfg = RobotConfig::load(std::path::Path::new(&path))?;
    let stage = Stage::new(cfg.runtime("controller"))?;
    let fused = stage.subscriber::<FusedState>(topics::FUSED)?;
    let waiter = stage.waiter()?;
    let pose = waiter.attach(&fused)?;
    for _ in 0..50 {
        match waiter.wait_timeout(Duration::from_secs(1))? {
            Wake::Shutdown => break,
            Wake::Timeout => println!("no pose for 1 s: stop the robot"),
            Wake::Fired(f) if f.contains(&pose) => {
                fused.drain(|p| {
                    let valid = p.header.flags & FusedState::FLAG_VALID != 0
                        && p.header.flags & FusedState::FLAG_STALE == 0;
                    let sigma = (p.cov[0][0] + p.cov[1][1]).sqrt();
                    let age_ms = monotonic_ns().saturating_sub(p.header.pub_time_ns) as f64 * 1e-6;
                    let mode = if !valid {
                        "hold: pose not valid"
                    } else if p.header.flags & FusedState::FLAG_DEGRADED != 0 {
                        "slow: coasting on INS"
                    } else if p.header.flags & FusedState::FLAG_UWB_ONLY != 0 {
                        "slow: UWB only, INS down"
                    } else if sigma > 0.2 {
                        "slow: uncertain"
                    } else {
                        "drive"
                    };
                    println!(
                        "{} ({:.2}, {:.2}) m yaw {:.2} rad sigma {:.3} m age {:.1} ms frame {}: {mode}",
                        p.header.seq,
                        p.pos_m[0],
                        p.pos_m[1],
                        p.yaw_rad,
                        sigma,
                        age_ms,
                        name_str(&p.frame_id)
                    );
                })?;
            }
            Wake::Fired(_) => {}
        }
    }
    Ok(())
}
