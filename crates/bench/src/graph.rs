//! Running the floor graph: one `insuwb-bench-floor` process per role under the
//! launcher's supervisor, through the groups' launch loop
//! (`insuwb_group::launch`; no restarts, no watchdog: a floor process that
//! exits fails the run), for a fixed time, then an orderly SIGTERM shutdown
//! in the pipeline's order; the floor logger's records and receive trace are
//! read back, and the CPU time of each role over a steady window is taken
//! from `/proc`.

use core::time::Duration;
use std::path::PathBuf;
use std::time::Instant;

use insuwb_group::launch::{supervise, LoopEnd, LoopOptions, Watch};
use insuwb_launch::{LaunchError, RestartPolicy, StageSpec, Supervisor};
use insuwb_log::Record;
use insuwb_runtime::{cleanup, monotonic_ns};

use crate::floor::{Role, FLOOR_LOG_FILE, FUSED_TRACE_FILE};
use crate::trace::{self, RecvStamp, TraceError};

/// How to run the floor graph.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorGraphOptions {
    /// The `insuwb-bench-floor` program.
    pub program: PathBuf,
    /// Run folder (created): iceoryx2 root (`iox2`) and the logger's trace (`trace`).
    pub run_dir: PathBuf,
    /// iceoryx2 service prefix of this run (unique per run).
    pub prefix: String,
    /// How long the graph runs, from the start of its processes.
    pub duration: Duration,
    /// Start of the CPU window after the start (the window ends at `duration`).
    pub cpu_from: Duration,
    /// SCHED_FIFO priority of the fusion role; the others get theirs from
    /// [`fifo_ladder`] (`None`: the normal scheduler).
    pub fifo_priority: Option<i32>,
}

/// The SCHED_FIFO priority of stage `stage` when the fusion stage has
/// `top`: one step down per hop away from the fused output along the fix
/// path (fusion `top`, INS `top - 1`, the drivers `top - 2`), so a stage
/// further down the path preempts the ones that feed it once their sample
/// is out; the logger stays in the normal scheduler (its disk writes must
/// not hold a CPU against the path). `None` for an unknown stage or a
/// priority out of 1..=99.
#[must_use]
pub fn fifo_ladder(stage: &str, top: i32) -> Option<i32> {
    let p = match stage.parse::<Role>().ok()? {
        Role::Fusion => top,
        Role::Ins => top - 1,
        Role::Imu | Role::Uwb => top - 2,
        Role::Logger | Role::Ros2 | Role::Foxglove | Role::Zenoh => return None,
    };
    (1..=99).contains(&p).then_some(p)
}

/// What a floor run produced.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorRun {
    /// Everything the floor logger received.
    pub records: Vec<Record>,
    /// When the floor logger received each fused state.
    pub recv: Vec<RecvStamp>,
    /// CPU time of each role over the window, percent of one core, in role order.
    pub cpu_percent: Vec<(String, f64)>,
}

