//! `insuwb demo`: the whole group on a simulated robot in real time,
//! optionally through emulated devices, with the optional bridges.

use std::io::Write;
use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Result};
use insuwb_devices::emulator::{DeviceSink, Faults, PlayReport, Player, PtyEmulator, TcpEmulator};
use insuwb_devices::Protocol;
use insuwb_group::robot::{choose_start_epoch, RobotConfig};
use insuwb_msg::{GroundTruth, StageRole, UwbKind};
use insuwb_runtime::monotonic_ns;

use crate::group_run::{run_group_with, GroupExtras, GroupReport, RunOptions};

/// Arguments of `insuwb demo`.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Seconds to run (the scenario lasts 60 s).
    #[arg(long, default_value_t = 20.0)]
    pub duration: f64,
    /// Filter (kf, shaf, stf, iakf, iakf_tdoa).
    #[arg(long, default_value_t = insuwb_msg::FilterKind::Iakf)]
    pub filter: insuwb_msg::FilterKind,
    /// Print one JSON object on standard output.
    #[arg(long)]
    pub json: bool,
    /// What the simulated UWB system measures: tdoa (differences, scenario nlos-long) or twr (two-way ranges, scenario nlos-long-twr: the same run with one range per anchor).
    #[arg(long, default_value_t = UwbKind::Tdoa)]
    pub uwb: UwbKind,
    /// Feed the drivers through emulated devices: the IMU driver reads WitMotion frames from a pseudo-terminal, the UWB driver Eliko `$PEKIO` lines from a loopback TCP port (with --uwb twr: DWM1001 `lec` range lines from a second pseudo-terminal), all played from the same scenario and seed.
    #[arg(long)]
    pub via_devices: bool,
    /// Run the Foxglove live view too (stage `foxglove`) and print its address: open it in the Foxglove app (Open connection, Foxglove WebSocket).
    #[arg(long)]
    pub foxglove: bool,
    /// The live view's address, IP:PORT (implies --foxglove).
    #[arg(long, value_name = "IP:PORT")]
    pub foxglove_bind: Option<String>,
    /// Run the Zenoh bridge too (stage `zenoh`) as robot `demo` (or --robot ID), connected to ENDPOINT (e.g. tcp/127.0.0.1:7447, where a fleet station or any Zenoh peer or router listens): it publishes insuwb/demo/pose and insuwb/demo/health (docs/ZENOH.md).
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh: Option<String>,
    /// The robot id the Zenoh bridge publishes as (with --zenoh): two demos with different ids join one station as two robots.
    #[arg(long, value_name = "ID", default_value = "demo", requires = "zenoh")]
    pub robot: String,
}

/// The emulated devices of `insuwb demo --via-devices`, playing.
struct DemoDevices {
    imu: Player<PtyEmulator>,
    uwb: UwbPlayer,
}

/// The emulated UWB system: an Eliko server (positions) or a DWM1001 tag
/// on a pseudo-terminal (ranges).
enum UwbPlayer {
    Eliko(Player<TcpEmulator>),
    Dwm1001(Player<PtyEmulator>),
}

impl DemoDevices {
    /// Stops both players and prints what they played.
    fn finish(self) {
        let uwb = match self.uwb {
            UwbPlayer::Eliko(p) => ("UWB (eliko, tcp)", p.stop_and_join()),
            UwbPlayer::Dwm1001(p) => ("UWB (dwm1001, pty)", p.stop_and_join()),
        };
        for (name, report) in [("IMU (witmotion, pty)", self.imu.stop_and_join()), uwb] {
            match report {
                Ok(r) => eprintln!("insuwb demo: {name}: {}", crate::emulate_cmd::summary(&r)),
                Err(e) => eprintln!("insuwb demo: {name}: {e}"),
            }
        }
    }
}

/// Stops a player and gives back its report (the device is closed).
trait StopAndJoin {
    fn stop_and_join(self) -> Result<PlayReport>;
}

impl<S: DeviceSink> StopAndJoin for Player<S> {
    fn stop_and_join(self) -> Result<PlayReport> {
        self.stop();
        Ok(self.join()?.1)
    }
}

