//! `insuwb emulate imu|uwb`: a device emulator. Plays a simulated scenario
//! or a log out through a pseudo-terminal (WitMotion, MAVLink, NLink,
//! DWM1001) or a loopback TCP server (Eliko), in real time against
//! CLOCK_MONOTONIC, with optional injected faults. What is played comes from
//! `insuwb_group::recording` (IMU samples, UWB positions) or, for a ranging
//! device (DWM1001; NLink with a two-way ranging source), the scenario's or
//! log's two-way ranges; the byte streams from `insuwb_devices::play`, the
//! devices and the player from `insuwb_devices::emulator`.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use insuwb_devices::emulator::{
    DeviceSink, Faults, Outage, PlayReport, Player, PtyEmulator, TcpEmulator, TcpEmulatorConfig,
};
use insuwb_devices::play::{self, Encoding};
use insuwb_devices::{eliko, Protocol};
use insuwb_group::recording::{self, Recording};
use insuwb_group::robot::choose_start_epoch;
use insuwb_log::Record;
use insuwb_msg::{UwbKind, UwbRange};
use insuwb_runtime::monotonic_ns;

/// Longest garbage burst injected before a chunk, bytes.
pub const GARBAGE_MAX_LEN: usize = 32;

/// Which device to emulate.
#[derive(Debug, clap::Subcommand)]
pub enum EmulateCmd {
    /// An IMU on a pseudo-terminal: WitMotion 0x51+0x52 cycles or MAVLink HIGHRES_IMU.
    Imu(EmulateArgs),
    /// A UWB system: NLink Tag_Frame0 (positions, or the ranges of a two-way ranging source) or DWM1001 `lec` lines (two-way ranges) on a pseudo-terminal, or Eliko COORD lines on a loopback TCP port.
    Uwb(EmulateArgs),
}

/// Arguments of `insuwb emulate imu|uwb`.
#[derive(Debug, clap::Args)]
pub struct EmulateArgs {
    /// Protocol: witmotion or mavlink (imu, default witmotion); nlink, eliko or dwm1001 (uwb, default eliko).
    #[arg(long)]
    pub protocol: Option<String>,
    /// Scenario to simulate (built-in name or TOML file; default nlos-long, for dwm1001 twr-3.4).
    #[arg(long, conflicts_with = "log")]
    pub scenario: Option<String>,
    /// Simulation seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Play an insuwb log instead of a scenario (UWB: its two-way ranges, else the fixes of its TDOA, or its recorded fixes).
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// Serial protocols: also keep a symlink at PATH to the pseudo-terminal, re-pointed across disconnects (as udev does).
    #[arg(long, value_name = "PATH")]
    pub link: Option<PathBuf>,
    /// Eliko: TCP port on 127.0.0.1 (0: any free port; the port is printed).
    #[arg(long, default_value_t = 0)]
    pub port: u16,
    /// UWB tag id (NLink: 0 to 255).
    #[arg(long, default_value_t = 1)]
    pub tag: u32,
    /// Serial protocols: baud rate of the modelled line; a frame is written when its last byte would have arrived (0: at once).
    #[arg(long, default_value_t = play::DEFAULT_SERIAL_BAUD)]
    pub baud: u32,
    /// Play speed (1: the recorded rate).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// CLOCK_MONOTONIC time (ns) of the recording's start (default: the next start epoch at least 0.5 s ahead, `insuwb_runtime::epoch`).
    #[arg(long)]
    pub start_epoch_ns: Option<u64>,
    /// Device clock at the epoch, s (default: 10 s since boot for MAVLink and NLink, Unix time 1700000000 for Eliko; WitMotion and DWM1001 send none).
    #[arg(long)]
    pub clock_start_s: Option<f64>,
    /// Device clock drift against the host's, ppm.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub drift_ppm: f64,
    /// Bursts of random bytes (up to 32) inserted per second, on average.
    #[arg(long, default_value_t = 0.0)]
    pub garbage_per_s: f64,
    /// Runs of bytes (up to one frame) dropped per second, on average.
    #[arg(long, default_value_t = 0.0)]
    pub drop_per_s: f64,
    /// Unplug the device every S seconds (the pseudo-terminal closes; the TCP port refuses connections).
    #[arg(long, value_name = "S", requires = "disconnect_for_ms")]
    pub disconnect_every_s: Option<f64>,
    /// How long each unplug lasts, ms.
    #[arg(long, value_name = "MS", requires = "disconnect_every_s")]
    pub disconnect_for_ms: Option<u64>,
    /// Seed of the injected faults.
    #[arg(long, default_value_t = 1)]
    pub fault_seed: u64,
}

