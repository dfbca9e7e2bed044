//! CPU time and resources of processes, read from Linux `/proc`.
//!
//! [`cpu_time_ns`] sums the scheduler's run time of every thread of a process
//! (`/proc/PID/task/TID/schedstat`, nanoseconds, exact) and falls back to
//! `utime + stime` of `/proc/PID/stat` (clock ticks of 10 ms, the kernel's
//! fixed `USER_HZ` of 100) where schedstat is missing. The percentage of one
//! core a process used over a window is the difference of two readings over
//! the wall time between them ([`percent_of_core`]). [`of_process`] reads
//! a process's resident memory and open file descriptors, what a leak
//! grows over hours.

use std::path::Path;

/// Nanoseconds per clock tick of `/proc/PID/stat` (`USER_HZ` = 100 on Linux).
pub const NS_PER_TICK: u64 = 10_000_000;

/// Why the CPU time of a process could not be read.
#[derive(Debug, thiserror::Error)]
pub enum CpuError {
    /// `/proc/PID/stat` could not be read (the process is gone).
    #[error("cannot read /proc/{pid}/stat: {error}")]
    Read {
        /// The process.
        pid: u32,
        /// The I/O error.
        error: std::io::Error,
    },
    /// `/proc/PID/stat` has an unexpected layout.
    #[error("/proc/{pid}/stat: unexpected content {text:?}")]
    Parse {
        /// The process.
        pid: u32,
        /// The start of the content.
        text: String,
    },
}

/// The fields of `/proc/PID/stat` this module uses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProcStat {
    /// Command name (`comm`, at most 15 bytes).
    pub comm: String,
    /// Parent process id.
    pub ppid: u32,
    /// User time, clock ticks.
    pub utime_ticks: u64,
    /// System time, clock ticks.
    pub stime_ticks: u64,
}

/// Parses the content of `/proc/PID/stat`: `pid (comm) state ppid ...`,
/// `utime` and `stime` being fields 14 and 15. The command name may hold
/// spaces and parentheses: it ends at the last `)`.
#[must_use]
pub fn parse_stat(text: &str) -> Option<ProcStat> {
    let open = text.find('(')?;
    let close = text.rfind(')')?;
    let comm = text.get(open + 1..close)?.to_owned();
    // Fields from 3 (state) on.
    let rest: Vec<&str> = text.get(close + 1..)?.split_ascii_whitespace().collect();
    let field = |n: usize| rest.get(n - 3).copied();
    Some(ProcStat {
        comm,
        ppid: field(4)?.parse().ok()?,
        utime_ticks: field(14)?.parse().ok()?,
        stime_ticks: field(15)?.parse().ok()?,
    })
}

/// Reads `/proc/PID/stat`.
pub fn stat(pid: u32) -> Result<ProcStat, CpuError> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .map_err(|source| CpuError::Read { pid, error: source })?;
    parse_stat(&text).ok_or_else(|| CpuError::Parse {
        pid,
        text: text.chars().take(80).collect(),
    })
}

/// Sum of the first field (run time, ns) of `task/*/schedstat` under `proc_dir`.
fn schedstat_sum(proc_dir: &Path) -> Option<u64> {
    let mut sum = 0u64;
    let mut any = false;
    for e in std::fs::read_dir(proc_dir.join("task")).ok()? {
        let Ok(e) = e else { continue };
        // A thread may end between listing and reading: skip it.
        let Ok(text) = std::fs::read_to_string(e.path().join("schedstat")) else {
            continue;
        };
        let ns: u64 = text.split_ascii_whitespace().next()?.parse().ok()?;
        sum = sum.saturating_add(ns);
        any = true;
    }
    any.then_some(sum)
}

/// CPU time used so far by process `pid` (all its live threads), ns.
pub fn cpu_time_ns(pid: u32) -> Result<u64, CpuError> {
    let s = stat(pid)?;
    if let Some(ns) = schedstat_sum(Path::new(&format!("/proc/{pid}"))) {
        return Ok(ns);
    }
    Ok((s.utime_ticks + s.stime_ticks).saturating_mul(NS_PER_TICK))
}

