//! The floor binary starts, documents its flags and refuses bad input.
use std::process::Command;

#[test]
fn help_lists_the_flags() {
    let out = Command::new(env!("CARGO_BIN_EXE_insuwb-bench-floor"))
        .arg("--help")
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--role",
        "--prefix",
        "--root-path",
        "--start-epoch-ns",
        "--trace-dir",
    ] {
        assert!(text.contains(flag), "{flag} missing from --help:\n{text}");
    }
}

#[test]
fn an_unknown_role_and_a_bad_rate_are_refused_by_name() {
    let out = Command::new(env!("CARGO_BIN_EXE_insuwb-bench-floor"))
        .args(["--role", "gps"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("gps"), "{err}");
    let out = Command::new(env!("CARGO_BIN_EXE_insuwb-bench-floor"))
        .args(["--role", "imu", "--imu-rate-hz", "0"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("floor.imu_rate_hz"), "{err}");
}
