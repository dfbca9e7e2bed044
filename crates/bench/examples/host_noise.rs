//! How much the machine itself disturbs a 10 Hz loop, with no insuwb code
//! running: read this before trusting a latency percentile.
//!
//! `cargo run --release -p insuwb-bench --example host_noise -- [SECONDS]`
//! (default 20):
//! 1. **Stolen CPU.** One thread pinned to each CPU in turn spins on the
//!    monotonic clock for SECONDS / CPUs; every gap between two readings
//!    longer than 300 us is time the CPU ran something else (a kernel thread,
//!    an interrupt, or, in a virtual machine, another guest). One CPU at a
//!    time: with every vCPU at 100 % a hypervisor's CPU quota throttles the
//!    guest and adds gaps of its own.
//! 2. **Timer wake-ups.** A thread sleeps to absolute deadlines 10 ms apart
//!    (clock_nanosleep, TIMER_ABSTIME) for SECONDS: how late each wake-up
//!    is, as a driver's; then pinned to each CPU in turn for SECONDS / CPUs
//!    (a timer interrupt comes to the CPU that armed it, so a CPU the host
//!    deschedules more often wakes its sleepers later).
//!
//! A gap of a few milliseconds that lands in the ~0.2 ms of a fix's path
//! makes one outlier of the 300 cycles `insuwb bench latency` measures per
//! graph; three of them set its p99 (BENCHMARKS.md, "How much the host
//! disturbs a loop").

// clock_nanosleep and sched_setaffinity have no safe wrapper in std.
#![allow(unsafe_code)]

use std::time::{Duration, Instant};

/// A gap this long counts as stolen time.
const GAP: Duration = Duration::from_micros(300);

fn pin_to(cpu: usize) -> bool {
    // SAFETY: a zeroed cpu_set_t is valid; CPU_SET writes inside it.
    unsafe {
        let mut set: libc::cpu_set_t = core::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, core::mem::size_of::<libc::cpu_set_t>(), &set) == 0
    }
}

fn spin(cpu: usize, d: Duration) -> Option<Vec<(f64, f64)>> {
    std::thread::spawn(move || {
        if !pin_to(cpu) {
            return None;
        }
        let t0 = Instant::now();
        let mut prev = t0;
        let mut gaps = Vec::new();
        loop {
            let t = Instant::now();
            let g = t - prev;
            if g > GAP {
                gaps.push(((t - t0).as_secs_f64(), g.as_secs_f64() * 1e3));
            }
            prev = t;
            if t - t0 > d {
                return Some(gaps);
            }
        }
    })
    .join()
    .ok()
    .flatten()
}

fn monotonic() -> libc::timespec {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is valid for the call.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts
}

fn ns(ts: &libc::timespec) -> i128 {
    i128::from(ts.tv_sec) * 1_000_000_000 + i128::from(ts.tv_nsec)
}

fn timer_lateness_us(d: Duration) -> Vec<f64> {
    let period: i128 = 10_000_000;
    let n = (d.as_nanos() as i128 / period).max(1);
    let start = ns(&monotonic()) + 100_000_000;
    let mut late = Vec::with_capacity(n as usize);
    for k in 0..n {
        let due = start + k * period;
        let ts = libc::timespec {
            tv_sec: (due / 1_000_000_000) as libc::time_t,
            tv_nsec: (due % 1_000_000_000) as libc::c_long,
        };
        // SAFETY: `ts` is valid for the call; an early return (signal) only
        // shows up as a negative lateness, clamped below.
        unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                core::ptr::null_mut(),
            )
        };
        late.push(((ns(&monotonic()) - due).max(0)) as f64 / 1e3);
    }
    late
}

fn pct(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 * p).ceil() as usize).clamp(1, sorted.len().max(1)) - 1;
    sorted.get(i).copied().unwrap_or(0.0)
}

fn main() {
    let secs: f64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .filter(|s: &f64| s.is_finite() && *s > 0.0)
        .unwrap_or(20.0);
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    println!("host_noise: {cpus} CPU(s), {secs} s");
    let per_cpu = Duration::from_secs_f64(secs / cpus as f64);
    for cpu in 0..cpus {
        let Some(gaps) = spin(cpu, per_cpu) else {
            println!("cpu{cpu}: could not pin a thread to it");
            continue;
        };
        let total = gaps.iter().fold(0.0, |a, g| a + g.1);
        let max = gaps.iter().map(|g| g.1).fold(0.0, f64::max);
        let over1 = gaps.iter().filter(|g| g.1 > 1.0).count();
        let rate = gaps.len() as f64 / per_cpu.as_secs_f64();
        println!(
            "cpu{cpu}: {} gaps > 0.3 ms in {:.1} s ({rate:.1}/s), {over1} > 1 ms, longest {max:.2} ms, \
             {total:.1} ms stolen ({:.3} %)",
            gaps.len(),
            per_cpu.as_secs_f64(),
            total / (per_cpu.as_secs_f64() * 1e3) * 100.0
        );
        let times: Vec<String> = gaps
            .iter()
            .filter(|g| g.1 > 1.0)
            .take(12)
            .map(|g| format!("{:.2}@{:.3}s", g.1, g.0))
            .collect();
        if !times.is_empty() {
            println!("  gaps > 1 ms (ms@s): {}", times.join(" "));
        }
    }
    // Timer wake-ups: unpinned (as the stages run), then pinned to each CPU
    // in turn (the timer interrupt comes to the CPU that armed it).
    let summary = |what: &str, mut late: Vec<f64>| {
        late.sort_by(f64::total_cmp);
        let over = late.iter().filter(|l| **l > 500.0).count();
        println!(
            "timer wake-ups every 10 ms, {what}: n = {}, late p50 {:.1} us, p99 {:.1} us, \
             p99.9 {:.1} us, max {:.1} us, {over} over 0.5 ms",
            late.len(),
            pct(&late, 0.5),
            pct(&late, 0.99),
            pct(&late, 0.999),
            late.last().copied().unwrap_or(0.0)
        );
    };
    summary("unpinned", timer_lateness_us(Duration::from_secs_f64(secs)));
    for cpu in 0..cpus {
        let late = std::thread::spawn(move || pin_to(cpu).then(|| timer_lateness_us(per_cpu)))
            .join()
            .ok()
            .flatten();
        match late {
            Some(late) => summary(&format!("pinned to cpu{cpu}"), late),
            None => println!("cpu{cpu}: could not pin a thread to it"),
        }
    }
}
