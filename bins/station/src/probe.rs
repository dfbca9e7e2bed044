//! `insuwb-station probe ros2|zenoh`: a bridge's poses as received outside
//! the robot, for `insuwb bench latency --with ros2|zenoh`. One line per
//! pose on standard output, `STAMP_NS RX_NS` (the pose's stamp and its
//! arrival, CLOCK_MONOTONIC ns; the bench's group stamps in
//! CLOCK_MONOTONIC), until standard input closes or `--seconds` pass. It
//! prints `ready` on standard error once its reader is open.
//!
//! The probe is a process of its own so that the `insuwb` command needs
//! neither DDS nor Zenoh: the transports are built with the bridges and the
//! station.

use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use insuwb_runtime::monotonic_ns;

/// Arguments of `insuwb-station probe`.
#[derive(Debug, clap::Args)]
pub struct ProbeArgs {
    /// Which bridge's poses.
    #[command(subcommand)]
    pub what: ProbeWhat,
    /// Stop after this many seconds at most.
    #[arg(long, default_value_t = 120.0, global = true)]
    pub seconds: f64,
}

/// The bridge probed.
#[derive(Debug, clap::Subcommand)]
pub enum ProbeWhat {
    /// A DDS reader of the ROS 2 bridge's odometry, with the `[ros2]` settings of a robot config.
    Ros2 {
        /// The robot group configuration whose `[ros2]` the bridge runs with.
        config: PathBuf,
    },
    /// A Zenoh subscriber of the Zenoh bridge's poses, listening on ENDPOINT (the bridge connects to it).
    Zenoh {
        /// Where to listen, e.g. tcp/127.0.0.1:7447.
        endpoint: String,
        /// The robot id the bridge publishes as.
        robot: String,
    },
}

/// Runs `insuwb-station probe`.
pub fn run(a: &ProbeArgs) -> Result<()> {
    if !(a.seconds.is_finite() && a.seconds > 0.0 && a.seconds <= 3600.0) {
        anyhow::bail!("--seconds must be in (0, 3600], got {}", a.seconds);
    }
    let bound = Duration::from_secs_f64(a.seconds);
    // Standard input closing is the stop signal.
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    std::thread::spawn(move || {
        let mut sink = [0u8; 64];
        let mut stdin = std::io::stdin();
        while matches!(stdin.read(&mut sink), Ok(n) if n > 0) {}
        flag.store(true, Ordering::Relaxed);
    });
    let out = std::io::stdout();
    let mut emit = |stamp: u64, rx: u64| -> Result<()> {
        let mut o = out.lock();
        writeln!(o, "{stamp} {rx}")?;
        o.flush()?;
        Ok(())
    };
    match &a.what {
        ProbeWhat::Ros2 { config } => ros2(config, &stop, bound, &mut emit),
        ProbeWhat::Zenoh { endpoint, robot } => zenoh(endpoint, robot, &stop, bound, &mut emit),
    }
}

type Emit<'a> = dyn FnMut(u64, u64) -> Result<()> + 'a;

fn ros2(
    config: &std::path::Path,
    stop: &AtomicBool,
    bound: Duration,
    emit: &mut Emit<'_>,
) -> Result<()> {
    use insuwb_ros2::msgs::Odometry;
    use insuwb_ros2::subscribe::{odometry_qos, Subscriber};
    let cfg = insuwb_group::robot::RobotConfig::load(config)?;
    let ros2 = cfg.ros2;
    let mut sub = Subscriber::<Odometry>::open_with(
        &ros2,
        "insuwb_bench_probe",
        &ros2.odom_topic,
        &odometry_qos(),
    )
    .context("opening the DDS reader of the bridge's odometry")?;
    eprintln!("ready");
    let t0 = Instant::now();
    while !stop.load(Ordering::Relaxed) && t0.elapsed() < bound {
        let mut next = sub.recv_timeout(Duration::from_millis(20));
        while let Ok(Some(m)) = next {
            let rx = monotonic_ns();
            let s = m.header.stamp;
            let stamp = u64::try_from(s.sec).unwrap_or(0) * 1_000_000_000 + u64::from(s.nanosec);
            emit(stamp, rx)?;
            next = sub.try_recv();
        }
        if let Err(e) = next {
            if !e.is_recoverable() {
                return Err(e).context("reading the bridge's odometry");
            }
        }
    }
    Ok(())
}

fn zenoh(
    endpoint: &str,
    robot: &str,
    stop: &AtomicBool,
    bound: Duration,
    emit: &mut Emit<'_>,
) -> Result<()> {
    use insuwb_zenoh::config::{LinkConfig, Mode};
    use zenoh::Wait;
    let link = LinkConfig {
        mode: Mode::Peer,
        listen: vec![endpoint.to_owned()],
        ..LinkConfig::default()
    };
    let session = insuwb_zenoh::session::open(&link)
        .context("opening the Zenoh subscriber of the bridge's poses")?;
    let key = insuwb_fleet::keys::Key::new(robot, insuwb_fleet::keys::Kind::Pose)?;
    let sub = session
        .declare_subscriber(key.to_string())
        .wait()
        .map_err(|e| anyhow::anyhow!("subscribing to {key}: {e}"))?;
    eprintln!("ready");
    let t0 = Instant::now();
    while !stop.load(Ordering::Relaxed) && t0.elapsed() < bound {
        let Ok(Some(sample)) = sub.recv_timeout(Duration::from_millis(20)) else {
            continue;
        };
        let rx = monotonic_ns();
        if let Ok(r) = insuwb_zenoh::session::decode_sample(&sample) {
            if let insuwb_zenoh::payload::Payload::Pose(p) = r.payload {
                emit(p.sample().stamp_ns, rx)?;
            }
        }
    }
    Ok(())
}
