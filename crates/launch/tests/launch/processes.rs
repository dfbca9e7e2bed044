//! The supervisor against real processes (`/bin/sh`, `sleep`, `false`).
//! The tests measure time, so they run one at a time (SERIAL); every time
//! bound is a lower bound or a generous "within" limit.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use insuwb_launch::{
    Event, ExitKind, KillError, LaunchError, RestartPolicy, StageSpec, Supervisor, SupervisorState,
};

static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

fn sh(name: &str, script: &str) -> StageSpec {
    StageSpec::new(name, "/bin/sh", &["-c", script])
}

fn sleeper(name: &str) -> StageSpec {
    StageSpec::new(name, "sleep", &["30"])
}

/// A fresh path in the temp folder, removed if it exists.
fn temp_path(tag: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("insuwb-launch-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_file(&p);
    p
}

/// A policy with the watchdog off and a large budget, for tests to adjust.
fn quiet_policy() -> RestartPolicy {
    RestartPolicy {
        heartbeat_timeout_ms: 0,
        budget_restarts: 100,
        ..Default::default()
    }
}

/// An event seen by [`run_until`], with the `now` of the poll that returned it.
type Timed = (Instant, Event);

/// Polls every 5 ms (calling `each` before each poll) until `done` holds
/// for an event; panics after `within`. Returns every event seen.
fn run_until(
    sup: &mut Supervisor,
    within: Duration,
    mut each: impl FnMut(&mut Supervisor, Instant),
    mut done: impl FnMut(&Event) -> bool,
) -> Vec<Timed> {
    let t0 = Instant::now();
    let mut seen = Vec::new();
    loop {
        let now = Instant::now();
        assert!(
            now - t0 < within,
            "condition not met within {within:?}; events: {seen:#?}"
        );
        each(sup, now);
        let evs = sup.poll(now);
        let hit = evs.iter().any(&mut done);
        seen.extend(evs.into_iter().map(|e| (now, e)));
        if hit {
            return seen;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn no_hook(_: &mut Supervisor, _: Instant) {}

/// True when the process is gone or a zombie that is not ours to reap.
fn process_gone(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Err(_) => true,
        Ok(stat) => {
            // State is the field after the ")" that closes the command name.
            let state = stat
                .rsplit(')')
                .next()
                .and_then(|r| r.split_whitespace().next());
            state == Some("Z")
        }
    }
}

fn wait_gone(pid: u32, within: Duration) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < within {
        if process_gone(pid) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}

fn pid_of(sup: &Supervisor, stage: &str) -> Option<u32> {
    sup.pids()
        .into_iter()
        .find(|(n, _)| n == stage)
        .and_then(|(_, p)| p)
}

fn read_lines(p: &Path) -> Vec<String> {
    std::fs::read_to_string(p)
        .unwrap_or_default()
        .lines()
        .map(str::to_owned)
        .collect()
}

#[test]
fn crashing_stage_restarts_with_growing_capped_backoff_and_counts_generations() {
    let _g = serial();
    let file = temp_path("generations");
    let script = format!(
        "echo \"$INSUWB_GENERATION $INSUWB_STAGE\" >> '{}'; exit 3",
        file.display()
    );
    let policy = RestartPolicy {
        backoff_initial_ms: 50,
        backoff_max_ms: 200,
        ..quiet_policy()
    };
    let mut sup = Supervisor::new(policy, vec![sh("crasher", &script)]).unwrap();
    let t0 = Instant::now();
    sup.start(t0).unwrap();
    assert!(matches!(
        sup.events(),
        [Event::Started { stage, generation: 0, .. }] if stage == "crasher"
    ));
    let seen = run_until(&mut sup, Duration::from_secs(5), no_hook, |e| {
        matches!(e, Event::Restarted { generation: 5, .. })
    });
    // Let generation 5 end too, so the file holds exactly six lines.
    run_until(&mut sup, Duration::from_secs(2), no_hook, |e| {
        matches!(e, Event::Exited { .. })
    });

    let delays: Vec<u64> = seen
        .iter()
        .filter_map(|(_, e)| match e {
            Event::RestartScheduled { delay_ms, .. } => Some(*delay_ms),
            _ => None,
        })
        .collect();
    // 50, doubling, capped at 200 (each run is far shorter than stable_after_s).
    assert_eq!(delays, [50, 100, 200, 200, 200]);
    let gens: Vec<u32> = seen
        .iter()
        .filter_map(|(_, e)| match e {
            Event::Restarted { generation, .. } => Some(*generation),
            _ => None,
        })
        .collect();
    assert_eq!(gens, [1, 2, 3, 4, 5]);
    for (_, e) in &seen {
        if let Event::Exited { status, .. } = e {
            assert_eq!(*status, ExitKind::Code(3));
        }
    }
    // Each restart happened no earlier than its delay after the exit was reaped.
    let mut exit_at = None;
    let mut checked = 0;
    for (t, e) in &seen {
        match e {
            Event::Exited { .. } => exit_at = Some(*t),
            Event::Restarted { generation, .. } => {
                let want = delays[*generation as usize - 1];
                let gap = *t - exit_at.unwrap();
                assert!(
                    gap >= Duration::from_millis(want),
                    "gen {generation}: {gap:?}"
                );
                checked += 1;
            }
            _ => {}
        }
    }
    assert_eq!(checked, 5);
    assert_eq!(sup.restarts("crasher"), 5);
    assert_eq!(sup.total_restarts(), 5);
    assert_eq!(sup.state(), SupervisorState::Running);

    let expected: Vec<String> = (0..6).map(|g| format!("{g} crasher")).collect();
    assert_eq!(read_lines(&file), expected);
    sup.shutdown(&[]);
    let _ = std::fs::remove_file(&file);
}

/// Polls for `span` and fails on any event.
fn assert_quiet(sup: &mut Supervisor, span: Duration) {
    let t0 = Instant::now();
    while t0.elapsed() < span {
        let evs = sup.poll(Instant::now());
        assert!(evs.is_empty(), "{evs:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Starts a stage `crasher` that exits at once (budget `budget` restarts in
/// 10 s, fast backoff, `optional` stages) beside a healthy sleeper; returns
/// the supervisor and the sleeper's pid.
fn start_crasher(crasher: &str, budget: u32, optional: &[&str]) -> (Supervisor, u32) {
    let policy = RestartPolicy {
        backoff_initial_ms: 10,
        backoff_max_ms: 20,
        budget_restarts: budget,
        budget_window_s: 10.0,
        optional: optional.iter().map(|s| (*s).to_owned()).collect(),
        ..quiet_policy()
    };
    let stages = vec![StageSpec::new(crasher, "false", &[]), sleeper("healthy")];
    let mut sup = Supervisor::new(policy, stages).unwrap();
    sup.start(Instant::now()).unwrap();
    let healthy_pid = pid_of(&sup, "healthy").unwrap();
    (sup, healthy_pid)
}

#[test]
fn a_stage_that_keeps_crashing_exhausts_its_budget() {
    let _g = serial();
    let (mut sup, healthy_pid) = start_crasher("crasher", 3, &[]);
    let seen = run_until(&mut sup, Duration::from_secs(5), no_hook, |e| {
        matches!(e, Event::BudgetExhausted { .. })
    });
    let scheduled = seen
        .iter()
        .filter(|(_, e)| matches!(e, Event::RestartScheduled { .. }))
        .count();
    assert_eq!(scheduled, 3);
    let exits: Vec<&ExitKind> = seen
        .iter()
        .filter_map(|(_, e)| match e {
            Event::Exited { status, .. } => Some(status),
            _ => None,
        })
        .collect();
    assert_eq!(exits, [&ExitKind::Code(1); 4]);
    assert!(matches!(
        seen.last().map(|(_, e)| e),
        Some(Event::BudgetExhausted { stage }) if stage == "crasher"
    ));
    assert_eq!(
        sup.state(),
        SupervisorState::Failed {
            stage: "crasher".into()
        }
    );
    assert_eq!(sup.restarts("crasher"), 3);

    // Failed: nothing is restarted any more; the healthy stage is untouched.
    assert_quiet(&mut sup, Duration::from_millis(200));
    assert_eq!(pid_of(&sup, "crasher"), None);
    assert_eq!(pid_of(&sup, "healthy"), Some(healthy_pid));
    assert_eq!(sup.restarts("healthy"), 0);

    let evs = sup.shutdown(&["healthy"]);
    assert_eq!(
        evs,
        [
            Event::Exited {
                stage: "healthy".into(),
                pid: healthy_pid,
                status: ExitKind::Signal(libc::SIGTERM)
            },
            Event::Stopped {
                stage: "healthy".into()
            },
            Event::Stopped {
                stage: "crasher".into()
            },
        ]
    );
    assert_eq!(sup.state(), SupervisorState::Stopped);
}

#[test]
fn an_optional_stage_that_keeps_crashing_is_given_up_alone() {
    let _g = serial();
    let (mut sup, healthy_pid) = start_crasher("recorder", 2, &["recorder"]);
    let seen = run_until(&mut sup, Duration::from_secs(5), no_hook, |e| {
        matches!(e, Event::GaveUp { .. })
    });
    assert!(
        !seen
            .iter()
            .any(|(_, e)| matches!(e, Event::BudgetExhausted { .. })),
        "{seen:?}"
    );
    assert_eq!(sup.restarts("recorder"), 2);
    assert_eq!(sup.given_up(), ["recorder"]);
    // Still running: the other stage is supervised as before, the optional
    // one is never restarted again.
    assert_eq!(sup.state(), SupervisorState::Running);
    assert_quiet(&mut sup, Duration::from_millis(200));
    assert_eq!(pid_of(&sup, "recorder"), None);
    // A crash of the healthy stage is still restarted.
    sup.kill_stage("healthy", libc::SIGKILL).unwrap();
    run_until(
        &mut sup,
        Duration::from_secs(5),
        no_hook,
        |e| matches!(e, Event::Restarted { stage, .. } if stage == "healthy"),
    );
    assert_ne!(pid_of(&sup, "healthy"), Some(healthy_pid));
    sup.shutdown(&[]);
    assert_eq!(sup.state(), SupervisorState::Stopped);
}

#[test]
fn a_killed_stage_is_restarted_after_the_hook() {
    let _g = serial();
    let mark = temp_path("hook-mark");
    let result = temp_path("hook-result");
    // Generation 1 reports whether the hook's mark existed when it started.
    let script = format!(
        "if [ \"$INSUWB_GENERATION\" = 1 ] && [ -e '{m}' ]; then echo ok > '{r}'; fi; exec sleep 30",
        m = mark.display(),
        r = result.display()
    );
    let mut sup = Supervisor::new(
        quiet_policy(),
        vec![sh("victim", &script), sleeper("bystander")],
    )
    .unwrap();
    let calls = Arc::new(Mutex::new(Vec::<String>::new()));
    let (calls2, mark2) = (Arc::clone(&calls), mark.clone());
    sup.set_before_restart(Box::new(move |stage| {
        calls2.lock().unwrap().push(stage.to_owned());
        std::fs::write(&mark2, stage).unwrap();
    }));
    sup.start(Instant::now()).unwrap();
    let victim = pid_of(&sup, "victim").unwrap();
    let bystander = pid_of(&sup, "bystander").unwrap();

    assert!(matches!(
        sup.kill_stage("nobody", libc::SIGKILL),
        Err(KillError::UnknownStage(n)) if n == "nobody"
    ));
    sup.kill_stage("victim", libc::SIGKILL).unwrap();
    let seen = run_until(&mut sup, Duration::from_secs(5), no_hook, |e| {
        matches!(e, Event::Restarted { .. })
    });
    let evs: Vec<&Event> = seen.iter().map(|(_, e)| e).collect();
    assert_eq!(
        evs,
        [
            &Event::Exited {
                stage: "victim".into(),
                pid: victim,
                status: ExitKind::Signal(libc::SIGKILL)
            },
            &Event::RestartScheduled {
                stage: "victim".into(),
                delay_ms: 50
            },
            &Event::Restarted {
                stage: "victim".into(),
                pid: pid_of(&sup, "victim").unwrap(),
                generation: 1
            },
        ]
    );
    assert_eq!(*calls.lock().unwrap(), ["victim"]);
    let new_victim = pid_of(&sup, "victim").unwrap();
    assert_ne!(new_victim, victim);
    assert!(process_gone(victim));
    assert_eq!(pid_of(&sup, "bystander"), Some(bystander));
    assert_eq!((sup.restarts("victim"), sup.restarts("bystander")), (1, 0));
    // The new generation saw the mark: the hook ran before it was spawned.
    let t0 = Instant::now();
    while read_lines(&result).is_empty() && t0.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(read_lines(&result), ["ok"]);

    sup.shutdown(&["victim", "bystander"]);
    assert!(process_gone(new_victim) && process_gone(bystander));
    assert!(matches!(
        sup.kill_stage("victim", libc::SIGKILL),
        Err(KillError::NotRunning(_))
    ));
    let _ = std::fs::remove_file(&mark);
    let _ = std::fs::remove_file(&result);
}

#[test]
fn a_stopped_stage_loses_its_heartbeat_and_is_killed_and_restarted() {
    let _g = serial();
    let policy = RestartPolicy {
        heartbeat_timeout_ms: 300,
        startup_grace_ms: 200,
        ..quiet_policy()
    };
    let mut sup = Supervisor::new(policy, vec![sleeper("healthy"), sleeper("frozen")]).unwrap();
    let t0 = Instant::now();
    sup.start(t0).unwrap();
    let frozen = pid_of(&sup, "frozen").unwrap();
    let healthy = pid_of(&sup, "healthy").unwrap();
    // A heartbeat carrying another pid (a dead generation's) is ignored.
    assert!(!sup.note_heartbeat_from("frozen", frozen.wrapping_add(1), t0));
    assert!(!sup.note_heartbeat("nobody", t0));

    let mut stopped_at: Option<Instant> = None;
    let mut last_frozen_beat = t0;
    let seen = run_until(
        &mut sup,
        Duration::from_secs(5),
        |sup, now| {
            assert!(sup.note_heartbeat_from("healthy", healthy, now));
            if stopped_at.is_none() {
                assert!(sup.note_heartbeat("frozen", now));
                last_frozen_beat = now;
                if now - t0 >= Duration::from_millis(300) {
                    sup.kill_stage("frozen", libc::SIGSTOP).unwrap();
                    stopped_at = Some(now);
                }
            }
        },
        |e| matches!(e, Event::Restarted { .. }),
    );
    let lost = seen
        .iter()
        .find_map(|(t, e)| match e {
            Event::HeartbeatLost { stage, silent_ms } => Some((*t, stage.clone(), *silent_ms)),
            _ => None,
        })
        .unwrap();
    assert_eq!(lost.1, "frozen");
    assert!(lost.2 >= 300, "silent {} ms", lost.2);
    assert!(lost.0 - last_frozen_beat >= Duration::from_millis(300));
    let evs: Vec<&Event> = seen.iter().map(|(_, e)| e).collect();
    assert_eq!(
        &evs[1..],
        [
            &Event::Exited {
                stage: "frozen".into(),
                pid: frozen,
                status: ExitKind::Signal(libc::SIGKILL)
            },
            &Event::RestartScheduled {
                stage: "frozen".into(),
                delay_ms: 50
            },
            &Event::Restarted {
                stage: "frozen".into(),
                pid: pid_of(&sup, "frozen").unwrap(),
                generation: 1
            },
        ]
    );
    assert!(process_gone(frozen));
    assert_eq!(pid_of(&sup, "healthy"), Some(healthy));
    assert_eq!(sup.restarts("healthy"), 0);
    sup.shutdown(&[]);
}

#[test]
fn the_watchdog_waits_for_the_startup_grace() {
    let _g = serial();
    let policy = RestartPolicy {
        heartbeat_timeout_ms: 300,
        startup_grace_ms: 600,
        ..quiet_policy()
    };
    let mut sup = Supervisor::new(policy, vec![sleeper("mute")]).unwrap();
    let t0 = Instant::now();
    sup.start(t0).unwrap();
    let seen = run_until(&mut sup, Duration::from_secs(5), no_hook, |e| {
        matches!(e, Event::HeartbeatLost { .. })
    });
    let (t, e) = seen.last().unwrap();
    // Never before startup_grace_ms + heartbeat_timeout_ms after the spawn.
    assert!(*t - t0 >= Duration::from_millis(900), "{:?}", *t - t0);
    assert!(matches!(e, Event::HeartbeatLost { silent_ms, .. } if *silent_ms >= 900));
    sup.shutdown(&[]);
}

#[test]
fn shutdown_kills_a_stage_that_ignores_sigterm_and_leaves_no_zombie() {
    let _g = serial();
    let gc_file = temp_path("grandchild");
    // The stubborn stage and its own child ignore SIGTERM.
    let script = format!(
        "trap '' TERM; sleep 30 & echo $! > '{}'; wait",
        gc_file.display()
    );
    let policy = RestartPolicy {
        grace_ms: 400,
        ..quiet_policy()
    };
    let mut sup =
        Supervisor::new(policy, vec![sleeper("polite"), sh("stubborn", &script)]).unwrap();
    sup.start(Instant::now()).unwrap();
    let polite = pid_of(&sup, "polite").unwrap();
    let stubborn = pid_of(&sup, "stubborn").unwrap();
    let t0 = Instant::now();
    while read_lines(&gc_file).is_empty() && t0.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let grandchild: u32 = read_lines(&gc_file)[0].parse().unwrap();
    assert!(!process_gone(grandchild));

    let t0 = Instant::now();
    let evs = sup.shutdown(&["stubborn", "polite"]);
    let took = t0.elapsed();
    assert!(took >= Duration::from_millis(400), "{took:?}");
    assert_eq!(
        evs,
        [
            Event::Exited {
                stage: "stubborn".into(),
                pid: stubborn,
                status: ExitKind::Signal(libc::SIGKILL)
            },
            Event::Stopped {
                stage: "stubborn".into()
            },
            Event::Exited {
                stage: "polite".into(),
                pid: polite,
                status: ExitKind::Signal(libc::SIGTERM)
            },
            Event::Stopped {
                stage: "polite".into()
            },
        ]
    );
    // Reaped: no /proc entry at all (a zombie would still have one).
    assert!(!Path::new(&format!("/proc/{stubborn}")).exists());
    assert!(!Path::new(&format!("/proc/{polite}")).exists());
    // The stage's own child went with its process group.
    assert!(wait_gone(grandchild, Duration::from_secs(2)));
    assert_eq!(sup.state(), SupervisorState::Stopped);
    assert!(sup.pids().iter().all(|(_, p)| p.is_none()));
    assert!(sup.poll(Instant::now()).is_empty());
    let _ = std::fs::remove_file(&gc_file);
}

#[test]
fn the_budget_window_slides_so_sparse_faults_never_exhaust_it() {
    let _g = serial();
    // Faults are >= 0.35 s apart (0.3 s run + 50 ms backoff), so any 0.5 s
    // window holds at most 2 of them: a budget of 2 per 0.5 s is never
    // exhausted, though it is exceeded in total (a fixed count would fail).
    let policy = RestartPolicy {
        backoff_initial_ms: 50,
        backoff_max_ms: 50,
        budget_restarts: 2,
        budget_window_s: 0.5,
        ..quiet_policy()
    };
    let mut sup = Supervisor::new(policy, vec![sh("flaky", "sleep 0.3; exit 1")]).unwrap();
    sup.start(Instant::now()).unwrap();
    let seen = run_until(&mut sup, Duration::from_secs(5), no_hook, |e| {
        matches!(e, Event::Restarted { generation: 4, .. })
    });
    assert!(seen
        .iter()
        .all(|(_, e)| !matches!(e, Event::BudgetExhausted { .. })));
    assert_eq!(sup.restarts("flaky"), 4);
    assert_eq!(sup.state(), SupervisorState::Running);
    sup.shutdown(&[]);
}

#[test]
fn stages_die_with_the_thread_that_spawned_them_when_asked() {
    let _g = serial();
    for die in [true, false] {
        let policy = RestartPolicy {
            die_with_launcher: die,
            ..quiet_policy()
        };
        // The spawning thread ends; the supervisor moves to this thread.
        let mut sup = std::thread::spawn(move || {
            let mut sup = Supervisor::new(policy, vec![sleeper("orphan")]).unwrap();
            sup.start(Instant::now()).unwrap();
            sup
        })
        .join()
        .unwrap();
        let pid = pid_of(&sup, "orphan").unwrap();
        if die {
            let seen = run_until(&mut sup, Duration::from_secs(3), no_hook, |e| {
                matches!(e, Event::Exited { .. })
            });
            assert!(seen.iter().any(|(_, e)| *e
                == Event::Exited {
                    stage: "orphan".into(),
                    pid,
                    status: ExitKind::Signal(libc::SIGKILL)
                }));
        } else {
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_millis(300) {
                assert!(sup.poll(Instant::now()).is_empty());
                std::thread::sleep(Duration::from_millis(10));
            }
            assert_eq!(pid_of(&sup, "orphan"), Some(pid));
        }
        sup.shutdown(&[]);
        assert!(process_gone(pid));
    }
}

#[test]
fn construction_and_start_errors() {
    let _g = serial();
    assert!(matches!(
        Supervisor::new(RestartPolicy::default(), vec![]),
        Err(LaunchError::NoStages)
    ));
    let e = Supervisor::new(
        RestartPolicy {
            backoff_initial_ms: 0,
            ..Default::default()
        },
        vec![sleeper("a")],
    )
    .unwrap_err();
    assert!(e.to_string().contains("launch.backoff_initial_ms"), "{e}");
    let e =
        Supervisor::new(RestartPolicy::default(), vec![sleeper("a"), sleeper("a")]).unwrap_err();
    assert!(e.to_string().contains("launch.stages[1].name"), "{e}");

    // A missing program fails start; the stage before it runs until shutdown.
    let mut sup = Supervisor::new(
        quiet_policy(),
        vec![
            sleeper("first"),
            StageSpec::new("missing", "/nonexistent/insuwb-stage", &[]),
        ],
    )
    .unwrap();
    let e = sup.start(Instant::now()).unwrap_err();
    assert!(
        matches!(&e, LaunchError::Spawn { stage, .. } if stage == "missing"),
        "{e}"
    );
    assert!(e.to_string().contains("/nonexistent/insuwb-stage"), "{e}");
    assert!(matches!(
        sup.start(Instant::now()),
        Err(LaunchError::AlreadyStarted { .. })
    ));
    let first = pid_of(&sup, "first").unwrap();
    sup.shutdown(&[]);
    assert!(process_gone(first));
}

#[test]
fn a_failed_restart_spawn_counts_against_the_budget() {
    let _g = serial();
    let dir = std::env::temp_dir().join(format!("insuwb-launch-{}-prog", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The program deletes itself: its restarts cannot spawn.
    let prog = dir.join("once.sh");
    std::fs::write(
        &prog,
        format!("#!/bin/sh\nrm -f '{}'\nexit 2\n", prog.display()),
    )
    .unwrap();
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&prog, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let policy = RestartPolicy {
        backoff_initial_ms: 10,
        backoff_max_ms: 20,
        budget_restarts: 2,
        budget_window_s: 10.0,
        ..quiet_policy()
    };
    let mut sup = Supervisor::new(policy, vec![StageSpec::new("once", &prog, &[])]).unwrap();
    sup.start(Instant::now()).unwrap();
    let seen = run_until(&mut sup, Duration::from_secs(5), no_hook, |e| {
        matches!(e, Event::BudgetExhausted { .. })
    });
    let failed = seen
        .iter()
        .filter(|(_, e)| matches!(e, Event::SpawnFailed { stage, .. } if stage == "once"))
        .count();
    assert_eq!(failed, 2);
    assert_eq!(sup.restarts("once"), 0);
    assert!(matches!(sup.state(), SupervisorState::Failed { stage } if stage == "once"));
    sup.shutdown(&[]);
    let _ = std::fs::remove_dir_all(&dir);
}
