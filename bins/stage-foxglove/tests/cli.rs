//! The Foxglove live-view binary starts, documents its flag and refuses a
//! missing config or a bad `[foxglove]` key before it opens anything. Its
//! own test file also makes cargo build the binary for the workspace's
//! integration tests (bins/insuwb/tests/foxglove_live.rs).
#![allow(clippy::unwrap_used)]

use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_insuwb-stage-foxglove");

#[test]
fn help_lists_the_config_flag() {
    let out = Command::new(BIN).arg("--help").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("--config"), "{text}");
}

#[test]
fn missing_config_is_refused_with_its_path() {
    let out = Command::new(BIN)
        .args(["--config", "/nonexistent/insuwb-robot.toml"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/insuwb-robot.toml"), "{err}");
}

#[test]
fn a_bad_bind_address_is_refused_naming_the_key() {
    let dir = std::env::temp_dir().join(format!("insuwb-foxglove-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("robot.toml");
    std::fs::write(
        &cfg,
        format!(
            "[group]\nname = \"t\"\nprefix = \"insuwb_fgcli_{}_\"\nrun_dir = \"{}\"\n[foxglove]\nbind = \"localhost:8765\"\n",
            std::process::id(),
            dir.join("run").display()
        ),
    )
    .unwrap();
    let out = Command::new(BIN)
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("foxglove.bind"), "{err}");
}
