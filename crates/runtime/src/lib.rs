//! Stage runtime over iceoryx2 0.10: every stage binary is a thin `main` over
//! this crate.
//!
//! It owns the iceoryx2 node of a stage ([`Stage`]: service prefix, root
//! folder, generation, dead-node cleanup, signals), the typed ports with the
//! QoS of [`insuwb_msg::qos`] ([`Pub`] stamps headers, [`Sub`] checks layout
//! versions and tracks sequence gaps and restarts), the wait loop ([`Waiter`]:
//! an epoll set over the subscribers' listeners, a deadline timerfd and the
//! termination eventfd, or busy polling), the heartbeat ([`HealthReporter`]), the
//! process-comparable clock ([`monotonic_ns`]), logging ([`init_tracing`]),
//! the iceoryx2 service type whose loans allocate nothing ([`service::Ipc`]),
//! shared memory paged in ahead of use ([`prefault`]), the due time of the
//! next periodic sample ([`anticipate`]),
//! owner-only files ([`perm`]) and inspection/cleanup of a deployment's
//! resources ([`cleanup`]).
//!
//! # The loop of a stage
//!
//! ```
//! use core::time::Duration;
//! use insuwb_msg::{topics, Header, ImuSample};
//! use insuwb_runtime::{cleanup, RuntimeConfig, Stage, Wake};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let prefix = format!("insuwb_doc{}_", std::process::id());
//! let root = std::env::temp_dir().join(&prefix);
//! let cfg = RuntimeConfig {
//!     prefix: prefix.clone(),
//!     root_path: Some(root.clone()),
//!     stage_name: "doc".into(),
//!     ..Default::default()
//! };
//! {
//!     let stage = Stage::new(cfg)?;
//!     let mut imu_pub = stage.publisher::<ImuSample>(topics::IMU)?;
//!     let imu_sub = stage.subscriber::<ImuSample>(topics::IMU)?;
//!     let mut health = stage.health_reporter()?;
//!
//!     let waiter = stage.waiter()?;
//!     let imu = waiter.attach(&imu_sub)?;
//!     let heartbeat = waiter.attach_interval(health.period())?;
//!
//!     imu_pub.publish(ImuSample { header: Header::new(0, 1_000), ..Default::default() })?;
//!     let mut got = Vec::new();
//!     while got.is_empty() {
//!         match waiter.wait_timeout(Duration::from_secs(5))? {
//!             Wake::Shutdown => break, // SIGINT/SIGTERM: leave and exit 0
//!             Wake::Timeout => panic!("no sample within 5 s"),
//!             Wake::Fired(fired) => {
//!                 if fired.contains(&imu) {
//!                     // Read until empty: this also consumes the wake-up.
//!                     imu_sub.drain(|s| got.push(s))?;
//!                 }
//!                 if fired.contains(&heartbeat) {
//!                     let mut c = insuwb_runtime::HealthCounters::default();
//!                     c.add_sub(&imu_sub.stats());
//!                     health.report(&c, insuwb_msg::HealthState::Ok)?;
//!                 }
//!             }
//!         }
//!     }
//!     assert_eq!(got[0].header.seq, 0);
//!     assert_eq!(got[0].header.meas_time_ns, 1_000);
//!     assert!(got[0].header.pub_time_ns > 0);
//! } // ports, waiter and node dropped here
//! cleanup::remove_prefix_files(&prefix, Some(&root))?;
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod anticipate;
pub mod cleanup;
mod config;
pub mod drain;
pub mod epoch;
mod health;
pub mod perm;
mod port;
pub mod prefault;
pub mod realtime;
pub mod service;
pub mod signal;
mod stage;
mod waiter;

pub use config::{
    RuntimeConfig, RuntimeConfigError, GENERATION_ENV, MAX_PREFIX_LEN, MAX_ROOT_PATH_LEN,
    MAX_STAGE_NAME_LEN,
};
pub use health::{HealthCounters, HealthReporter};
pub use port::{PortError, Pub, PublishError, ReceiveError, Sub, SubStats, MAX_TRACKED_SOURCES};
pub use stage::{iceoryx_config, Shutdown, Stage, StageError};
pub use waiter::{Attachment, Fired, WaitError, Waiter, Wake, MAX_ATTACHMENTS};

