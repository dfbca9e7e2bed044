// Shared body of every stage binary's CLI test (included by bins/stage-*/tests/cli.rs,
// which define `STAGE_BIN`). Each stage package keeps its own test file so that
// cargo builds its binary for the integration tests of the workspace.
use std::process::Command;

#[test]
fn help_lists_the_flags() {
    let out = Command::new(STAGE_BIN)
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
    let out = Command::new(STAGE_BIN)
        .args(["--config", "/nonexistent/insuwb-robot.toml"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/insuwb-robot.toml"), "{err}");
}
