//! The robot config: errors name the file, the line and the key; optional
//! sections (devices, real-time settings) reach the stages.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;

use insuwb_group::robot::{RobotConfig, RobotConfigError};
use insuwb_group::sources::Source;
use insuwb_msg::StageRole;

fn parse(extra: &str) -> Result<RobotConfig, RobotConfigError> {
    RobotConfig::from_str(extra, "robot.toml", Path::new("/tmp"))
}

fn err(text: &str) -> String {
    format!("{:#}", parse(text).unwrap_err())
}

#[test]
fn realtime_settings_reach_the_stage_runtime() {
    let c = parse("[realtime.fusion]\ncpus = [0]\nfifo_priority = 40\n").unwrap();
    let rt = c.runtime("fusion").realtime;
    assert_eq!(rt.cpus, vec![0]);
    assert_eq!(rt.fifo_priority, Some(40));
    assert_eq!(
        c.runtime("ins").realtime,
        insuwb_runtime::realtime::RealtimeConfig::default()
    );
}

#[test]
fn bad_realtime_and_device_settings_name_the_key() {
    let e = err("[realtime.fusoin]\ncpus = [0]\n");
    assert!(
        e.contains("robot.toml") && e.contains("realtime.fusoin"),
        "{e}"
    );
    let e = err("[realtime.ins]\nfifo_priority = 120\n");
    assert!(e.contains("realtime.ins") && e.contains("1..=99"), "{e}");
    let e = err("[sources]\nimu = \"device\"\n");
    assert!(
        e.contains("sources.imu") && e.contains("[devices.imu]"),
        "{e}"
    );
    let e = err(
        "[sources]\nimu = \"device\"\n[devices.imu]\nsource = \"serial:/dev/ttyUSB0\"\nprotocol = \"nlink\"\n",
    );
    assert!(
        e.contains("devices.imu.protocol") && e.contains("witmotion"),
        "{e}"
    );
    let e = err(
        "[sources]\nuwb = \"device\"\n[devices.uwb]\nsource = \"udp:1.2.3.4\"\nprotocol = \"eliko\"\n",
    );
    assert!(e.contains("devices.uwb.source"), "{e}");
    let e = err("[devices.uwb]\nsource = \"tcp:127.0.0.1:9\"\nprotocol = \"eliko\"\nbaud = 0\n");
    assert!(e.contains("devices.uwb"), "{e}");
    let ok = parse(
        "[sources]\nimu = \"device\"\nuwb = \"device\"\n\
         [devices.imu]\nsource = \"serial:/dev/ttyUSB0\"\nprotocol = \"witmotion\"\n\
         [devices.uwb]\nsource = \"tcp:127.0.0.1:25025\"\nprotocol = \"eliko\"\ntag_id = 7\n",
    )
    .unwrap();
    assert_eq!(ok.devices.uwb.unwrap().tag_id, 7);
}

#[test]
fn a_uwb_device_lever_arm_reaches_the_loose_filters() {
    let c = parse(
        "[sources]\nuwb = \"device\"\n\
         [devices.uwb]\nsource = \"tcp:127.0.0.1:25025\"\nprotocol = \"eliko\"\nlever_arm_m = [0.1, 0.0, 0.3]\n",
    )
    .unwrap();
    assert_eq!(
        c.fusion_config().unwrap().loose.lever_arm_m,
        [0.1, 0.0, 0.3]
    );
    // Without a device the scenario's own (zero) arm stays.
    assert_eq!(
        parse("")
            .unwrap()
            .fusion_config()
            .unwrap()
            .loose
            .lever_arm_m,
        [0.0; 3]
    );
}

#[test]
fn errors_name_the_line_of_the_key() {
    for (text, want) in [
        (
            "[group]\nname = \"r\"\n\n[sources]\nspeed = 0.0\n",
            "robot.toml:5: key 'sources.speed': must be in (0, 1000]",
        ),
        (
            "[devices.uwb]\nsource = \"tcp:127.0.0.1:9\"\nprotocol = \"eliko\"\nbaud = 0\n",
            "robot.toml:1: key 'devices.uwb': baud and wrong_baud_bytes",
        ),
        (
            "[launch]\noptional = [\"nope\"]\n",
            "robot.toml:2: key 'launch.optional': unknown stage 'nope'",
        ),
        // A wrong type or an unknown key, found while parsing.
        (
            "[fusion]\n\ncheckpoint_period_s = \"x\"\n",
            "robot.toml:3: key 'fusion.checkpoint_period_s'",
        ),
        ("[logger]\ndri = \"log\"\n", "robot.toml:2: key 'logger"),
    ] {
        let e = err(text);
        assert!(e.starts_with(want), "{e}");
    }
}