/// CLOCK_MONOTONIC in nanoseconds: the same clock in every process of the
/// machine, so a publish time stamped by one process can be subtracted from a
/// receive time taken in another.
#[must_use]
#[allow(unsafe_code)]
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, exclusively borrowed timespec for the duration
    // of the call; CLOCK_MONOTONIC is always supported on Linux, and on the
    // impossible failure `ts` stays zeroed (no uninitialised read).
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    if rc != 0 {
        return 0;
    }
    let secs = u64::try_from(ts.tv_sec).unwrap_or(0);
    let nanos = u64::try_from(ts.tv_nsec).unwrap_or(0);
    secs.saturating_mul(1_000_000_000).saturating_add(nanos)
}

/// Why [`init_tracing`] failed.
#[derive(Debug, thiserror::Error)]
pub enum TracingInitError {
    /// `RUST_LOG` is not a valid filter.
    #[error("RUST_LOG is not a valid tracing filter ({value:?}): {reason}")]
    Filter {
        /// The variable's value.
        value: String,
        /// The parser's message.
        reason: String,
    },
    /// A global subscriber was installed already.
    #[error("a global tracing subscriber is installed already")]
    AlreadySet,
}

/// The log filter of every insuwb process when `RUST_LOG` is unset:
/// `info`, but RustDDS (the ROS 2 bridge, the IMU source `ros2:`, the
/// latency bench's DDS reader) reports every socket and discovery event at
/// `info` and warns of each datagram above 1500 bytes (the bridge's
/// diagnostics array; the IP layer fragments it), ros2-client warns when
/// `ROS_DISTRO` is unset (no ROS installation is the point), and Zenoh (the
/// Zenoh bridge, the fleet's station, the simulated robots of `bench
/// fleet`) reports its listeners and links at `info` and warns at each
/// peer session that gossip is off (on purpose: nothing is scouted).
pub const DEFAULT_LOG_FILTER: &str = "info,rustdds=warn,rustdds::network::udp_sender=error,\
     ros2_client=warn,ros2_client::distributions=error,zenoh=warn,\
     zenoh::net::routing::hat::peer=error";

/// Logs to stderr with the `RUST_LOG` filter (default
/// [`DEFAULT_LOG_FILTER`]), each line prefixed by `stage_name`. Also sets
/// iceoryx2's own log level to `warn` (unless `IOX2_LOG_LEVEL` says
/// otherwise).
pub fn init_tracing(stage_name: &str) -> Result<(), TracingInitError> {
    use tracing_subscriber::EnvFilter;
    let filter = match std::env::var("RUST_LOG") {
        Ok(v) if !v.trim().is_empty() => {
            EnvFilter::try_new(&v).map_err(|e| TracingInitError::Filter {
                value: v.clone(),
                reason: e.to_string(),
            })?
        }
        _ => EnvFilter::new(DEFAULT_LOG_FILTER),
    };
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Warn);
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .event_format(StagePrefixed {
            stage: stage_name.to_owned(),
            inner: tracing_subscriber::fmt::format::Format::default(),
        })
        .try_init()
        .map_err(|_| TracingInitError::AlreadySet)
}

/// The `main` of a stage process once its arguments are parsed: logging
/// with [`init_tracing`] for `stage_name`, then `run`. The exit policy of
/// every stage: a run that ends in [`StageError::ShutdownRequested`] (SIGINT
/// or SIGTERM while it was starting; anywhere in the error's causes) is a
/// clean stop and exits 0. Any other error is logged as the process's last
/// line, with its causes where its alternate form (`{:#}`, as anyhow's)
/// shows them, and gives the exit status 1. Where logging cannot start (an
/// invalid `RUST_LOG`), that is said on standard error and the stage runs
/// on, its error then written there too.
pub fn stage_main<E>(
    stage_name: &str,
    run: impl FnOnce() -> Result<(), E>,
) -> std::process::ExitCode
where
    E: std::fmt::Display + AsRef<dyn std::error::Error + Send + Sync + 'static>,
{
    let logging = init_tracing(stage_name);
    if let Err(e) = &logging {
        eprintln!("[{stage_name}] logging: {e}");
    }
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if shutdown_requested(e.as_ref()) => {
            tracing::info!("stopped while starting: {e:#}");
            std::process::ExitCode::SUCCESS
        }
        Err(e) => {
            if logging.is_ok() {
                tracing::error!("{e:#}");
            } else {
                eprintln!("[{stage_name}] error: {e:#}");
            }
            std::process::ExitCode::FAILURE
        }
    }
}

