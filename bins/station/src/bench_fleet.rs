//! `insuwb bench fleet`: the fleet's station under the load of N simulated
//! robots at 10 Hz over loopback, for each N asked (10, 100, 500 by
//! default).
//!
//! For each N: a station (`insuwb-station --listen tcp/127.0.0.1:PORT
//! --json --stamp-clock monotonic`, this executable, its own process) on a free
//! port; the load generator (`insuwb_zenoh::loadgen`: a Zenoh session per
//! robot, connected to the station, each robot's poses spread over the
//! period, a health report a second) in this process, which first waits
//! until every robot sees the station's subscriber; `--seconds` of
//! publishing, over which the station's CPU time is read from
//! `/proc/PID/task/*/schedstat` (all its threads: Zenoh's and its own);
//! then SIGTERM to the station, whose last snapshot gives what it
//! received: poses per robot against what each published (the drops), the
//! gaps in the `seq` of each robot's poses and health, and the delay of
//! every pose from its stamp (CLOCK_MONOTONIC, taken just before the
//! encode and put) to its arrival at the station's subscriber callback.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use insuwb_fleet::view::Snapshot;
use insuwb_zenoh::loadgen::{LoadFleet, LoadReport, LoadSpec};

/// Arguments of `insuwb bench fleet`.
#[derive(Debug, clap::Args)]
pub struct FleetBenchArgs {
    /// Fleet sizes to measure, comma-separated, one station each.
    #[arg(long, value_delimiter = ',', default_value = "10,100,500")]
    pub robots: Vec<usize>,
    /// Seconds each fleet publishes once every robot sees the station.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Poses per second of each robot.
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
    /// Print the report as one JSON object on standard output (the table goes to standard error).
    #[arg(long)]
    pub json: bool,
    /// Seconds between two looks at the station while it runs (its
    /// anonymous resident memory, open file descriptors, robots OK and
    /// poses received since the last look), for runs of hours; none by
    /// default.
    #[arg(long)]
    pub every: Option<f64>,
}

/// One look at the station while the fleet publishes (`--every`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct StationLook {
    /// Seconds since the publishing started.
    pub t_s: f64,
    /// The station's anonymous resident memory (`RssAnon`: heap and
    /// stacks), KiB.
    pub rss_anon_kib: u64,
    /// Its open file descriptors.
    pub fds: u64,
    /// Robots OK in its last snapshot.
    pub robots_ok: usize,
    /// Poses received per second since the previous look.
    pub poses_per_s: f64,
}

/// The station's memory and descriptors at the first look after warm-up
/// (a fifth of the run, at most 5 minutes), at the last look and the most
/// after warm-up.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct StationGrowth {
    /// `RssAnon` after warm-up, at the last look and the most, KiB.
    pub rss_anon_kib: [u64; 3],
    /// Descriptors after warm-up, at the last look and the most.
    pub fds: [u64; 3],
}

/// One fleet size's figures.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FleetRun {
    /// Robots.
    pub robots: usize,
    /// Seconds of publishing.
    pub seconds: f64,
    /// Seconds until every robot saw the station (Zenoh sessions opened and
    /// connected, publishers matched).
    pub connect_s: f64,
    /// Poses put by the generator.
    pub published: u64,
    /// Poses the station received.
    pub received: u64,
    /// Poses published that the station did not receive.
    pub dropped: u64,
    /// Gaps in the `seq` of the poses and health samples received.
    pub gaps: u64,
    /// The station's CPU time over the publishing, percent of one core.
    pub station_cpu_percent: f64,
    /// The generator's (this process) CPU time over the same window.
    pub generator_cpu_percent: f64,
    /// The station's peak resident memory, MiB.
    pub station_peak_rss_mib: f64,
    /// Stamp to the station's receive, median, ms.
    pub delay_p50_ms: Option<f64>,
    /// Same, 99th percentile, ms.
    pub delay_p99_ms: Option<f64>,
    /// Same, largest, ms.
    pub delay_max_ms: Option<f64>,
    /// The generator's puts late against their schedule, 99th percentile, us.
    pub put_late_p99_us: f64,
    /// Robots the station saw as OK in its last snapshot while the load ran.
    pub robots_ok: usize,
    /// The looks of `--every`, in order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub looks: Vec<StationLook>,
    /// What grew after warm-up (with `--every`, from two looks on).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub growth: Option<StationGrowth>,
}

