//! The robot config: errors name the file and the key; optional sections
//! (devices, real-time settings) reach the stages.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;

use insuwb_stage::group::RobotConfig;

fn parse(extra: &str) -> anyhow::Result<RobotConfig> {
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
