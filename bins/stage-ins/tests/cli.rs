//! The ins stage binary starts, documents its flags and refuses a missing config.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use std::process::Command;

#[test]
fn help_lists_the_flags() {
    let out = Command::new(env!("CARGO_BIN_EXE_insuwb-ins"))
        .arg("--help")
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for flag in ["--config", "--source", "--speed", "--start-epoch-ns"] {
        assert!(text.contains(flag), "{flag} missing from --help:\n{text}");
    }
}

#[test]
fn missing_config_is_refused_with_its_path() {
    let out = Command::new(env!("CARGO_BIN_EXE_insuwb-ins"))
        .args(["--config", "/nonexistent/insuwb-robot.toml"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/insuwb-robot.toml"), "{err}");
}
