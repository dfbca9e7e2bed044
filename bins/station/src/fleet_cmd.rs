//! `insuwb fleet` and `insuwb fleet record DIR`: the fleet's station over
//! Zenoh (`insuwb_zenoh::station`): every robot's pose, rate, age of its
//! last pose, status (ok / degraded / stale / lost) and restarts, as a
//! terminal table redrawn twice a second, or with `--json` one JSON
//! snapshot per period (`insuwb_fleet::view`); lost and back events on
//! standard error; `record` also writes each robot's stream into its own
//! insuwb log (`insuwb_fleet::record`).

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use insuwb_fleet::record::{FleetRecorder, RecordSettings};
use insuwb_fleet::view::{render_table, Snapshot};
use insuwb_report::clock::StampClock;
use insuwb_zenoh::config::Mode;
use insuwb_zenoh::identity::Refusals;
use insuwb_zenoh::station::{FleetStation, RunOptions, StationSettings};

/// Arguments of `insuwb fleet`.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct FleetArgs {
    /// `record DIR`: record too.
    #[command(subcommand)]
    pub cmd: Option<FleetCmd>,
    /// Where the station listens or connects, and what it prints.
    #[command(flatten)]
    pub station: StationArgs,
}

/// `insuwb fleet` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum FleetCmd {
    /// The station under the load of N simulated robots at 10 Hz over loopback (`insuwb bench fleet`).
    Bench(crate::bench_fleet::FleetBenchArgs),
    /// Listen to a bridge's poses from outside the robot and print `stamp_ns rx_ns` per pose until standard input closes (the pose probe of `insuwb bench latency --with ros2|zenoh`).
    Probe(crate::probe::ProbeArgs),
    /// Run the station and write each robot's stream (fused states from its poses, a heartbeat per stage from its health) into its own insuwb log, DIR/<robot>/seg-*.iulog, which `insuwb log info`, `log export` and `eval` read.
    Record(RecordArgs),
}

/// Arguments of `insuwb fleet record`.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// The recording's folder (created if needed; a new segment per robot at each start).
    pub dir: PathBuf,
    /// Where the station listens or connects, and what it prints.
    #[command(flatten)]
    pub station: StationArgs,
}

/// Where the station listens or connects, and what it prints.
#[derive(Debug, clap::Args)]
pub struct StationArgs {
    /// Listen on ENDPOINT for the robots' bridges (tcp/IP:PORT, or tls/IP:PORT with a --config file's [station.tls]; repeatable): the station serves as the fleet's Zenoh router. Replaces the config file's `listen`.
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Connect to ENDPOINT, a Zenoh router the robots connect to (repeatable). Replaces the config file's `connect`.
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// The session's role: router (the default when listening), peer (the default otherwise) or client.
    #[arg(long, value_parser = ["peer", "client", "router"])]
    pub mode: Option<String>,
    /// Refuse a plain tcp/ endpoint off the loopback instead of warning
    /// about it (also `[station] require_tls` in the --config file).
    #[arg(long)]
    pub require_tls: bool,
    /// A station config file: a [station] table with name, mode, listen, connect, require_tls, stamp_clock, lost_after_s, stale_after_s, rate_window_s, max_robots (the most robots tracked, default 1000; samples of further robots are counted as excess), and [station.tls] (root_ca_certificate, certificate, private_key, mutual, verify_name; paths relative to the file). The options here override its keys.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Print one JSON snapshot per period on standard output, one object a line: t_s, now_ns, robots (id, status, rate_hz, age_s, restarts, lost_count, pose, poses, health, gaps, runs, delay_ms), events (new, lost, back), delivery.
    #[arg(long)]
    pub json: bool,
    /// Seconds between two views or snapshots (default: 0.5 on a terminal, else 1).
    #[arg(long, value_name = "S")]
    pub period: Option<f64>,
    /// Stop after S seconds (default: run until SIGINT or SIGTERM).
    #[arg(long, value_name = "S")]
    pub duration: Option<f64>,
    /// The clock of the robots' stamps, for the delays: realtime (the bridges' default) or monotonic (robots on this machine with stamp_clock = "monotonic").
    #[arg(long, value_parser = ["realtime", "monotonic"])]
    pub stamp_clock: Option<String>,
    /// The station's name in its recordings' metadata (default: the host name).
    #[arg(long)]
    pub name: Option<String>,
}

/// A station config file: `[station]`.
#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
struct StationFile {
    station: StationSettings,
}

/// Runs `insuwb fleet`; a station counts its access control's refusals
/// from `refusals` (fed by the process's `tracing` layer).
pub fn run(a: &FleetArgs, refusals: Arc<Refusals>) -> Result<()> {
    match &a.cmd {
        None => station(&a.station, None, refusals),
        Some(FleetCmd::Record(r)) => station(&r.station, Some(&r.dir), refusals),
        Some(FleetCmd::Bench(b)) => crate::bench_fleet::fleet(b),
        Some(FleetCmd::Probe(p)) => crate::probe::run(p),
    }
}