/// The processes whose parent is `parent`: `(pid, comm)`, in pid order.
#[must_use]
pub fn children(parent: u32) -> Vec<(u32, String)> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    let mut out: Vec<(u32, String)> = dir
        .filter_map(Result::ok)
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter_map(|pid| {
            let s = stat(pid).ok()?;
            (s.ppid == parent).then_some((pid, s.comm))
        })
        .collect();
    out.sort_unstable();
    out
}

/// Percentage of one core: `cpu_ns` of CPU time over `wall_ns` of wall
/// time, times 100 (0 for an empty window).
#[must_use]
pub fn percent_of_core(cpu_ns: u64, wall_ns: u64) -> f64 {
    if wall_ns == 0 {
        return 0.0;
    }
    cpu_ns as f64 / wall_ns as f64 * 100.0
}

/// The warm-up of a run of `duration_s` seconds before which a long run's
/// growth is not judged: a fifth of it, at most 5 minutes (`insuwb soak`,
/// `insuwb bench fleet --every`).
#[must_use]
pub fn warm_up_s(duration_s: f64) -> f64 {
    (duration_s / 5.0).min(300.0)
}

/// One process's resources at one time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct ProcessResources {
    /// Its pid.
    pub pid: u32,
    /// Resident set size (`VmRSS`), KiB: the shared-memory pages the
    /// process has touched included.
    pub rss_kib: u64,
    /// Its anonymous part (`RssAnon`: heap and stacks), KiB: what a leak
    /// grows.
    pub rss_anon_kib: u64,
    /// Open file descriptors (entries of `/proc/PID/fd`).
    pub fds: u64,
}

/// The resources of process `pid`, or `None` when it is gone (or `/proc`
/// cannot be read).
pub fn of_process(pid: u32) -> Option<ProcessResources> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kib = |key: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(key))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse::<u64>().ok())
    };
    let rss_kib = kib("VmRSS:")?;
    let rss_anon_kib = kib("RssAnon:")?;
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .ok()?
        .filter_map(Result::ok)
        .count() as u64;
    Some(ProcessResources {
        pid,
        rss_kib,
        rss_anon_kib,
        fds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_stat_with_odd_command_names() {
        // Fields: pid (comm) state ppid pgrp session tty tpgid flags minflt
        // cminflt majflt cmajflt utime stime ...
        let t = "4242 (my (odd) prog) S 17 4242 4242 0 -1 4194560 100 0 0 0 250 31 0 0 20 0 1 0";
        let s = parse_stat(t).unwrap();
        assert_eq!(s.comm, "my (odd) prog");
        assert_eq!((s.ppid, s.utime_ticks, s.stime_ticks), (17, 250, 31));
        assert!(parse_stat("12 (x) S").is_none());
        assert!(parse_stat("garbage").is_none());
    }

    #[test]
    fn percent_of_core_is_a_ratio() {
        assert_eq!(percent_of_core(5_000_000, 1_000_000_000), 0.5);
        assert_eq!(percent_of_core(1, 0), 0.0);
    }

    #[test]
    fn own_cpu_time_grows_by_at_least_the_work_done() {
        let me = std::process::id();
        let before = cpu_time_ns(me).unwrap();
        // Spin for 200 ms of wall time on this thread: at least most of it is
        // CPU time (the lower bound leaves room for preemption on a busy machine).
        let t = std::time::Instant::now();
        let mut x = 0u64;
        while t.elapsed() < std::time::Duration::from_millis(200) {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let after = cpu_time_ns(me).unwrap();
        assert!(after > before, "{before} -> {after}");
        assert!(after - before >= 20_000_000, "{before} -> {after}");
        assert_eq!(stat(me).unwrap().ppid, std::os::unix::process::parent_id());
    }

    #[test]
    fn children_lists_a_spawned_child_and_a_gone_process_is_an_error() {
        let mut child = std::process::Command::new("sleep")
            .arg("5")
            .spawn()
            .unwrap();
        let kids = children(std::process::id());
        let pid = child.id();
        child.kill().unwrap();
        child.wait().unwrap();
        assert!(
            kids.iter().any(|(p, c)| *p == pid && c == "sleep"),
            "{kids:?}"
        );
        let e = cpu_time_ns(pid).unwrap_err().to_string();
        assert!(e.contains(&format!("/proc/{pid}/stat")), "{e}");
    }
}