#[test]
fn a_file_is_named_with_the_line_and_its_relative_paths_are_under_its_folder() {
    let dir = std::env::temp_dir().join(format!("insuwb-robot-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("robot.toml");
    std::fs::write(&path, "[group]\nrun_dir = \"run\"\n").unwrap();
    let c = RobotConfig::load(&path);
    std::fs::write(
        &path,
        "[group]\nrun_dir = \"run\"\n[sources]\nuwb = \"replay:missing.log\"\n",
    )
    .unwrap();
    let e = RobotConfig::load(&path);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(c.unwrap().group.run_dir, dir.join("run"));
    assert_eq!(
        e.unwrap_err().to_string(),
        format!(
            "{}:4: key 'sources.uwb': replay file {} does not exist",
            path.display(),
            dir.join("missing.log").display()
        )
    );
}

/// A scratch folder of its own, removed at the end.
struct Scratch(std::path::PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let p = std::env::temp_dir().join(format!("insuwb-robot-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A source is parsed where the file is read: a bad one names the file,
/// the line and the key, and says which forms are accepted.
#[test]
fn a_bad_source_names_the_file_and_the_key() {
    let dir = Scratch::new("bad-source");
    let path = dir.0.join("robot.toml");
    for (text, key, says) in [
        (
            "[sources]\nimu = \"serial:/dev/ttyUSB0\"\n",
            "2: key 'sources.imu'",
            "unknown source 'serial:/dev/ttyUSB0' (sim, device, replay:FILE or ros2:/TOPIC)",
        ),
        (
            "[sources]\nimu = \"sim\"\nuwb = \"replay:\"\n",
            "3: key 'sources.uwb'",
            "needs a file",
        ),
        (
            "[sources]\nimu = \"ros2:/imu//data\"\n",
            "2: key 'sources.imu'",
            "ros2:TOPIC",
        ),
        (
            "[sources]\nuwb = \"ros2:/uwb\"\n",
            "2: key 'sources.uwb'",
            "IMU only",
        ),
        (
            "[sources]\nimu = 3\n",
            "2: key 'sources.imu'",
            "replay:FILE",
        ),
    ] {
        std::fs::write(&path, text).unwrap();
        let e = format!("{:#}", RobotConfig::load(&path).unwrap_err());
        assert!(
            e.starts_with(&format!("{}:{key}", path.display())) && e.contains(says),
            "{text}: {e}"
        );
    }
}

/// The text form round-trips through the loaded config: a replayed file
/// absolute under the config's folder, the others as written.
#[test]
fn sources_round_trip_through_their_text() {
    let dir = Scratch::new("round-trip");
    std::fs::write(dir.0.join("run.iulog"), b"").unwrap();
    let c = RobotConfig::from_str(
        "[sources]\nimu = \"replay:run.iulog\"\nuwb = \"device\"\n\
         [devices.uwb]\nsource = \"tcp:127.0.0.1:25025\"\nprotocol = \"eliko\"\n",
        "robot.toml",
        &dir.0,
    );
    let c = c.unwrap();
    assert_eq!(c.sources.imu, Source::Replay(dir.0.join("run.iulog")));
    assert_eq!(c.sources.uwb, Source::Device);
    for s in [&c.sources.imu, &c.sources.uwb] {
        assert_eq!(&s.to_string().parse::<Source>().unwrap(), s);
    }
    assert_eq!(
        c.sources.imu.to_string(),
        format!("replay:{}", dir.0.join("run.iulog").display())
    );
    // The whole table, written and read back.
    let text = toml::to_string(&c.sources).unwrap();
    let back: insuwb_group::robot::SourcesConfig = toml::from_str(&text).unwrap();
    assert_eq!(back, c.sources, "{text}");
}

/// `[realtime.<stage>]` is keyed by the stage role; another name is
/// refused, naming it and the roles.
#[test]
fn realtime_tables_are_keyed_by_stage_role() {
    let c = parse("[realtime.fusion]\ncpus = [1]\n[realtime.imu]\nfifo_priority = 10\n").unwrap();
    assert_eq!(
        c.realtime.keys().copied().collect::<Vec<_>>(),
        [StageRole::Imu, StageRole::Fusion]
    );
    assert_eq!(c.runtime("imu").realtime.fifo_priority, Some(10));
    assert_eq!(
        c.runtime("monitor").realtime,
        insuwb_runtime::realtime::RealtimeConfig::default()
    );
    let e = err("[realtime.fusion]\ncpus = [1]\n[realtime.gps]\ncpus = [0]\n");
    assert!(
        e.starts_with("robot.toml")
            && e.contains("key 'realtime'")
            && e.contains("[realtime.gps]: unknown stage 'gps'")
            && e.contains("imu, uwb, ins, fusion"),
        "{e}"
    );
    // A setting inside a table is still named by its whole key.
    let e = err("[realtime.ins]\ncpus = \"x\"\n");
    assert!(e.contains("robot.toml:2: key 'realtime.ins.cpus'"), "{e}");
}

/// robot.toml's `[fusion]` is the fusion process's: an estimator table
/// there is refused, saying where it goes; its own keys keep working.
#[test]
fn an_estimator_setting_in_the_process_table_says_where_it_goes() {
    for (text, key) in [
        (
            "[fusion]\nfilter = \"iakf\"\n\n[fusion.fix]\nperiod_s = 0.2\n",
            "fusion.fix",
        ),
        ("[fusion.filter]\ngamma = 2.0\n", "fusion.filter"),
        ("[fusion]\nvehicle = \"ground\"\n", "fusion.vehicle"),
    ] {
        let e = err(text);
        assert!(
            e.contains(&format!("key '{key}'"))
                && e.contains("estimator setting")
                && e.contains("fusion.config"),
            "{text}: {e}"
        );
    }
    let e = err("[fusion]\nfilter = \"iakf\"\n\n[fusion.fix]\nperiod_s = 0.2\n");
    assert!(e.starts_with("robot.toml:4: key 'fusion.fix'"), "{e}");
    let c =
        parse("[fusion]\nfilter = \"iakf_tdoa\"\ncheckpoint_period_s = 1.0\neager_lag_s = 0.01\n")
            .unwrap();
    assert_eq!(c.filter_kind(), insuwb_msg::FilterKind::IakfTdoa);
    assert_eq!(c.fusion.eager_lag_s, 0.01);
    // A misspelt key is still the parser's unknown field.
    assert!(err("[fusion]\neager_lag = 0.0\n").contains("eager_lag"));
}

/// `eager_lag_s` lives in robot.toml's `[fusion]`: the estimator's
/// settings file refuses its own as the robot config is loaded, naming the
/// file, its key and robot.toml's.
#[test]
fn eager_lag_s_has_one_home() {
    let dir = Scratch::new("eager");
    let estimator = dir.0.join("estimator.toml");
    std::fs::write(&estimator, "[fusion.engine]\neager_lag_s = 0.01\n").unwrap();
    let robot = "[fusion]\nconfig = \"estimator.toml\"\neager_lag_s = 0.02\n";
    let e = format!(
        "{:#}",
        RobotConfig::from_str(robot, "robot.toml", &dir.0).unwrap_err()
    );
    assert!(
        e.starts_with(&format!(
            "{}:2: key 'fusion.engine.eager_lag_s'",
            estimator.display()
        )) && e.contains("robot.toml's [fusion] table"),
        "{e}"
    );
    // Without it the file is the estimator's settings.
    std::fs::write(&estimator, "[fusion.fix]\nperiod_s = 0.2\n").unwrap();
    let c = RobotConfig::from_str(robot, "robot.toml", &dir.0).unwrap();
    assert_eq!(c.fusion_config().unwrap().fix.period_s, 0.2);
    assert_eq!(c.fusion.eager_lag_s, 0.02);
}

/// The fusion settings of a replayed log come from its header alone: a
/// log whose records are garbage still gives them, and one without a
/// header is named.
#[test]
fn a_replayed_log_s_settings_come_from_its_header_alone() {
    use insuwb_log::{LogWriter, Metadata};
    let dir = Scratch::new("replay-header");
    let log = dir.0.join("run.iulog");
    let meta = Metadata::new("test").with(
        "fusion_config",
        "[fusion.fix]\nperiod_s = 0.25\n[fusion.loose]\nlever_arm_m = [0.0, 0.0, 0.5]\n",
    );
    LogWriter::create(&log, &meta, 0).unwrap().finish().unwrap();
    let mut bytes = std::fs::read(&log).unwrap();
    bytes.extend(std::iter::repeat_n(0xa5u8, 1 << 20));
    std::fs::write(&log, &bytes).unwrap();
    let c = parse_in(
        &dir.0,
        "[sources]\nimu = \"replay:run.iulog\"\nuwb = \"replay:run.iulog\"\n",
    );
    let f = c.fusion_config().unwrap();
    assert_eq!(f.fix.period_s, 0.25);
    assert_eq!(f.loose.lever_arm_m, [0.0, 0.0, 0.5]);
    std::fs::write(&log, b"not a log").unwrap();
    let e = format!("{:#}", c.fusion_config().unwrap_err());
    assert!(
        e.contains(&log.display().to_string()) && e.contains("log header"),
        "{e}"
    );
}

fn parse_in(dir: &Path, text: &str) -> RobotConfig {
    RobotConfig::from_str(text, "robot.toml", dir).unwrap()
}