/// IMU or UWB.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// An IMU.
    Imu,
    /// A UWB system.
    Uwb,
}

/// The scenario played when none is named.
const DEFAULT_SCENARIO: &str = "nlos-long";

/// The scenario a ranging device plays when none is named.
const DEFAULT_RANGING_SCENARIO: &str = "twr-3.4";

/// Runs `insuwb emulate`.
pub fn run(cmd: &EmulateCmd) -> Result<()> {
    let (kind, a) = match cmd {
        EmulateCmd::Imu(a) => (Kind::Imu, a),
        EmulateCmd::Uwb(a) => (Kind::Uwb, a),
    };
    let protocol = protocol_of(kind, a.protocol.as_deref())?;
    if !(a.speed.is_finite() && a.speed > 0.0 && a.speed <= 1000.0) {
        bail!("--speed must be in (0, 1000], got {}", a.speed);
    }
    let scenario = a.scenario.as_deref().unwrap_or(match protocol {
        Protocol::Dwm1001 => DEFAULT_RANGING_SCENARIO,
        _ => DEFAULT_SCENARIO,
    });
    let mut enc = Encoding {
        tag: a.tag,
        speed: a.speed,
        ..Encoding::new(protocol)
    };
    if protocol != Protocol::Eliko {
        enc.baud = a.baud;
    }
    enc.clock.drift_ppm = a.drift_ppm;
    if let Some(s) = a.clock_start_s {
        if !(s.is_finite() && s >= 0.0) {
            bail!("--clock-start-s must be >= 0, got {s}");
        }
        enc.clock.start_ns = secs_to_ns(s);
    }
    if !a.drift_ppm.is_finite() || a.drift_ppm.abs() >= 1e5 {
        bail!("--drift-ppm must be within +-100000, got {}", a.drift_ppm);
    }
    // A ranging device plays two-way ranges; NLink plays them when the
    // source has them, positions otherwise.
    let ranges = match (kind, protocol) {
        (Kind::Uwb, Protocol::Dwm1001 | Protocol::Nlink) => {
            ranges_of(a.log.as_deref(), scenario, a.seed)?
        }
        _ => None,
    };
    let (name, span_ns, chunks, what) = match ranges {
        Some((name, ranges)) => {
            let end = ranges.last().map_or(0, |r| r.header.meas_time_ns);
            (name, end, play::range_chunks(&ranges, &enc)?, "UWB ranging rounds")
        }
        None if protocol == Protocol::Dwm1001 => bail!(
            "dwm1001 is a two-way ranging device, but {}: play a scenario with [sim.uwb] kind = \"twr\" (e.g. --scenario {DEFAULT_RANGING_SCENARIO}) or a log of one",
            match &a.log {
                Some(p) => format!("the log {} holds no two-way ranges", p.display()),
                None => format!("scenario {scenario:?} simulates [sim.uwb] kind = \"tdoa\""),
            }
        ),
        None => {
            let rec = match &a.log {
                Some(p) => recording::from_log(p)?,
                None => recording::from_scenario(scenario, a.seed)?,
            };
            let chunks = chunks_for(kind, &rec, &enc)?;
            let what = match kind {
                Kind::Imu => "IMU samples",
                Kind::Uwb => "UWB positions",
            };
            (rec.name.clone(), rec.end_ns(), chunks, what)
        }
    };
    if chunks.is_empty() {
        bail!("{name}: nothing to play for this device");
    }
    let faults = faults_of(a, &chunks)?;
    let epoch = a
        .start_epoch_ns
        .unwrap_or_else(|| choose_start_epoch(monotonic_ns()));
    let what = describe(what, protocol, &name, span_ns, &chunks, &enc);
    if protocol == Protocol::Eliko {
        if a.link.is_some() {
            bail!("--link is for the serial protocols (eliko is served over TCP: --port)");
        }
        let tcp = start_eliko(a.port)?;
        let port = tcp.port();
        announce(&port.to_string())?;
        eprintln!("insuwb emulate: {what} on tcp:127.0.0.1:{port}");
        serve(tcp, chunks, epoch, faults)
    } else {
        if a.port != 0 {
            bail!("--port is for eliko (serial protocols are served on a pseudo-terminal)");
        }
        let pty = open_pty(a.link.as_deref())?;
        let path = pty
            .driver_path()
            .context("the pseudo-terminal has no path")?
            .display()
            .to_string();
        if a.disconnect_every_s.is_some() && a.link.is_none() {
            tracing::warn!(
                "without --link the pseudo-terminal gets a new path after each disconnect"
            );
        }
        announce(&path)?;
        eprintln!("insuwb emulate: {what} on serial:{path}");
        serve(pty, chunks, epoch, faults)
    }
}

