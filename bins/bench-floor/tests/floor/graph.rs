//! The floor graph with real processes: five `insuwb-bench-floor` roles over
//! iceoryx2 shared memory for a few seconds, then its recording checked.

use std::time::Duration;

use insuwb_bench::analysis::{analyse, AnalysisConfig};
use insuwb_bench::graph::{run_floor_graph, FloorGraphOptions};
use insuwb_log::Record;

#[test]
fn the_floor_forwards_every_fix_with_the_ins_state_covering_its_epoch() {
    let id = std::process::id();
    let run_dir = std::env::temp_dir().join(format!("insuwb-floor-test-{id}"));
    let _ = std::fs::remove_dir_all(&run_dir);
    let prefix = format!("iufloortest{id}_");
    let run = run_floor_graph(&FloorGraphOptions {
        program: env!("CARGO_BIN_EXE_insuwb-bench-floor").into(),
        run_dir: run_dir.clone(),
        prefix: prefix.clone(),
        duration: Duration::from_secs(8),
        cpu_from: Duration::from_secs(2),
        fifo_priority: None,
    })
    .unwrap();
    let leftover: Vec<String> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&prefix))
        .collect();
    let _ = std::fs::remove_dir_all(&run_dir);
    assert!(leftover.is_empty(), "/dev/shm files left: {leftover:?}");

    let count = |f: fn(&Record) -> bool| run.records.iter().filter(|r| f(r)).count();
    let imu = count(|r| matches!(r, Record::Imu(_)));
    let truth = count(|r| matches!(r, Record::Truth(_)));
    let nav = count(|r| matches!(r, Record::Nav(_)));
    let fixes = count(|r| matches!(r, Record::Fix(_)));
    let tdoa = count(|r| matches!(r, Record::Tdoa(_)));
    // Every IMU sample has its truth and its INS state, every fix its three
    // differences. How many there are depends on how soon the roles start on
    // a busy machine (100 Hz and 10 Hz from the start epoch on a quiet
    // one); enough for the checks below is asked.
    assert!(
        imu >= 50 && truth == imu && nav >= imu - 5,
        "{imu} {truth} {nav}"
    );
    assert!(fixes >= 5 && tdoa == 3 * fixes, "{fixes} {tdoa}");

    // The waiting rule: each fused state names a fix and the first INS state
    // at or after its epoch (IMU every 10 ms, fixes on whole 100 ms).
    let fused: Vec<_> = run
        .records
        .iter()
        .filter_map(|r| match r {
            Record::Fused(f) => Some(*f),
            _ => None,
        })
        .collect();
    assert!(
        fused.len() >= fixes - 2,
        "{} fused for {fixes} fixes",
        fused.len()
    );
    for f in &fused {
        assert_eq!(f.ins_meas_time_ns, f.uwb_meas_time_ns, "{f:?}");
        assert!(f.header.pub_time_ns >= f.uwb_pub_time_ns.max(f.ins_pub_time_ns));
    }
    assert_eq!(run.recv.len(), fused.len());

    // Missed cycles are a timing figure of `insuwb bench latency`, not a
    // contract of this test: a loaded machine misses some.
    let r = analyse(&run.records, &run.recv, &AnalysisConfig::default()).unwrap();
    assert!(r.fixes >= 3, "{r:?}");
    assert!(
        r.e2e_uwb_fused.count >= 3 && r.e2e_uwb_fused.p50_us > 0.0,
        "{r:?}"
    );
    assert!(r.hops.fusion_logger.count >= 3, "{r:?}");
    let roles: Vec<&str> = run.cpu_percent.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(roles, ["imu", "uwb", "ins", "fusion", "logger"]);
    assert!(
        run.cpu_percent.iter().all(|(_, p)| *p > 0.0),
        "{:?}",
        run.cpu_percent
    );
}
