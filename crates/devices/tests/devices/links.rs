//! Links and emulators over real pseudo-terminals and loopback sockets:
//! bytes arrive intact and in order, the TCP link sends its commands before
//! the stream starts, unplugging is noticed and the link comes back within
//! 1 s of the device, backoff is capped, a read keeps to its timeout, and
//! reads in the steady state do not allocate.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use insuwb_devices::emulator::{
    Faults, Outage, Player, PtyEmulator, TcpEmulator, TcpEmulatorConfig,
};
use insuwb_devices::link::{Link, LinkSpec, LinkState, Read, ReconnectPolicy};
use insuwb_runtime::monotonic_ns;
use rand::{RngExt as _, SeedableRng as _};
use rand_xoshiro::Xoshiro256StarStar;

/// Tests here start threads, open ptys and sockets, and measure time: one at
/// a time.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn serialise() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner)
}

thread_local! {
    /// Allocations made by this thread while `COUNTING` is set.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

/// The system allocator, counting the allocations of threads that ask.
struct Counting;

fn count_one() {
    if COUNTING.try_with(Cell::get).unwrap_or(false) {
        let _ = ALLOCATIONS.try_with(|a| a.set(a.get() + 1));
    }
}

// SAFETY: every call is forwarded unchanged to the system allocator; the
// counting touches only const-initialised thread locals.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        // SAFETY: the caller's contract is passed through.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract is passed through.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        // SAFETY: the caller's contract is passed through.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// One read, with the allocations this thread made during it.
fn counted_read(link: &mut Link, buf: &mut [u8], timeout: Duration) -> (Read, u64) {
    let before = ALLOCATIONS.with(Cell::get);
    COUNTING.with(|c| c.set(true));
    let r = link.read(buf, timeout).unwrap();
    COUNTING.with(|c| c.set(false));
    (r, ALLOCATIONS.with(Cell::get) - before)
}

const ELIKO_HANDSHAKE: [&str; 2] = ["$PEKIO,EULA,ACCEPT\r\n", "$PEKIO,SET_REPORT_LIST,COORD\r\n"];

/// A fresh directory for symlinks, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "insuwb-links-{}-{tag}-{}",
            std::process::id(),
            monotonic_ns()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn serial_link(path: &std::path::Path, policy: ReconnectPolicy) -> Link {
    let spec: LinkSpec = format!("serial:{}", path.display()).parse().unwrap();
    Link::new(spec, 921_600, policy, Vec::new(), monotonic_ns).unwrap()
}

fn tcp_link(port: u16, on_connect: &[u8], policy: ReconnectPolicy) -> Link {
    let spec: LinkSpec = format!("tcp:127.0.0.1:{port}").parse().unwrap();
    Link::new(spec, 0, policy, on_connect.to_vec(), monotonic_ns).unwrap()
}

/// Reads until the link is connected (up to 5 s).
fn connect(link: &mut Link) {
    let mut buf = [0_u8; 64];
    let end = monotonic_ns() + 5_000_000_000;
    while monotonic_ns() < end {
        link.read(&mut buf, Duration::from_millis(20)).unwrap();
        if matches!(link.state(), LinkState::Connected { .. }) {
            return;
        }
    }
    panic!("link never connected: {:?}", link.stats());
}

/// Reads until `want` bytes came or 10 s passed; returns what came.
fn read_bytes(link: &mut Link, want: usize) -> Vec<u8> {
    let mut got = Vec::with_capacity(want);
    let mut buf = [0_u8; 4096];
    let end = monotonic_ns() + 10_000_000_000;
    while got.len() < want && monotonic_ns() < end {
        if let Read::Data { n, .. } = link.read(&mut buf, Duration::from_millis(50)).unwrap() {
            got.extend_from_slice(&buf[..n]);
        }
    }
    got
}

/// A byte pattern in which a lost, repeated or swapped byte shows.
fn pattern(len: usize, salt: u64) -> Vec<u8> {
    let mut rng = Xoshiro256StarStar::seed_from_u64(salt);
    (0..len).map(|_| rng.random::<u8>()).collect()
}

#[test]
fn pty_bytes_arrive_intact_and_in_order() {
    let _one = serialise();
    let mut pty = PtyEmulator::open().unwrap();
    // A slow reader makes the emulator wait rather than lose bytes here.
    pty.set_write_timeout(Duration::from_secs(5));
    let path = pty.driver_path().unwrap().to_owned();
    let mut link = serial_link(&path, ReconnectPolicy::default());
    connect(&mut link);

    // 200 chunks of 1..=700 bytes, one every 500 us: 70 KB in 0.1 s.
    let data = pattern(70_000, 1);
    let mut chunks = Vec::new();
    let mut at = 0_usize;
    let mut k = 0_u64;
    while at < data.len() {
        let len = (1 + (k * 7919) % 700) as usize;
        let end = (at + len).min(data.len());
        chunks.push((k * 500_000, data[at..end].to_vec()));
        at = end;
        k += 1;
    }
    let player = Player::start(pty, chunks, monotonic_ns(), monotonic_ns, Faults::none()).unwrap();
    let got = read_bytes(&mut link, data.len());
    let (pty, report) = player.join().unwrap();

    assert_eq!(report.bytes_delivered, data.len() as u64, "{report:?}");
    assert_eq!(pty.stats().bytes_dropped, 0);
    assert_eq!(got.len(), data.len());
    assert!(got == data, "bytes changed or reordered on the way");
    assert_eq!(link.stats().bytes_read, data.len() as u64);
    assert_eq!(link.stats().connects, 1);

    // The reader side closes and opens again (a driver restart): the
    // device keeps working for the new reader.
    drop(link);
    let mut pty = pty;
    let mut link = serial_link(&path, ReconnectPolicy::default());
    connect(&mut link);
    let again = pattern(1000, 2);
    assert_eq!(pty.write(&again), again.len());
    assert_eq!(read_bytes(&mut link, again.len()), again);
}

/// An Eliko-like server that wants the handshake, and a link that sends it,
/// connected and streaming.
fn eliko_server_and_client() -> (TcpEmulator, Link, Vec<u8>) {
    let emulator = TcpEmulator::start(TcpEmulatorConfig {
        expect_lines: ELIKO_HANDSHAKE.iter().map(|s| (*s).to_owned()).collect(),
        ..TcpEmulatorConfig::default()
    })
    .unwrap();
    let on_connect: Vec<u8> = ELIKO_HANDSHAKE.concat().into_bytes();
    let mut link = tcp_link(emulator.port(), &on_connect, ReconnectPolicy::default());
    connect(&mut link);
    assert!(emulator.wait_for_client(Duration::from_secs(5)));
    (emulator, link, on_connect)
}

#[test]
fn tcp_link_sends_commands_then_gets_the_stream() {
    let _one = serialise();
    let (emulator, mut link, on_connect) = eliko_server_and_client();
    assert_eq!(
        emulator.received_lines(),
        ["$PEKIO,EULA,ACCEPT", "$PEKIO,SET_REPORT_LIST,COORD"]
    );
    assert_eq!(link.stats().bytes_written, on_connect.len() as u64);

    let mut stream = Vec::new();
    for seq in 0..500 {
        let line = format!(
            "$PEKIO,COORD,{},0x001A2B,1.50,-2.25,0.80,,1700000000.25\r\n",
            seq % 256
        );
        assert_eq!(emulator.write(line.as_bytes()), line.len());
        stream.extend_from_slice(line.as_bytes());
    }
    assert_eq!(read_bytes(&mut link, stream.len()), stream);
    assert_eq!(emulator.stats().clients, 1);

    // A client that sends the wrong commands gets no stream.
    let mut wrong = tcp_link(emulator.port(), b"HELLO\r\n", ReconnectPolicy::default());
    let mut buf = [0_u8; 64];
    let end = monotonic_ns() + 5_000_000_000;
    while (emulator.stats().handshake_failures == 0 || wrong.stats().disconnects == 0)
        && monotonic_ns() < end
    {
        let _ = wrong.read(&mut buf, Duration::from_millis(20)).unwrap();
    }
    // The server closed it: the wrong link saw the end of the stream.
    assert!(emulator.stats().handshake_failures >= 1);
    assert!(wrong.stats().connects >= 1 && wrong.stats().disconnects >= 1);
    assert_eq!(wrong.stats().bytes_read, 0);
    assert_eq!(
        emulator.stats().clients,
        1,
        "the wrong client got the stream"
    );
    assert!(emulator.received_lines().iter().any(|l| l == "HELLO"));
}

/// Reads with a short timeout until the link is connected again; returns
/// the time it became connected (None after `wait_ns`).
fn wait_connected(link: &mut Link, wait_ns: u64) -> Option<u64> {
    let mut buf = [0_u8; 256];
    let end = monotonic_ns() + wait_ns;
    while monotonic_ns() < end {
        link.read(&mut buf, Duration::from_millis(10)).unwrap();
        if let LinkState::Connected { since_ns } = link.state() {
            return Some(since_ns);
        }
    }
    None
}

#[test]
fn pty_unplug_is_noticed_and_the_link_is_back_within_1s() {
    let _one = serialise();
    let dir = TempDir::new("unplug");
    let mut pty = PtyEmulator::open_with_link(&dir.0, "imu").unwrap();
    let stable = pty.stable_path().unwrap().to_owned();
    let first_slave = pty.slave_path().unwrap().to_owned();
    assert_eq!(std::fs::read_link(&stable).unwrap(), first_slave);
    let policy = ReconnectPolicy {
        initial_backoff: Duration::from_millis(50),
        max_backoff: Duration::from_millis(500),
        ..ReconnectPolicy::default()
    };
    let mut link = serial_link(&stable, policy);
    connect(&mut link);
    assert_eq!(pty.write(b"before"), 6);
    assert_eq!(read_bytes(&mut link, 6), b"before");

    let mut buf = [0_u8; 64];
    for round in 0..3 {
        // Unplug: the next read reports the device down.
        let unplugged = monotonic_ns();
        pty.disconnect();
        assert!(!stable.exists(), "the symlink outlived the device");
        let down = link.read(&mut buf, Duration::from_secs(1)).unwrap();
        assert!(matches!(down, Read::Down { .. }), "{down:?}");
        let noticed_ms = (monotonic_ns() - unplugged) as f64 / 1e6;

        // Away long enough for the backoff to reach its cap.
        let away_until = monotonic_ns() + 2_000_000_000;
        while monotonic_ns() < away_until {
            let r = link.read(&mut buf, Duration::from_millis(50)).unwrap();
            assert!(matches!(r, Read::Down { .. }), "{r:?}");
        }
        let LinkState::Disconnected { attempts, .. } = link.state() else {
            panic!("connected to an unplugged device");
        };
        assert!(attempts >= 3, "{attempts} attempts while away");

        pty.reconnect().unwrap();
        let back = monotonic_ns();
        assert_eq!(
            std::fs::read_link(&stable).unwrap(),
            pty.slave_path().unwrap()
        );
        let connected = wait_connected(&mut link, 5_000_000_000).expect("never reconnected");
        let reconnect_ms = connected.saturating_sub(back) as f64 / 1e6;
        println!(
            "round {round}: unplug noticed in {noticed_ms:.3} ms, {attempts} failed attempts, \
             reconnected {reconnect_ms:.1} ms after the device returned"
        );
        assert!(
            connected <= back + 1_000_000_000,
            "reconnected {reconnect_ms} ms after the device returned"
        );
        // Bytes flow through the new pseudo-terminal.
        let msg = format!("after {round}");
        assert_eq!(pty.write(msg.as_bytes()), msg.len());
        assert_eq!(read_bytes(&mut link, msg.len()), msg.as_bytes());
    }
    assert_eq!(link.stats().connects, 4);
    assert_eq!(link.stats().disconnects, 3);
    assert_eq!(pty.stats().unplugs, 3);
    drop(pty);
    assert!(!stable.exists(), "the symlink outlived the emulator");
}

#[test]
fn tcp_disconnects_and_refusals_are_survived() {
    let _one = serialise();
    let (emulator, mut link, _) = eliko_server_and_client();

    // The server drops the client: EOF, down, and back at once (the port
    // still listens), with the commands sent again.
    emulator.disconnect();
    let mut buf = [0_u8; 64];
    let r = link.read(&mut buf, Duration::from_secs(1)).unwrap();
    assert!(matches!(r, Read::Down { .. }), "{r:?}");
    assert!(wait_connected(&mut link, 5_000_000_000).is_some());
    assert!(emulator.wait_for_client(Duration::from_secs(5)));
    assert_eq!(emulator.received_lines().len(), 4);
    assert_eq!(emulator.write(b"x\n"), 2);
    assert_eq!(read_bytes(&mut link, 2), b"x\n");

    // The server goes away for 1.5 s: connections are refused, the link
    // keeps trying, and is back once the server is.
    let refused_at = monotonic_ns();
    emulator.disconnect_for(Duration::from_millis(1500));
    let back = refused_at + 1_500_000_000;
    let failures_before = link.stats().connect_failures;
    let connected = wait_connected(&mut link, 10_000_000_000).expect("never reconnected");
    let failures = link.stats().connect_failures - failures_before;
    println!(
        "tcp: {failures} refused attempts, reconnected {:.1} ms after the server returned",
        connected.saturating_sub(back) as f64 / 1e6
    );
    assert!(failures >= 2, "{failures} failed attempts while refused");
    assert!(connected >= back, "connected while the port was closed");
    // How soon it is back is printed, not asserted: on a busy machine the
    // retry runs late (the watchdog above bounds it at 10 s).
    assert!(link
        .stats()
        .last_error
        .as_deref()
        .is_some_and(|e| e.contains("refused")));
    assert!(emulator.wait_for_client(Duration::from_secs(5)));
    assert_eq!(emulator.write(b"y\n"), 2);
    assert_eq!(read_bytes(&mut link, 2), b"y\n");
}

#[test]
fn backoff_grows_to_its_cap_and_stays_there() {
    let _one = serialise();
    let dir = TempDir::new("backoff");
    let policy = ReconnectPolicy {
        initial_backoff: Duration::from_millis(10),
        max_backoff: Duration::from_millis(80),
        ..ReconnectPolicy::default()
    };
    let mut link = serial_link(&dir.0.join("absent"), policy);
    let mut buf = [0_u8; 16];
    let mut longest = Duration::ZERO;
    let start = monotonic_ns();
    while monotonic_ns() < start + 3_000_000_000 {
        match link.read(&mut buf, Duration::from_millis(50)).unwrap() {
            Read::Down { retry_in } => longest = longest.max(retry_in),
            other => panic!("{other:?} from a missing device"),
        }
    }
    let failures = link.stats().connect_failures;
    println!("3 s missing: {failures} attempts, longest wait {longest:?}");
    // Capped at 80 ms: about 37 attempts in 3 s (uncapped doubling: 8;
    // no backoff: 300).
    assert!(longest <= Duration::from_millis(80), "{longest:?}");
    assert!(longest >= Duration::from_millis(40), "{longest:?}");
    assert!((16..=100).contains(&failures), "{failures}");
    let LinkState::Disconnected { attempts, .. } = link.state() else {
        panic!("connected to a missing device");
    };
    assert_eq!(u64::from(attempts), failures);
    assert!(link
        .stats()
        .last_error
        .as_deref()
        .is_some_and(|e| e.contains("absent")));
}

#[test]
fn reads_keep_to_their_timeout() {
    let _one = serialise();
    let timeout = Duration::from_millis(50);
    let timeout_ns = 50_000_000_u64;
    let mut buf = [0_u8; 64];

    // Each case: 20 reads; none may take 10x the timeout, and a link that
    // is up without data or down must not spin (the 20 take >= 0.5 s).
    let mut check = |name: &str, link: &mut Link, expect_down: bool| {
        let start = monotonic_ns();
        let mut longest = 0_u64;
        for _ in 0..20 {
            let t0 = monotonic_ns();
            let r = link.read(&mut buf, timeout).unwrap();
            longest = longest.max(monotonic_ns() - t0);
            if expect_down {
                assert!(matches!(r, Read::Down { .. }), "{name}: {r:?}");
            } else {
                assert_eq!(r, Read::Timeout, "{name}");
            }
        }
        let total = monotonic_ns() - start;
        println!(
            "{name}: longest read {:.2} ms of 50, 20 reads in {:.1} ms",
            longest as f64 / 1e6,
            total as f64 / 1e6
        );
        assert!(longest < 10 * timeout_ns, "{name}: {longest} ns");
        assert!(total >= 20 * timeout_ns / 2, "{name}: spins, {total} ns");
    };

    let pty = PtyEmulator::open().unwrap();
    let mut serial_up = serial_link(pty.driver_path().unwrap(), ReconnectPolicy::default());
    connect(&mut serial_up);
    check("serial up, silent", &mut serial_up, false);

    let dir = TempDir::new("timeout");
    let mut serial_down = serial_link(&dir.0.join("absent"), ReconnectPolicy::default());
    check("serial down", &mut serial_down, true);

    let emulator = TcpEmulator::start(TcpEmulatorConfig::default()).unwrap();
    let mut tcp_up = tcp_link(emulator.port(), b"", ReconnectPolicy::default());
    connect(&mut tcp_up);
    check("tcp up, silent", &mut tcp_up, false);

    // A port nobody listens on: refused at once, then backoff.
    let port = emulator.port();
    drop(emulator);
    let mut tcp_down = tcp_link(port, b"", ReconnectPolicy::default());
    check("tcp down", &mut tcp_down, true);
}

#[test]
fn player_faults_are_seeded_and_counted() {
    let _one = serialise();
    let dir = TempDir::new("player");
    let faults = Faults {
        seed: 7,
        garbage_prob: 0.2,
        garbage_max_len: 5,
        drop_prob: 0.1,
        drop_max_len: 3,
        outage: Some(Outage {
            every: Duration::from_millis(400),
            length: Duration::from_millis(100),
        }),
    };
    // 1 s of 100-byte chunks every 2 ms.
    let chunks: Vec<(u64, Vec<u8>)> = (0..500_u64)
        .map(|k| (k * 2_000_000, pattern(100, k)))
        .collect();
    let mut reports = Vec::new();
    for _ in 0..2 {
        let mut pty = PtyEmulator::open_with_link(&dir.0, "dev").unwrap();
        pty.set_write_timeout(Duration::from_secs(5));
        let stable = pty.stable_path().unwrap().to_owned();
        let mut link = serial_link(
            &stable,
            ReconnectPolicy {
                initial_backoff: Duration::from_millis(5),
                max_backoff: Duration::from_millis(20),
                ..ReconnectPolicy::default()
            },
        );
        connect(&mut link);
        let player =
            Player::start(pty, chunks.clone(), monotonic_ns(), monotonic_ns, faults).unwrap();
        let mut buf = [0_u8; 4096];
        while !player.is_finished() {
            let _ = link.read(&mut buf, Duration::from_millis(5)).unwrap();
        }
        let (_pty, report) = player.join().unwrap();
        // Drain what is left.
        while let Read::Data { .. } = link.read(&mut buf, Duration::from_millis(50)).unwrap() {}
        println!(
            "player: {report:?}; link read {} bytes over {} connections; late by up to {:.2} ms",
            link.stats().bytes_read,
            link.stats().connects,
            report.max_late_ns as f64 / 1e6
        );
        // Outages at 0.4 and 0.8 s, 100 ms each: the chunks due in
        // [400, 500) and [800, 900) ms are lost, 50 each.
        assert_eq!(report.outages, 2);
        assert_eq!(report.chunks_lost_in_outage, 100, "{report:?}");
        assert_eq!(report.chunks_played + report.chunks_lost_in_outage, 500);
        assert!(
            report.garbage_bursts > 0 && report.drop_events > 0,
            "{report:?}"
        );
        assert_eq!(
            report.bytes_offered,
            report.chunks_played * 100 + report.garbage_bytes - report.bytes_dropped
        );
        assert_eq!(link.stats().connects, 3, "{:?}", link.stats());
        // What the link read is what the device got out.
        assert!(link.stats().bytes_read <= report.bytes_delivered);
        assert!(link.stats().bytes_read > report.bytes_delivered / 2);
        assert!(report.replug_errors.is_none());
        reports.push(report);
    }
    // Same seed, same faults.
    let (a, b) = (&reports[0], &reports[1]);
    assert_eq!(
        (
            a.garbage_bursts,
            a.garbage_bytes,
            a.drop_events,
            a.bytes_dropped,
            a.bytes_offered
        ),
        (
            b.garbage_bursts,
            b.garbage_bytes,
            b.drop_events,
            b.bytes_dropped,
            b.bytes_offered
        )
    );
}

#[test]
fn reads_that_bring_data_do_not_allocate() {
    let _one = serialise();
    let mut buf = [0_u8; 256];

    // Serial: 8 KB waiting in the pty, read 256 bytes at a time.
    let mut pty = PtyEmulator::open().unwrap();
    let mut serial = serial_link(pty.driver_path().unwrap(), ReconnectPolicy::default());
    connect(&mut serial);
    let data = pattern(8192, 3);
    assert_eq!(pty.write(&data), data.len());
    let (mut got, mut data_reads, mut allocations) = (0, 0, 0);
    while got < data.len() {
        let (r, a) = counted_read(&mut serial, &mut buf, Duration::from_secs(1));
        let Read::Data { n, .. } = r else {
            panic!("{r:?} with bytes waiting");
        };
        got += n;
        data_reads += 1;
        allocations += a;
    }
    for _ in 0..5 {
        let (r, a) = counted_read(&mut serial, &mut buf, Duration::from_millis(5));
        assert_eq!(r, Read::Timeout);
        allocations += a;
    }
    println!("serial: {data_reads} reads with data and 5 timed out, {allocations} allocations");
    assert_eq!(allocations, 0);

    // TCP: 64 KB in the socket buffers, and reads that time out.
    let emulator = TcpEmulator::start(TcpEmulatorConfig::default()).unwrap();
    let mut tcp = tcp_link(emulator.port(), b"", ReconnectPolicy::default());
    connect(&mut tcp);
    assert!(emulator.wait_for_client(Duration::from_secs(5)));
    let data = pattern(65_536, 4);
    assert_eq!(emulator.write(&data), data.len());
    let (mut got, mut reads, mut allocations) = (0, 0, 0);
    while got < data.len() {
        let (r, a) = counted_read(&mut tcp, &mut buf, Duration::from_secs(1));
        if let Read::Data { n, .. } = r {
            got += n;
        }
        reads += 1;
        allocations += a;
    }
    for _ in 0..5 {
        let (r, a) = counted_read(&mut tcp, &mut buf, Duration::from_secs(1) / 100);
        assert_eq!(r, Read::Timeout);
        reads += 1;
        allocations += a;
    }
    println!("tcp: {reads} reads (5 timed out), {allocations} allocations");
    assert_eq!(allocations, 0);
}
