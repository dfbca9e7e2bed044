// Shared body of the bridge stages' CLI tests (included by
// bins/stage-ros2/tests/cli.rs, bins/stage-foxglove/tests/cli.rs and
// bins/stage-zenoh/tests/cli.rs, which define `STAGE_BIN`, the bridge's
// `TABLE`, a `BAD_ENTRY` of it and the `BAD_KEY` its error must name). A
// bridge takes only `--config`; it refuses a missing config or a bad key of
// its table before it opens anything. Each package keeps its own test file
// so that cargo builds its binary for the integration tests of the
// workspace.
use std::process::Command;

#[test]
fn help_lists_the_config_flag() {
    let out = Command::new(STAGE_BIN).arg("--help").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("--config"), "{text}");
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

#[test]
fn a_bad_key_of_its_table_is_refused_naming_the_key() {
    let id = format!("{TABLE}-cli-{}", std::process::id());
    let dir = std::env::temp_dir().join(format!("insuwb-{id}"));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("robot.toml");
    std::fs::write(
        &cfg,
        format!(
            "[group]\nname = \"t\"\nprefix = \"insuwb_{}_\"\nrun_dir = \"{}\"\n[{TABLE}]\n{BAD_ENTRY}\n",
            id.replace('-', "_"),
            dir.join("run").display()
        ),
    )
    .unwrap();
    let out = Command::new(STAGE_BIN)
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(BAD_KEY), "{err}");
}