/// Why the floor graph could not be run.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    /// The run folder could not be created.
    #[error("cannot create the floor run folder {path}: {error}")]
    RunDir {
        /// The folder.
        path: String,
        /// The I/O error.
        error: std::io::Error,
    },
    /// The floor program is missing.
    #[error("floor program {0} not found (build the workspace: cargo build --release)")]
    Program(String),
    /// The supervisor could not start the graph.
    #[error(transparent)]
    Launch(#[from] LaunchError),
    /// A floor process exited during the run.
    #[error("floor process {0} exited during the run (see its log above)")]
    Exited(String),
    /// The floor log could not be read.
    #[error("cannot read the floor log {path}: {reason}")]
    Log {
        /// The file.
        path: String,
        /// Why.
        reason: String,
    },
    /// The receive trace could not be read.
    #[error(transparent)]
    Trace(#[from] TraceError),
}

/// CPU time (ns) of each `(name, pid)`; a process that cannot be read counts 0.
#[must_use]
pub fn cpu_snapshot(pids: &[(String, u32)]) -> Vec<(String, u64)> {
    pids.iter()
        .map(|(n, p)| (n.clone(), crate::cpu::cpu_time_ns(*p).unwrap_or(0)))
        .collect()
}

/// Percent of one core per name between two snapshots `wall_ns` apart
/// (names missing from `before` count from 0).
#[must_use]
pub fn cpu_percent(
    before: &[(String, u64)],
    after: &[(String, u64)],
    wall_ns: u64,
) -> Vec<(String, f64)> {
    after
        .iter()
        .map(|(n, a)| {
            let b = before.iter().find(|(m, _)| m == n).map_or(0, |(_, v)| *v);
            (
                n.clone(),
                crate::cpu::percent_of_core(a.saturating_sub(b), wall_ns),
            )
        })
        .collect()
}

/// Runs the floor graph (see the module documentation).
pub fn run_floor_graph(opts: &FloorGraphOptions) -> Result<FloorRun, GraphError> {
    if !opts.program.is_file() {
        return Err(GraphError::Program(opts.program.display().to_string()));
    }
    let root = opts.run_dir.join("iox2");
    let trace_dir = opts.run_dir.join("trace");
    for d in [&root, &trace_dir] {
        // Owner-only, as the stages want their iceoryx2 root.
        insuwb_runtime::perm::create_private_dir(d).map_err(|source| GraphError::RunDir {
            path: d.display().to_string(),
            error: source,
        })?;
    }
    // As the pipeline's launcher: a start epoch (`insuwb_runtime::epoch`)
    // at least 1 s ahead.
    let epoch = insuwb_runtime::epoch::epoch_at_or_after(monotonic_ns() + 1_000_000_000);
    let (root_s, trace_s, epoch_s) = (
        root.display().to_string(),
        trace_dir.display().to_string(),
        epoch.to_string(),
    );
    // The floor's five stages: the ROS 2 bridge has no floor stage.
    let specs: Vec<StageSpec> = Role::DEFAULT
        .iter()
        .map(|r| {
            let mut args = vec![
                "--role",
                r.name(),
                "--prefix",
                &opts.prefix,
                "--root-path",
                &root_s,
                "--start-epoch-ns",
                &epoch_s,
                "--trace-dir",
                &trace_s,
            ];
            let fifo = opts
                .fifo_priority
                .and_then(|top| fifo_ladder(r.name(), top))
                .map(|p| p.to_string());
            if let Some(p) = &fifo {
                args.extend(["--fifo-priority", p.as_str()]);
            }
            StageSpec::new(r.name(), &opts.program, &args)
        })
        .collect();
    let policy = RestartPolicy {
        heartbeat_timeout_ms: 0,
        budget_restarts: 0,
        ..RestartPolicy::default()
    };
    let mut sup = Supervisor::new(policy, specs)?;
    let mut watch = CpuWatch {
        cpu_from: opts.cpu_from,
        duration: opts.duration,
        before: None,
        cpu: Vec::new(),
    };
    let loop_opts = LoopOptions {
        duration: Some(opts.duration),
        max_wait: Duration::from_millis(20),
        shutdown_order: Role::DEFAULT.map(|r| r.name().to_owned()).to_vec(),
    };
    let end = supervise(&mut sup, Instant::now(), &loop_opts, &mut watch, None);
    let failed = match end {
        Ok(LoopEnd::Failed(stage)) => Some(GraphError::Exited(stage)),
        Ok(LoopEnd::NotStarted(e)) => Some(GraphError::from(e)),
        Ok(LoopEnd::Duration | LoopEnd::Shutdown) => None,
        Err(never) => match never {},
    };
    let cpu = watch.cpu;
    if let Err(e) = cleanup::remove_prefix_files(&opts.prefix, Some(&root)) {
        tracing::warn!("removing the floor's shared-memory files: {e}");
    }
    if let Some(e) = failed {
        return Err(e);
    }
    let log = trace_dir.join(FLOOR_LOG_FILE);
    let (records, _, _) = insuwb_log::read_all(&log).map_err(|e| GraphError::Log {
        path: log.display().to_string(),
        reason: e.to_string(),
    })?;
    let recv = trace::read(&trace_dir.join(FUSED_TRACE_FILE))?;
    Ok(FloorRun {
        records,
        recv,
        cpu_percent: cpu,
    })
}

fn live_pids(sup: &Supervisor) -> Vec<(String, u32)> {
    sup.pids()
        .into_iter()
        .filter_map(|(n, p)| Some((n, p?)))
        .collect()
}

/// The floor graph's watch: a 20 ms sleep between polls, and the stages'
/// CPU from `cpu_from` to the end of the run.
struct CpuWatch {
    cpu_from: Duration,
    duration: Duration,
    before: Option<(Instant, Vec<(String, u64)>)>,
    cpu: Vec<(String, f64)>,
}

impl Watch for CpuWatch {
    type Error = std::convert::Infallible;

    fn wait(&mut self, max: Duration) -> Result<bool, Self::Error> {
        std::thread::sleep(max);
        Ok(false)
    }

    fn on_wake(
        &mut self,
        sup: &mut Supervisor,
        now: Instant,
        elapsed: Duration,
    ) -> Result<(), Self::Error> {
        let pids = live_pids(sup);
        if self.before.is_none() && elapsed >= self.cpu_from {
            self.before = Some((now, cpu_snapshot(&pids)));
        }
        if elapsed >= self.duration {
            if let Some((at, before)) = &self.before {
                let wall = u64::try_from(now.duration_since(*at).as_nanos()).unwrap_or(u64::MAX);
                self.cpu = cpu_percent(before, &cpu_snapshot(&pids), wall);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_percent_pairs_snapshots_by_name() {
        let before = vec![("a".to_owned(), 1_000_000), ("b".to_owned(), 0)];
        let after = vec![
            ("a".to_owned(), 11_000_000),
            ("b".to_owned(), 5_000_000),
            ("c".to_owned(), 2_000_000),
        ];
        let p = cpu_percent(&before, &after, 1_000_000_000);
        assert_eq!(
            p,
            vec![("a".into(), 1.0), ("b".into(), 0.5), ("c".into(), 0.2)]
        );
    }

    #[test]
    fn the_fifo_ladder_steps_down_the_fix_path() {
        assert_eq!(fifo_ladder("fusion", 50), Some(50));
        assert_eq!(fifo_ladder("ins", 50), Some(49));
        assert_eq!(fifo_ladder("imu", 50), Some(48));
        assert_eq!(fifo_ladder("uwb", 50), Some(48));
        assert_eq!(fifo_ladder("logger", 50), None, "the logger stays normal");
        assert_eq!(fifo_ladder("other", 50), None);
        // Every priority stays in 1..=99.
        assert_eq!(fifo_ladder("fusion", 2), Some(2));
        assert_eq!(fifo_ladder("ins", 2), Some(1));
        assert_eq!(fifo_ladder("imu", 2), None);
        assert_eq!(fifo_ladder("fusion", 100), None);
    }

    #[test]
    fn a_missing_program_is_refused_by_path() {
        let e = run_floor_graph(&FloorGraphOptions {
            program: "/nonexistent/insuwb-bench-floor".into(),
            run_dir: std::env::temp_dir().join("insuwb-bench-never"),
            prefix: "x_".into(),
            duration: Duration::from_secs(1),
            cpu_from: Duration::ZERO,
            fifo_priority: None,
        })
        .unwrap_err();
        assert!(
            e.to_string().contains("/nonexistent/insuwb-bench-floor"),
            "{e}"
        );
    }
}
