//! `insuwb eval --flights`: the same numbers whatever the thread count, each
//! flight's entry as `insuwb eval FILE --json` prints it, the figures, and
//! bad manifests refused with the manifest's name, line and column.
//! Simulated logs stand in for real flights.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use common::{run, succeeded};

fn json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&succeeded(out).stdout).unwrap()
}

/// A folder with three simulated logs (one in a subfolder), made once.
fn logs() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("insuwb-flights-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("sub")).unwrap();
        for (seed, file) in [("1", "a.log"), ("2", "sub/b.log"), ("3", "c.log")] {
            let out = d.join(file);
            succeeded(&run(&[
                "sim",
                "--scenario",
                "paper-3.4",
                "--seed",
                seed,
                "--out",
                out.to_str().unwrap(),
            ]));
        }
        d
    })
}

fn manifest(name: &str, text: &str) -> PathBuf {
    let p = logs().join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const MANIFEST: &str = "file,anchors,note,ref_m\n\
    a.log,,first,0.05\n\
    sub/b.log,,second,\n\
    c.log,,third,0.2\n";

#[test]
fn same_numbers_on_one_or_several_threads_and_entries_as_single_runs() {
    let m = manifest("flights.csv", MANIFEST);
    let m = m.to_str().unwrap();
    let one = succeeded(&run(&["eval", "--flights", m, "--json", "--jobs", "1"])).clone();
    let three = succeeded(&run(&["eval", "--flights", m, "--json", "--jobs", "3"])).clone();
    assert_eq!(
        String::from_utf8_lossy(&one.stdout),
        String::from_utf8_lossy(&three.stdout)
    );
    let v = json(&one);
    let flights = v["flights"].as_array().unwrap();
    assert_eq!(flights.len(), 3);
    for (f, name) in flights.iter().zip(["a.log", "sub/b.log", "c.log"]) {
        assert_eq!(f["file"], name);
        // The entry is the single-flight object plus `file` and the references.
        let single = json(&run(&[
            "eval",
            logs().join(name).to_str().unwrap(),
            "--json",
        ]));
        let mut entry = f.as_object().unwrap().clone();
        entry.remove("file");
        entry.remove("ref_m");
        assert_eq!(serde_json::Value::Object(entry), single, "{name}");
    }
    assert_eq!(flights[0]["ref_m"], 0.05);
    assert!(flights[1].get("ref_m").is_none());
    // Summary: ratios over the two flights with a reference.
    let kf = &v["summary"]["kf"];
    assert_eq!(kf["flights"], 3);
    assert_eq!(kf["ref_m"]["flights"], 2);
    let r0 = flights[0]["kf"]["rmse_horizontal"].as_f64().unwrap() / 0.05;
    let r2 = flights[2]["kf"]["rmse_horizontal"].as_f64().unwrap() / 0.2;
    let med = kf["ref_m"]["median"].as_f64().unwrap();
    assert!((med - 0.5 * (r0 + r2)).abs() < 1e-12, "{med} {r0} {r2}");
    // (serde_json's default float parsing may be one ulp off.)
    let worst = kf["ref_m"]["worst"].as_f64().unwrap();
    assert!((worst - r0.max(r2)).abs() < 1e-12, "{worst} {r0} {r2}");
    assert!(kf["nees_mean"]["median"].as_f64().unwrap() > 0.0);
    assert!(v["summary"]["uwb"].get("nees_mean").is_none());
    // The tables go to standard error with --json, to standard output without.
    let err = String::from_utf8_lossy(&one.stderr);
    assert!(err.contains("summary over 3 flights"), "{err}");
    let plain = succeeded(&run(&["eval", "--flights", m])).clone();
    let text = String::from_utf8_lossy(&plain.stdout);
    assert!(
        text.contains("sub/b.log") && text.contains("ref_m"),
        "{text}"
    );
}

#[test]
fn plots_one_folder_per_flight_and_a_summary() {
    let m = manifest(
        "plots.csv",
        "file,anchors,ref_m\na.log,,0.05\nsub/b.log,,0.06\n",
    );
    let dir = logs().join("figures");
    succeeded(&run(&[
        "eval",
        "--flights",
        m.to_str().unwrap(),
        "--filters",
        "kf",
        "--plot",
        dir.to_str().unwrap(),
    ]));
    let summary = std::fs::read_to_string(dir.join("summary.svg")).unwrap();
    assert!(
        summary.contains("<title>plots.csv: horizontal RMSE"),
        "summary title"
    );
    for name in ["a.log", "sub/b.log", "ref_m", "kf"] {
        assert!(summary.contains(&format!(">\n{name}\n</text>")), "{name}");
    }
    for folder in ["a.log", "sub_b.log"] {
        assert!(
            dir.join(folder).join("trajectory.svg").is_file(),
            "{folder}"
        );
    }
}

fn refused(manifest_text: &str, wanted: &[&str]) {
    let m = manifest("bad.csv", manifest_text);
    let out = run(&["eval", "--flights", m.to_str().unwrap(), "--json"]);
    assert!(!out.status.success());
    assert!(out.stdout.is_empty());
    let err = String::from_utf8_lossy(&out.stderr);
    for w in wanted {
        let w = w.replace("MANIFEST", &m.display().to_string());
        assert!(err.contains(&w), "wanted '{w}' in: {err}");
    }
}

#[test]
fn bad_manifests_and_failing_flights_are_named() {
    refused(
        "file,ref_m\na.log,0.1\n",
        &["MANIFEST:1: the header has no column `anchors`"],
    );
    refused(
        "file,anchors,ref_m\na.log,,0.1\nmissing.log,,0.1\n",
        &["MANIFEST:3: column `file`: no such file", "missing.log"],
    );
    refused(
        "file,anchors,ref_m\na.log,,0.1m\n",
        &["MANIFEST:2: column `ref_m`: '0.1m' is not a positive number"],
    );
    std::fs::write(logs().join("not-a-log.bin"), b"hello").unwrap();
    refused(
        "file,anchors\na.log,\nnot-a-log.bin,\n",
        &[
            "flight not-a-log.bin (MANIFEST, line 3)",
            "not an insuwb log nor a Crazyflie event log",
        ],
    );
}