/// The protocol named (or the default of the device kind), checked.
pub fn protocol_of(kind: Kind, name: Option<&str>) -> Result<Protocol> {
    let protocol: Protocol = match name {
        Some(n) => n.parse()?,
        None if kind == Kind::Imu => Protocol::WitMotion,
        None => Protocol::Eliko,
    };
    let ok = match kind {
        Kind::Imu => matches!(protocol, Protocol::WitMotion | Protocol::Mavlink),
        Kind::Uwb => matches!(
            protocol,
            Protocol::Nlink | Protocol::Eliko | Protocol::Dwm1001
        ),
    };
    if !ok {
        bail!(
            "protocol {protocol} is not a {} protocol (imu: witmotion, mavlink; uwb: nlink, eliko, dwm1001)",
            match kind {
                Kind::Imu => "IMU",
                Kind::Uwb => "UWB",
            }
        );
    }
    Ok(protocol)
}

/// The device's byte chunks: IMU samples or UWB fixes.
pub fn chunks_for(kind: Kind, rec: &Recording, enc: &Encoding) -> Result<Vec<(u64, Vec<u8>)>> {
    Ok(match kind {
        Kind::Imu => play::imu_chunks(&rec.imu, enc)?,
        Kind::Uwb => play::uwb_chunks(&rec.fixes, enc)?,
    })
}