/// Looks at the station `pid` every `every` until `stop` is set.
fn look_at(
    pid: u32,
    snaps: Snapshots,
    every: Duration,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> Vec<StationLook> {
    use std::sync::atomic::Ordering;
    let t0 = Instant::now();
    let mut looks = Vec::new();
    let mut prev: Option<(f64, u64)> = None;
    let mut next = every;
    while !stop.load(Ordering::Relaxed) {
        if t0.elapsed() < next {
            std::thread::sleep(Duration::from_millis(50).min(next - t0.elapsed()));
            continue;
        }
        next += every;
        let Some(r) = insuwb_bench::cpu::of_process(pid) else {
            break;
        };
        let (ok, poses) = snaps
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .1
            .as_ref()
            .map_or((0, 0), |s| {
                (s.count(insuwb_fleet::station::Status::Ok), s.delivery.poses)
            });
        let t_s = t0.elapsed().as_secs_f64();
        let poses_per_s = prev.map_or(0.0, |(t, p)| {
            poses.saturating_sub(p) as f64 / (t_s - t).max(1e-9)
        });
        prev = Some((t_s, poses));
        looks.push(StationLook {
            t_s,
            rss_anon_kib: r.rss_anon_kib,
            fds: r.fds,
            robots_ok: ok,
            poses_per_s,
        });
    }
    looks
}

/// The growth over `looks` of a run of `seconds`.
fn growth(looks: &[StationLook], seconds: f64) -> Option<StationGrowth> {
    let warm = insuwb_bench::cpu::warm_up_s(seconds);
    let after: Vec<&StationLook> = looks.iter().filter(|l| l.t_s >= warm).collect();
    let (first, last) = (after.first()?, after.last()?);
    let max = |f: fn(&StationLook) -> u64| after.iter().map(|l| f(l)).max().unwrap_or(0);
    Some(StationGrowth {
        rss_anon_kib: [
            first.rss_anon_kib,
            last.rss_anon_kib,
            max(|l| l.rss_anon_kib),
        ],
        fds: [first.fds, last.fds, max(|l| l.fds)],
    })
}

/// A free loopback port (the kernel's pick, released for the station).
fn free_port() -> Result<u16> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").context("finding a free port")?;
    Ok(l.local_addr()?.port())
}

/// The station's snapshots as its reader thread keeps them: how many came,
/// the last.
type Snapshots = Arc<Mutex<(usize, Option<Snapshot>)>>;

/// A station process and the reader of its snapshots.
struct StationProc {
    child: Child,
    snaps: Snapshots,
    reader: std::thread::JoinHandle<()>,
    log: PathBuf,
}

impl StationProc {
    fn start(endpoint: &str, log: PathBuf) -> Result<Self> {
        let exe = std::env::current_exe().context("locating the insuwb-station executable")?;
        let err = std::fs::File::create(&log)
            .with_context(|| format!("{}: cannot create", log.display()))?;
        let mut child = Command::new(exe)
            .args(["--listen", endpoint, "--json", "--period", "1"])
            .args(["--stamp-clock", "monotonic", "--name", "bench"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(err)
            .spawn()
            .context("starting the station (insuwb fleet)")?;
        let out = child
            .stdout
            .take()
            .context("the station's standard output")?;
        let snaps: Snapshots = Arc::default();
        let keep = snaps.clone();
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(out).lines() {
                let Ok(line) = line else { break };
                if let Ok(s) = serde_json::from_str::<Snapshot>(&line) {
                    let mut g = keep
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner);
                    g.0 += 1;
                    g.1 = Some(s);
                }
            }
        });
        Ok(Self {
            child,
            snaps,
            reader,
            log,
        })
    }

    fn last(&self) -> (usize, Option<Snapshot>) {
        let g = self
            .snaps
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        (g.0, g.1.clone())
    }

    /// Waits for the first snapshot (the station listens then).
    fn wait_up(&mut self, bound: Duration) -> Result<()> {
        let t0 = Instant::now();
        while self.last().0 == 0 {
            if let Some(st) = self.child.try_wait()? {
                bail!(
                    "the station ended ({st}):\n{}",
                    std::fs::read_to_string(&self.log).unwrap_or_default()
                );
            }
            if t0.elapsed() > bound {
                bail!("the station printed no snapshot within {bound:?}");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(())
    }

    /// SIGTERM, then its last snapshot.
    fn stop(mut self, bound: Duration) -> Result<Snapshot> {
        let pid = self.child.id().to_string();
        let _ = Command::new("kill").args(["-TERM", &pid]).status();
        let t0 = Instant::now();
        while self.child.try_wait()?.is_none() {
            if t0.elapsed() > bound {
                let _ = self.child.kill();
                let _ = self.child.wait();
                bail!("the station did not stop within {bound:?} of SIGTERM");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let Self { snaps, reader, .. } = self;
        let _ = reader.join();
        let last = snaps
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .1
            .clone();
        last.context("no snapshot from the station")
    }
}

/// Peak resident memory of `pid` (`VmHWM`), MiB.
fn peak_rss_mib(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.split_whitespace().next()?.parse::<f64>().ok())
        })
        .map_or(0.0, |kib| kib / 1024.0)
}