/// The `[sources]`, `[devices.*]` and `[uwb]` of the device demo, and its
/// devices started: a WitMotion IMU on a pseudo-terminal (symlink
/// `run_dir/imu`) and an Eliko server on a loopback port (`kind` tdoa) or a
/// DWM1001 tag printing `lec` lines on a second pseudo-terminal (symlink
/// `run_dir/uwb`, `kind` twr), both playing the demo scenario from `epoch`.
/// Returns the config text, the devices, and the scenario's truth at
/// CLOCK_MONOTONIC times.
fn start_demo_devices(
    run_dir: &Path,
    epoch: u64,
    kind: UwbKind,
) -> Result<(String, DemoDevices, Vec<GroundTruth>)> {
    use insuwb_devices::play::{self, Encoding};
    use insuwb_group::recording;
    let scenario = demo_scenario(kind);
    let rec = recording::from_scenario(scenario, DEMO_SEED)?;
    let imu_enc = Encoding::new(Protocol::WitMotion);
    let imu_chunks = play::imu_chunks(&rec.imu, &imu_enc)?;
    let link = run_dir.join("imu");
    let pty = crate::emulate_cmd::open_pty(Some(&link))?;
    let (uwb_text, uwb_note, uwb) = match kind {
        UwbKind::Tdoa => {
            let uwb_enc = Encoding {
                tag: DEMO_TAG,
                ..Encoding::new(Protocol::Eliko)
            };
            let chunks = play::uwb_chunks(&rec.fixes, &uwb_enc)?;
            let tcp = crate::emulate_cmd::start_eliko(0)?;
            let port = tcp.port();
            let n = chunks.len();
            (
                format!(
                    "[devices.uwb]\nsource = \"tcp:127.0.0.1:{port}\"\nprotocol = \"eliko\"\ntag_id = {DEMO_TAG}\n"
                ),
                format!("Eliko server on tcp:127.0.0.1:{port} ({n} COORD lines)"),
                UwbPlayer::Eliko(Player::start(tcp, chunks, epoch, monotonic_ns, Faults::none())?),
            )
        }
        UwbKind::Twr => {
            let sim = insuwb_fusion::scenario::ScenarioFile::load(scenario)?.simulate(DEMO_SEED)?;
            let uwb_link = run_dir.join("uwb");
            let (player, n) =
                crate::emulate_cmd::start_dwm1001_player(&uwb_link, &sim.range, epoch)?;
            (
                format!(
                    "[devices.uwb]\nsource = \"serial:{}\"\nprotocol = \"dwm1001\"\n[uwb]\nkind = \"twr\"\n",
                    uwb_link.display(),
                ),
                format!("DWM1001 tag on serial:{} ({n} lec lines)", uwb_link.display()),
                UwbPlayer::Dwm1001(player),
            )
        }
    };
    let text = format!(
        "[sources]\nimu = \"device\"\nuwb = \"device\"\nscenario = \"{scenario}\"\nseed = {DEMO_SEED}\n\
         [devices.imu]\nsource = \"serial:{}\"\nprotocol = \"witmotion\"\nbaud = {}\n{uwb_text}",
        link.display(),
        imu_enc.baud,
    );
    eprintln!(
        "insuwb demo: devices: WitMotion IMU on serial:{} ({} cycles), {uwb_note}",
        link.display(),
        imu_chunks.len(),
    );
    let imu = Player::start(pty, imu_chunks, epoch, monotonic_ns, Faults::none())?;
    let truth = rec
        .truth
        .iter()
        .map(|t| {
            let mut t = *t;
            t.header.meas_time_ns = t.header.meas_time_ns.saturating_add(epoch);
            t
        })
        .collect();
    Ok((text, DemoDevices { imu, uwb }, truth))
}

/// The demo's scenario of UWB `kind` (the plain and the device demo alike).
const fn demo_scenario(kind: UwbKind) -> &'static str {
    match kind {
        UwbKind::Tdoa => "nlos-long",
        UwbKind::Twr => "nlos-long-twr",
    }
}
/// The demo's seed.
const DEMO_SEED: u64 = 1;
/// The Eliko tag id of the device demo.
const DEMO_TAG: u32 = 1;

/// Runs `insuwb demo`: the whole group on simulated sensors in real time.
pub fn demo(a: &DemoArgs) -> Result<()> {
    if !(a.duration.is_finite() && a.duration > 0.0 && a.duration <= 60.0) {
        bail!(
            "--duration must be in (0, 60] s (the demo scenario lasts 60 s), got {}",
            a.duration
        );
    }
    if let Some(e) = &a.zenoh {
        insuwb_zenoh::config::check_endpoint("connect", e)
            .map_err(|e| anyhow::anyhow!("--zenoh: {}", e.reason))?;
        insuwb_fleet::keys::check_robot_id(&a.robot)
            .map_err(|e| anyhow::anyhow!("--robot: {e}"))?;
    }
    if a.via_devices && a.uwb == UwbKind::Tdoa && a.filter == insuwb_msg::FilterKind::IakfTdoa {
        bail!("--via-devices needs a loosely coupled filter (kf, shaf, stf, iakf) or --uwb twr: the Eliko server reports positions, not TDOA");
    }
    let id = format!("{}_{}", std::process::id(), monotonic_ns() % 1_000_000);
    let run_dir = std::env::temp_dir().join(format!("insuwb-demo-{id}"));
    // Owner-only, as run_group makes everything else.
    insuwb_runtime::perm::restrict_umask();
    std::fs::create_dir_all(&run_dir)?;
    let result = demo_group(a, &id, &run_dir);
    let _ = std::fs::remove_dir_all(&run_dir);
    let r = result?;
    if a.json {
        let v = serde_json::to_value(&r)?;
        let mut out = std::io::stdout().lock();
        serde_json::to_writer(&mut out, &v)?;
        writeln!(out)?;
    } else {
        println!(
            "accuracy: horizontal RMS {} m against ground truth\nrates: fused {:.2} Hz, IMU {:.1} Hz, UWB fixes {:.1} Hz\nrestarts: {}\nlatency UWB fix -> fused: p50 {:.0} us, p99 {:.0} us\ndropped: {}, outliers flagged: {}, degraded outputs: {}",
            r.rmse_horizontal.map_or("n/a".into(), |v| format!("{v:.3}")),
            r.fused_rate_hz,
            r.imu_rate_hz,
            r.uwb_fix_rate_hz,
            r.restarts,
            r.latency_p50_us,
            r.latency_p99_us,
            r.dropped,
            r.outliers,
            r.degraded
        );
    }
    Ok(())
}