fn seconds(what: &str, v: Option<f64>) -> Result<Option<Duration>> {
    match v {
        None => Ok(None),
        Some(s) if s.is_finite() && s > 0.0 && s <= 1e9 => Ok(Some(Duration::from_secs_f64(s))),
        Some(s) => bail!("{what}: must be a number of seconds > 0, got {s}"),
    }
}

/// The settings: the config file's `[station]` (errors naming the file and
/// the key), then the command line's options over it.
fn settings(a: &StationArgs) -> Result<StationSettings> {
    let mut s = match &a.config {
        Some(path) => {
            let mut f: StationFile = insuwb_config::load_file(path)?;
            f.station
                .resolve_paths(path.parent().unwrap_or_else(|| Path::new(".")));
            f.station
        }
        None => StationSettings::default(),
    };
    if !a.listen.is_empty() {
        s.listen.clone_from(&a.listen);
    }
    if !a.connect.is_empty() {
        s.connect.clone_from(&a.connect);
    }
    if let Some(m) = &a.mode {
        s.mode = Some(match m.as_str() {
            "peer" => Mode::Peer,
            "client" => Mode::Client,
            _ => Mode::Router,
        });
    }
    if let Some(c) = &a.stamp_clock {
        s.stamp_clock = if c == "monotonic" {
            StampClock::Monotonic
        } else {
            StampClock::Realtime
        };
    }
    if let Some(n) = &a.name {
        s.name.clone_from(n);
    }
    s.require_tls |= a.require_tls;
    if let Err(e) = s.validate() {
        // The option that set the key, else the file, else the key alone.
        let option = match e.key.as_str() {
            "listen" if !a.listen.is_empty() => Some("--listen"),
            "connect" if !a.connect.is_empty() => Some("--connect"),
            "name" if a.name.is_some() => Some("--name"),
            _ => None,
        };
        match (option, &a.config) {
            (Some(o), _) => bail!("{o}: {}", e.reason),
            (None, Some(path)) => bail!("{}: {e}", path.display()),
            (None, None) if e.key.starts_with("tls.") => {
                bail!("{e} (TLS settings come from a --config file's [station.tls])")
            }
            (None, None) if e.key == "listen" => {
                bail!("give --listen ENDPOINT (e.g. tcp/0.0.0.0:7447) or --connect ENDPOINT, or a --config file")
            }
            (None, None) => bail!("{e}"),
        }
    }
    Ok(s)
}

/// Where the snapshots go.
enum Output {
    /// One JSON object a line.
    Json,
    /// The table, redrawn in place.
    Terminal,
    /// The table, one after the other.
    Plain,
}

impl Output {
    fn write(&self, s: &Snapshot) -> std::io::Result<()> {
        let mut out = std::io::stdout().lock();
        match self {
            Self::Json => {
                serde_json::to_writer(&mut out, s)?;
                writeln!(out)?;
            }
            // Home, clear the screen, draw.
            Self::Terminal => write!(out, "\x1b[H\x1b[2J{}", render_table(s))?,
            Self::Plain => writeln!(out, "{}", render_table(s))?,
        }
        out.flush()
    }
}

fn station(a: &StationArgs, record: Option<&PathBuf>, refusals: Arc<Refusals>) -> Result<()> {
    let settings = settings(a)?;
    let duration = seconds("--duration", a.duration)?;
    let tty = std::io::stdout().is_terminal();
    let output = match (a.json, tty) {
        (true, _) => Output::Json,
        (false, true) => Output::Terminal,
        (false, false) => Output::Plain,
    };
    let default_period = if tty && !a.json { 0.5 } else { 1.0 };
    let period = seconds("--period", a.period)?.unwrap_or(Duration::from_secs_f64(default_period));
    insuwb_runtime::signal::install().context("installing the SIGINT/SIGTERM handler")?;
    let recorder = match record {
        Some(dir) => {
            let mut rs = RecordSettings::new(&settings.station_name());
            rs.meta.push((
                "stamp_clock".to_owned(),
                match settings.stamp_clock {
                    StampClock::Realtime => "realtime",
                    StampClock::Monotonic => "monotonic",
                }
                .to_owned(),
            ));
            Some(
                FleetRecorder::open(dir, rs)
                    .with_context(|| format!("{}: cannot record there", dir.display()))?,
            )
        }
        None => None,
    };
    let mut st = FleetStation::open(&settings, recorder)
        .context("opening the station")?
        .with_refusals(refusals);
    let opts = RunOptions { period, duration };
    st.run(&opts, &mut |s| output.write(s))
        .context("the station")?;
    for r in st.finish().context("closing the recording")? {
        eprintln!(
            "insuwb fleet: recorded {} records of robot {} in {}",
            r.records,
            r.robot,
            r.dir.display()
        );
    }
    Ok(())
}