/// What one fleet's run measured before the station stops: connect time,
/// the generator's report, the station's and the generator's CPU percent,
/// the station's peak RSS, robots OK, the looks.
type Measured = (f64, LoadReport, f64, f64, f64, usize, Vec<StationLook>);

fn one_fleet(robots: usize, a: &FleetBenchArgs, dir: &std::path::Path) -> Result<FleetRun> {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let mut station = StationProc::start(&endpoint, dir.join(format!("station-{robots}.log")))?;
    let result = (|| -> Result<Measured> {
        station.wait_up(Duration::from_secs(30))?;
        let t0 = Instant::now();
        let spec = LoadSpec {
            endpoint: endpoint.clone(),
            robots,
            rate_hz: a.rate_hz,
            ..LoadSpec::default()
        };
        let mut fleet = LoadFleet::open(&spec).context("opening the simulated robots")?;
        let connect_s = t0.elapsed().as_secs_f64();
        let spid = station.child.id();
        let me = std::process::id();
        let (s0, g0, w0) = (
            insuwb_bench::cpu::cpu_time_ns(spid)?,
            insuwb_bench::cpu::cpu_time_ns(me)?,
            Instant::now(),
        );
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let looker = a.every.map(|every| {
            let (snaps, stop) = (station.snaps.clone(), stop.clone());
            std::thread::spawn(move || look_at(spid, snaps, Duration::from_secs_f64(every), stop))
        });
        let report = fleet.run(Duration::from_secs_f64(a.seconds), &|| false);
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let looks = looker
            .map(|h| h.join().unwrap_or_default())
            .unwrap_or_default();
        let wall = u64::try_from(w0.elapsed().as_nanos()).unwrap_or(u64::MAX);
        let (s1, g1) = (
            insuwb_bench::cpu::cpu_time_ns(spid)?,
            insuwb_bench::cpu::cpu_time_ns(me)?,
        );
        let ok = station
            .last()
            .1
            .map_or(0, |s| s.count(insuwb_fleet::station::Status::Ok));
        let rss = peak_rss_mib(spid);
        // What is still on its way.
        std::thread::sleep(Duration::from_millis(500));
        drop(fleet);
        Ok((
            connect_s,
            report,
            insuwb_bench::cpu::percent_of_core(s1.saturating_sub(s0), wall),
            insuwb_bench::cpu::percent_of_core(g1.saturating_sub(g0), wall),
            rss,
            ok,
            looks,
        ))
    })();
    let last = station.stop(Duration::from_secs(20));
    let (connect_s, report, station_cpu, gen_cpu, rss, robots_ok, looks) = result?;
    let last = last?;
    let received: u64 = last.robots.iter().map(|r| r.poses).sum();
    let dropped: u64 = report
        .per_robot
        .iter()
        .map(|(id, put)| {
            let got = last
                .robots
                .iter()
                .find(|r| &r.view.id == id)
                .map_or(0, |r| r.poses);
            put.saturating_sub(got)
        })
        .sum();
    Ok(FleetRun {
        robots,
        seconds: report.seconds,
        connect_s,
        published: report.poses,
        received,
        dropped,
        gaps: last.delivery.gaps,
        station_cpu_percent: station_cpu,
        generator_cpu_percent: gen_cpu,
        station_peak_rss_mib: rss,
        delay_p50_ms: last.delivery.delay_p50_ms,
        delay_p99_ms: last.delivery.delay_p99_ms,
        delay_max_ms: last.delivery.delay_max_ms,
        put_late_p99_us: report.late_p99_us,
        robots_ok,
        growth: growth(&looks, report.seconds),
        looks,
    })
}