/// Writes the demo's config into `run_dir`, starts the devices if asked,
/// and runs the group.
fn demo_group(a: &DemoArgs, id: &str, run_dir: &Path) -> Result<GroupReport> {
    let mut extras = GroupExtras::default();
    let (sources, devices) = if a.via_devices {
        let epoch = choose_start_epoch(monotonic_ns() + 500_000_000);
        let (text, devices, truth) = start_demo_devices(run_dir, epoch, a.uwb)?;
        extras.start_epoch_ns = Some(epoch);
        extras.truth = truth;
        (text, Some(devices))
    } else {
        (
            format!(
                "[sources]\nimu = \"sim\"\nuwb = \"sim\"\nscenario = \"{}\"\nseed = {DEMO_SEED}\nspeed = 1.0\n[uwb]\nkind = \"{}\"\n",
                demo_scenario(a.uwb),
                a.uwb
            ),
            None,
        )
    };
    // The optional stages asked for; `stages` is a top-level key: before
    // the first table.
    let extra = [
        (StageRole::Foxglove, a.foxglove || a.foxglove_bind.is_some()),
        (StageRole::Zenoh, a.zenoh.is_some()),
    ];
    let stages = if extra.iter().any(|(_, on)| *on) {
        format!(
            "stages = [{}]\n",
            StageRole::ALL
                .iter()
                .filter(|r| StageRole::DEFAULT.contains(r) || extra.contains(&(**r, true)))
                .map(|r| format!("\"{}\"", r.name()))
                .collect::<Vec<_>>()
                .join(", ")
        )
    } else {
        String::new()
    };
    let foxglove = a
        .foxglove_bind
        .as_ref()
        .map(|b| format!("[foxglove]\nbind = {}\n", toml::Value::String(b.clone())))
        .unwrap_or_default();
    let zenoh = a
        .zenoh
        .as_ref()
        .map(|e| {
            format!(
                "[zenoh]\nrobot = {}\nconnect = [{}]\n",
                toml::Value::String(a.robot.clone()),
                toml::Value::String(e.clone())
            )
        })
        .unwrap_or_default();
    let text = format!(
        "{stages}[group]\nname = \"demo\"\nprefix = \"insuwb_demo{id}_\"\nrun_dir = \"{}\"\n\
         {sources}[fusion]\nfilter = \"{}\"\n{foxglove}{zenoh}",
        run_dir.display(),
        a.filter
    );
    let cfg_path = run_dir.join("demo.toml");
    let result = std::fs::write(&cfg_path, &text)
        .map_err(anyhow::Error::from)
        .and_then(|()| Ok(RobotConfig::load(&cfg_path)?))
        .and_then(|cfg| {
            eprintln!(
                "insuwb demo: {} stages on the simulated scenario {}{} for {} s (run directory {})",
                cfg.stages.len(),
                demo_scenario(a.uwb),
                if a.via_devices { " through emulated devices" } else { "" },
                a.duration,
                run_dir.display()
            );
            if cfg.stages.contains(&StageRole::Foxglove) {
                eprintln!(
                    "insuwb demo: Foxglove live view on {} (Foxglove app: Open connection, Foxglove WebSocket; layout deploy/foxglove/insuwb-live.json)",
                    cfg.foxglove.url()?
                );
            }
            if cfg.stages.contains(&StageRole::Zenoh) {
                eprintln!(
                    "insuwb demo: Zenoh bridge as robot {robot}, connecting to {} (keys insuwb/{robot}/pose and insuwb/{robot}/health, docs/ZENOH.md)",
                    cfg.zenoh.connect.join(", "),
                    robot = cfg.zenoh.robot
                );
            }
            run_group_with(
                &cfg_path,
                &cfg,
                &RunOptions {
                    duration: Some(Duration::from_secs_f64(a.duration)),
                    live: true,
                    faults: Vec::new(),
                    chaos_seed: None,
                    sample_every: None,
                    env: Vec::new(),
                },
                extras,
            )
        });
    if let Some(d) = devices {
        d.finish();
    }
    result
}