/// Whether `e` or one of its causes is [`StageError::ShutdownRequested`].
fn shutdown_requested(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut next = Some(e);
    while let Some(c) = next {
        if matches!(
            c.downcast_ref::<StageError>(),
            Some(StageError::ShutdownRequested(_))
        ) {
            return true;
        }
        next = c.source();
    }
    false
}

/// The `main` of a command (`insuwb`, `insuwb-station`) once its
/// arguments are parsed: logging on standard error with the filter of
/// `RUST_LOG` (else [`DEFAULT_LOG_FILTER`]), then `run`; an error is
/// written as `error: ` and its causes, and gives the exit status 1.
pub fn command_main<E: std::fmt::Display>(
    run: impl FnOnce() -> Result<(), E>,
) -> std::process::ExitCode {
    command_main_with(None, run)
}

/// [`command_main`] with `extra`, a layer beside the log's (with its own
/// filter, e.g. one that counts what a library reports as events). Without
/// one, the log's filter is the subscriber's global filter, as before:
/// events no one prints are not even built.
pub fn command_main_with<E: std::fmt::Display>(
    extra: Option<Box<dyn tracing_subscriber::Layer<tracing_subscriber::Registry> + Send + Sync>>,
    run: impl FnOnce() -> Result<(), E>,
) -> std::process::ExitCode {
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    use tracing_subscriber::Layer as _;
    let filter = || {
        tracing_subscriber::EnvFilter::try_from_default_env()
            .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(DEFAULT_LOG_FILTER))
    };
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    // A subscriber set before (a test's) stays.
    let _already_set = match extra {
        None => tracing_subscriber::fmt()
            .with_writer(std::io::stderr)
            .with_ansi(ansi)
            .with_env_filter(filter())
            .try_init()
            .is_err(),
        Some(extra) => {
            let log = tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(ansi)
                .with_filter(filter());
            tracing_subscriber::registry()
                .with(extra)
                .with(log)
                .try_init()
                .is_err()
        }
    };
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// Event formatter writing `[stage] ` before the default format.
struct StagePrefixed<F> {
    stage: String,
    inner: F,
}

impl<S, N, F> tracing_subscriber::fmt::FormatEvent<S, N> for StagePrefixed<F>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
    N: for<'a> tracing_subscriber::fmt::FormatFields<'a> + 'static,
    F: tracing_subscriber::fmt::FormatEvent<S, N>,
{
    fn format_event(
        &self,
        ctx: &tracing_subscriber::fmt::FmtContext<'_, S, N>,
        mut writer: tracing_subscriber::fmt::format::Writer<'_>,
        event: &tracing::Event<'_>,
    ) -> core::fmt::Result {
        write!(writer, "[{}] ", self.stage)?;
        self.inner.format_event(ctx, writer, event)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_is_nondecreasing_and_matches_std_rate() {
        let a = monotonic_ns();
        let t = std::time::Instant::now();
        std::thread::sleep(core::time::Duration::from_millis(20));
        let b = monotonic_ns();
        let el = t.elapsed().as_nanos() as u64;
        assert!(a > 0 && b > a);
        // Instant is CLOCK_MONOTONIC on Linux too: the spans agree (a unit error would be 1000x off).
        assert!((b - a).abs_diff(el) < 50_000_000, "{} vs {el}", b - a);
    }

    #[derive(Clone, Default)]
    struct Buf(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

    impl std::io::Write for Buf {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn log_lines_carry_the_stage_name() {
        let buf = Buf::default();
        let w = buf.clone();
        let sub = tracing_subscriber::fmt()
            .with_writer(move || w.clone())
            .with_ansi(false)
            .event_format(StagePrefixed {
                stage: "fusion".into(),
                inner: tracing_subscriber::fmt::format::Format::default().with_ansi(false),
            })
            .finish();
        tracing::subscriber::with_default(sub, || tracing::info!(x = 3, "hello"));
        let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
        assert!(text.starts_with("[fusion] "), "{text}");
        assert!(text.contains("hello") && text.contains("x=3"), "{text}");
    }
}