/// Runs `insuwb bench fleet`.
pub fn fleet(a: &FleetBenchArgs) -> Result<()> {
    if a.robots.is_empty() || a.robots.contains(&0) {
        bail!("--robots: give fleet sizes of at least 1, e.g. 10,100,500");
    }
    if !(a.seconds.is_finite() && (1.0..=86_400.0).contains(&a.seconds)) {
        bail!("--seconds must be in [1, 86400], got {}", a.seconds);
    }
    if let Some(e) = a.every {
        if !(e.is_finite() && (1.0..=a.seconds).contains(&e)) {
            bail!("--every must be in [1, --seconds], got {e}");
        }
    }
    let dir = std::env::temp_dir().join(format!("insuwb-bench-fleet-{}", std::process::id()));
    insuwb_runtime::perm::create_private_dir(&dir)
        .with_context(|| format!("{}: cannot create", dir.display()))?;
    let mut runs = Vec::new();
    for &n in &a.robots {
        eprintln!(
            "insuwb bench fleet: {n} robots at {} Hz for {} s",
            a.rate_hz, a.seconds
        );
        match one_fleet(n, a, &dir) {
            Ok(r) => runs.push(r),
            Err(e) => {
                eprintln!("(the station's log is kept in {})", dir.display());
                return Err(e.context(format!("the fleet of {n} robots")));
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    let opt = |v: Option<f64>| v.map_or("-".to_owned(), |x| format!("{x:.2}"));
    let mut table = format!(
        "{:>7} {:>8} {:>10} {:>10} {:>7} {:>5} {:>12} {:>10} {:>9} {:>9} {:>9} {:>9}\n",
        "robots",
        "ok",
        "published",
        "received",
        "dropped",
        "gaps",
        "station CPU",
        "gen. CPU",
        "RSS MiB",
        "p50 ms",
        "p99 ms",
        "max ms"
    );
    for r in &runs {
        table.push_str(&format!(
            "{:>7} {:>8} {:>10} {:>10} {:>7} {:>5} {:>11.1}% {:>9.1}% {:>9.1} {:>9} {:>9} {:>9}\n",
            r.robots,
            r.robots_ok,
            r.published,
            r.received,
            r.dropped,
            r.gaps,
            r.station_cpu_percent,
            r.generator_cpu_percent,
            r.station_peak_rss_mib,
            opt(r.delay_p50_ms),
            opt(r.delay_p99_ms),
            opt(r.delay_max_ms),
        ));
    }
    if a.json {
        eprint!("{table}");
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &serde_json::json!({ "fleets": runs }))?;
        writeln!(out)?;
    } else {
        print!("{table}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn look(t_s: f64, rss_anon_kib: u64, fds: u64) -> StationLook {
        StationLook {
            t_s,
            rss_anon_kib,
            fds,
            robots_ok: 100,
            poses_per_s: 1000.0,
        }
    }

    /// Growth is read after warm-up (a fifth of the run, at most 5
    /// minutes): the first look from then on, the last, and the most.
    #[test]
    fn growth_is_read_after_warm_up() {
        let looks = [
            look(60.0, 900, 20),
            look(300.0, 1000, 30),
            look(360.0, 1200, 31),
            look(420.0, 1100, 30),
        ];
        let g = growth(&looks, 3600.0).unwrap();
        assert_eq!(g.rss_anon_kib, [1000, 1100, 1200]);
        assert_eq!(g.fds, [30, 30, 31]);
        // A short run warms up for a fifth of it.
        let g = growth(&looks, 500.0).unwrap();
        assert_eq!(g.rss_anon_kib[0], 1000);
        assert!(growth(&looks[..1], 3600.0).is_none());
    }
}
