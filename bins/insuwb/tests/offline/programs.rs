// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

//! Every program beside `insuwb` starts, documents its flags and refuses a
//! missing config or bad input before it opens anything: the five stages,
//! the three bridges (a bad key of their table named) and the floor bench.
//! They are built by `cargo build --release --workspace`, the first half of
//! the test command.

use std::path::PathBuf;
use std::process::Command;

/// Program `name` beside the `insuwb` executable under test.
fn program(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_BIN_EXE_insuwb"))
        .parent()
        .unwrap()
        .join(name);
    assert!(
        p.is_file(),
        "{} is not built: the tests need `cargo build --release --workspace` first",
        p.display()
    );
    p
}

const STAGES: [&str; 5] = [
    "insuwb-stage-imu",
    "insuwb-stage-uwb",
    "insuwb-stage-ins",
    "insuwb-stage-fusion",
    "insuwb-stage-logger",
];

/// The bridges: program, table, a bad entry of it, the key its error names.
const BRIDGES: [(&str, &str, &str, &str); 3] = [
    (
        "insuwb-stage-ros2",
        "ros2",
        "frame_id = \"/map\"",
        "ros2.frame_id",
    ),
    (
        "insuwb-stage-foxglove",
        "foxglove",
        "bind = \"localhost:8765\"",
        "foxglove.bind",
    ),
    (
        "insuwb-stage-zenoh",
        "zenoh",
        "connect = [\"udp/127.0.0.1:7447\"]",
        "zenoh.connect",
    ),
];

#[test]
fn every_stage_and_bridge_documents_its_flags() {
    for name in STAGES {
        let out = Command::new(program(name)).arg("--help").output().unwrap();
        assert!(out.status.success(), "{name}");
        let text = String::from_utf8_lossy(&out.stdout);
        for flag in ["--config", "--source", "--speed", "--start-epoch-ns"] {
            assert!(
                text.contains(flag),
                "{name}: {flag} missing from --help:\n{text}"
            );
        }
    }
    for (name, ..) in BRIDGES {
        let out = Command::new(program(name)).arg("--help").output().unwrap();
        assert!(out.status.success(), "{name}");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.contains("--config"), "{name}: {text}");
    }
}

#[test]
fn a_missing_config_is_refused_with_its_path() {
    for name in STAGES.into_iter().chain(BRIDGES.map(|b| b.0)) {
        let out = Command::new(program(name))
            .args(["--config", "/nonexistent/insuwb-robot.toml"])
            .output()
            .unwrap();
        assert!(!out.status.success(), "{name}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("/nonexistent/insuwb-robot.toml"),
            "{name}: {err}"
        );
    }
}

#[test]
fn a_bridge_refuses_a_bad_key_of_its_table_naming_the_key() {
    for (name, table, bad_entry, bad_key) in BRIDGES {
        let id = format!("{table}-cli-{}", std::process::id());
        let dir = std::env::temp_dir().join(format!("insuwb-{id}"));
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = dir.join("robot.toml");
        std::fs::write(
            &cfg,
            format!(
                "[group]\nname = \"t\"\nprefix = \"insuwb_{}_\"\nrun_dir = \"{}\"\n[{table}]\n{bad_entry}\n",
                id.replace('-', "_"),
                dir.join("run").display()
            ),
        )
        .unwrap();
        let out = Command::new(program(name))
            .arg("--config")
            .arg(&cfg)
            .output()
            .unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert!(!out.status.success(), "{name}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(bad_key), "{name}: {err}");
    }
}
