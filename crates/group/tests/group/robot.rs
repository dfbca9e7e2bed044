//! The robot config: errors name the file, the line and the key; optional
//! sections (devices, real-time settings) reach the stages.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;

use insuwb_group::robot::{RobotConfig, RobotConfigError};

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