/// The two-way ranges of the log at `log`, else of `scenario` simulated
/// with `seed`, in time order, times in ns since the start, and what they
/// are; `None` when there are none (a TDOA scenario, a log without ranges).
/// A log's times are shifted back by whole seconds so that the first lies
/// in the first second, as `insuwb_group::recording` does.
fn ranges_of(
    log: Option<&Path>,
    scenario: &str,
    seed: u64,
) -> Result<Option<(String, Vec<UwbRange>)>> {
    let Some(path) = log else {
        let sc = insuwb_fusion::scenario::ScenarioFile::load(scenario)?;
        if sc.sim.uwb.kind != UwbKind::Twr {
            return Ok(None);
        }
        let ranges = sc.simulate(seed)?.range;
        return Ok(Some((format!("{} (seed {seed})", sc.sim.name), ranges)));
    };
    let (records, tail, _) =
        insuwb_log::read_all(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    if let Some(t) = tail {
        tracing::warn!("{}: {t}", path.display());
    }
    let mut ranges: Vec<UwbRange> = records
        .into_iter()
        .filter_map(|r| match r {
            Record::Range(m) => Some(m),
            _ => None,
        })
        .collect();
    // By time, each round's ranges kept in their order.
    ranges.sort_by_key(|r| r.header.meas_time_ns);
    let Some(first) = ranges.first().map(|r| r.header.meas_time_ns) else {
        return Ok(None);
    };
    let shift = first / 1_000_000_000 * 1_000_000_000;
    for r in &mut ranges {
        r.header.meas_time_ns -= shift;
    }
    Ok(Some((path.display().to_string(), ranges)))
}

/// A DWM1001 tag on a pseudo-terminal with a stable symlink at `link`,
/// printing the ranging rounds of `ranges` (times in ns since `epoch_ns`)
/// as `lec` lines on a modelled 115200-baud line from `epoch_ns`
/// (CLOCK_MONOTONIC) on, without faults; also the number of lines.
///
/// # Errors
/// The ranges cannot be encoded (`play::range_chunks`), the
/// pseudo-terminal or the player cannot be started.
pub(crate) fn start_dwm1001_player(
    link: &Path,
    ranges: &[UwbRange],
    epoch_ns: u64,
) -> Result<(Player<PtyEmulator>, usize)> {
    let chunks = play::range_chunks(ranges, &Encoding::new(Protocol::Dwm1001))?;
    let n = chunks.len();
    let pty = open_pty(Some(link))?;
    let player = Player::start(pty, chunks, epoch_ns, monotonic_ns, Faults::none())?;
    Ok((player, n))
}

/// A pseudo-terminal, with a stable symlink at `link` if given.
pub fn open_pty(link: Option<&Path>) -> Result<PtyEmulator> {
    Ok(match link {
        Some(l) => {
            let name = l
                .file_name()
                .and_then(|n| n.to_str())
                .with_context(|| format!("--link {}: needs a file name", l.display()))?;
            let dir = match l.parent() {
                Some(d) if !d.as_os_str().is_empty() => d,
                _ => Path::new("."),
            };
            PtyEmulator::open_with_link(dir, name)?
        }
        None => PtyEmulator::open()?,
    })
}

/// An Eliko server on 127.0.0.1:`port` that streams after the client's handshake.
pub fn start_eliko(port: u16) -> Result<TcpEmulator> {
    Ok(TcpEmulator::start(TcpEmulatorConfig {
        port,
        expect_lines: eliko::HANDSHAKE.iter().map(|l| (*l).to_owned()).collect(),
        ..TcpEmulatorConfig::default()
    })?)
}

fn secs_to_ns(s: f64) -> u64 {
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let ns = (s * 1e9).round().min(u64::MAX as f64) as u64;
    ns
}

/// Chunks per second over the play.
fn chunk_rate(chunks: &[(u64, Vec<u8>)]) -> f64 {
    let first = chunks.first().map_or(0, |c| c.0);
    let last = chunks.last().map_or(0, |c| c.0);
    let span = last.saturating_sub(first) as f64 * 1e-9;
    if span > 0.0 {
        chunks.len().saturating_sub(1) as f64 / span
    } else {
        1.0
    }
}

/// The fault settings: rates per second become probabilities per chunk.
fn faults_of(a: &EmulateArgs, chunks: &[(u64, Vec<u8>)]) -> Result<Faults> {
    let per_chunk = |name: &str, per_s: f64| -> Result<f64> {
        if !(per_s.is_finite() && per_s >= 0.0) {
            bail!("--{name} must be >= 0, got {per_s}");
        }
        let p = per_s / chunk_rate(chunks);
        if p > 1.0 {
            bail!(
                "--{name} {per_s}: at most one per chunk ({:.1} chunks/s)",
                chunk_rate(chunks)
            );
        }
        Ok(p)
    };
    let max_frame = chunks.iter().map(|c| c.1.len()).max().unwrap_or(1);
    let outage = match (a.disconnect_every_s, a.disconnect_for_ms) {
        (Some(every), Some(ms)) => {
            if !(every.is_finite() && every > 0.0) {
                bail!("--disconnect-every-s must be > 0, got {every}");
            }
            let o = Outage {
                every: Duration::from_secs_f64(every),
                length: Duration::from_millis(ms),
            };
            if o.length.is_zero() || o.length >= o.every {
                bail!("--disconnect-for-ms must be > 0 and shorter than --disconnect-every-s");
            }
            Some(o)
        }
        _ => None,
    };
    Ok(Faults {
        seed: a.fault_seed,
        garbage_prob: per_chunk("garbage-per-s", a.garbage_per_s)?,
        garbage_max_len: GARBAGE_MAX_LEN,
        drop_prob: per_chunk("drop-per-s", a.drop_per_s)?,
        drop_max_len: max_frame,
        outage,
    })
}

/// What is served: `what` (samples, positions, rounds) of `name`, lasting
/// `span_ns` of recording time.
fn describe(
    what: &str,
    protocol: Protocol,
    name: &str,
    span_ns: u64,
    chunks: &[(u64, Vec<u8>)],
    enc: &Encoding,
) -> String {
    let clock = match protocol {
        Protocol::WitMotion | Protocol::Dwm1001 => String::new(),
        _ => format!(
            ", device clock {:.3} s at the epoch, drift {} ppm",
            enc.clock.start_ns as f64 * 1e-9,
            enc.clock.drift_ppm
        ),
    };
    let wire = if enc.baud > 0 {
        format!(", {} baud modelled", enc.baud)
    } else {
        String::new()
    };
    format!(
        "{protocol}: {} {what} ({:.1} Hz, {:.1} s) of {} at speed {}{clock}{wire}",
        chunks.len(),
        chunk_rate(chunks),
        span_ns as f64 * 1e-9 / enc.speed,
        name,
        enc.speed,
    )
}

/// Prints the device's address as the one line of standard output.
fn announce(line: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")?;
    out.flush()?;
    Ok(())
}

/// Plays `chunks` to `sink` from `epoch` until the end or SIGINT/SIGTERM.
fn serve<S: DeviceSink>(
    sink: S,
    chunks: Vec<(u64, Vec<u8>)>,
    epoch: u64,
    faults: Faults,
) -> Result<()> {
    // From here SIGINT/SIGTERM are reported below instead of killing the
    // process (a flag no other signal overwrites).
    insuwb_runtime::signal::install()?;
    let now = monotonic_ns();
    if epoch > now {
        eprintln!(
            "insuwb emulate: starting in {:.3} s (epoch {epoch} ns)",
            (epoch - now) as f64 * 1e-9
        );
    }
    let player = Player::start(sink, chunks, epoch, monotonic_ns, faults)?;
    let mut interrupted = false;
    while !player.is_finished() {
        if insuwb_runtime::signal::termination_requested() {
            interrupted = true;
            player.stop();
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let (_sink, report) = player.join()?;
    eprintln!(
        "insuwb emulate: {} {}",
        if interrupted { "interrupted:" } else { "done:" },
        summary(&report)
    );
    Ok(())
}

/// One line of a play's figures.
pub fn summary(r: &PlayReport) -> String {
    format!(
        "{} chunks played ({} bytes, {} delivered), {} lost in {} outages, {} garbage bursts ({} bytes), {} drops ({} bytes), worst lateness {:.3} ms{}",
        r.chunks_played,
        r.bytes_offered,
        r.bytes_delivered,
        r.chunks_lost_in_outage,
        r.outages,
        r.garbage_bursts,
        r.garbage_bytes,
        r.drop_events,
        r.bytes_dropped,
        r.max_late_ns as f64 * 1e-6,
        r.replug_errors
            .as_ref()
            .map_or(String::new(), |e| format!(", last replug error: {e}"))
    )
}
