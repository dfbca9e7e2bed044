//! `insuwb inspect`: per-topic rate, last-sample age, publishers and
//! subscribers of a running group.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use insuwb_group::robot::RobotConfig;
use insuwb_msg::{topics, FusedState, GroundTruth, Health, ImuSample, UwbFix};
use insuwb_runtime::{cleanup, monotonic_ns, Stage};

/// Arguments of `insuwb inspect`.
#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// The robot group configuration (for its prefix and run directory).
    pub config: PathBuf,
    /// Seconds to measure topic rates over.
    #[arg(long, default_value_t = 2.0)]
    pub duration: f64,
}

/// Runs `insuwb inspect`: per-topic rate, last-sample age, publishers and subscribers.
pub fn inspect(a: &InspectArgs) -> Result<()> {
    let cfg = RobotConfig::load(&a.config)?;
    let rt = cfg.runtime("inspect");
    let nodes = cleanup::list_nodes(&rt)?;
    println!("nodes:");
    for n in &nodes {
        println!(
            "  {:<12} pid {:>7} {:?}",
            n.name,
            n.pid.map_or("-".into(), |p| p.to_string()),
            n.state
        );
    }
    let services = cleanup::list_services(&rt)?;
    let stage = Stage::new(rt)?;
    let subs: Vec<Probe> = vec![
        probe::<ImuSample>(&stage, topics::IMU)?,
        probe::<insuwb_msg::UwbTdoa>(&stage, topics::UWB_TDOA)?,
        probe::<UwbFix>(&stage, topics::UWB_FIX)?,
        probe::<insuwb_msg::NavState>(&stage, topics::NAV)?,
        probe::<FusedState>(&stage, topics::FUSED)?,
        probe::<insuwb_msg::FilterDiag>(&stage, topics::DIAG)?,
        probe::<insuwb_msg::InsCorrection>(&stage, topics::CORRECTION)?,
        probe::<Health>(&stage, topics::HEALTH)?,
        probe::<GroundTruth>(&stage, topics::TRUTH)?,
        probe::<insuwb_msg::BodyVelocity>(&stage, topics::BODY_VEL)?,
    ];
    // The first samples are the publishers' history: let it arrive, then count.
    for _ in 0..3 {
        subs.iter().for_each(|(_, f)| {
            f();
        });
        let _ = stage.sleep(Duration::from_millis(150));
    }
    let start: Vec<u64> = subs.iter().map(|(_, f)| f().0).collect();
    let _ = stage.sleep(Duration::from_secs_f64(a.duration.clamp(0.1, 60.0)));
    let now = monotonic_ns();
    println!(
        "{:<12} {:>9} {:>12} {:>5} {:>5}",
        "topic", "rate Hz", "age ms", "pubs", "subs"
    );
    for (i, (topic, f)) in subs.iter().enumerate() {
        let (n, last) = f();
        let svc = services.iter().find(|s| s.name.ends_with(topic.as_str()));
        println!(
            "{:<12} {:>9.1} {:>12} {:>5} {:>5}",
            topic,
            (n - start[i]) as f64 / a.duration,
            last.map_or("-".into(), |t| format!(
                "{:.1}",
                now.saturating_sub(t) as f64 * 1e-6
            )),
            svc.and_then(|s| s.publishers)
                .map_or("-".into(), |v| v.to_string()),
            svc.and_then(|s| s.subscribers)
                .map_or("-".into(), |v| v.to_string())
        );
    }
    Ok(())
}

type Probe = (String, Box<dyn Fn() -> (u64, Option<u64>)>);

fn probe<T>(stage: &Stage, topic: &str) -> Result<Probe>
where
    T: insuwb_msg::HasHeader + Copy + std::fmt::Debug + iceoryx2::prelude::ZeroCopySend + 'static,
{
    let sub = stage.subscriber::<T>(topic)?;
    let state = std::cell::Cell::new((0u64, None::<u64>));
    Ok((
        topic.to_owned(),
        Box::new(move || {
            let (mut n, mut last) = state.get();
            let _ = sub.drain(|s| {
                n += 1;
                last = Some(s.header().pub_time_ns);
            });
            state.set((n, last));
            (n, last)
        }),
    ))
}
