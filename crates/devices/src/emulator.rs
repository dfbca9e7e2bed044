//! Device emulators at the byte level, for users without the hardware and
//! for tests: a serial device on a pseudo-terminal ([`PtyEmulator`]), a TCP
//! positioning server on loopback ([`TcpEmulator`]), and a [`Player`] that
//! writes timed byte chunks to either, with seeded faults (garbage, dropped
//! bytes, unplugging).
//!
//! ```no_run
//! use std::path::Path;
//! use insuwb_devices::emulator::{Faults, Player, PtyEmulator};
//!
//! # fn clock() -> u64 { 0 }
//! // A driver configured with serial:/tmp/devs/imu keeps working across
//! // unplug/replug, as with udev's /dev/serial/by-id links.
//! let pty = PtyEmulator::open_with_link(Path::new("/tmp/devs"), "imu")?;
//! let chunks: Vec<(u64, Vec<u8>)> = (0..200).map(|k| (k * 5_000_000, vec![0x55, 0x51])).collect();
//! let player = Player::start(pty, chunks, clock(), clock, Faults::none())?;
//! let (_pty, report) = player.join()?;
//! println!("{report:?}");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! A device does not wait for its reader: bytes written while nobody has
//! the port open, while the port is unplugged, or while the reader lets the
//! kernel buffer fill, are lost and counted, as a UART would lose them.
//!
//! The faults are drawn from `rand_xoshiro`'s xoshiro256** generator seeded
//! with [`Faults::seed`] (`SeedableRng::seed_from_u64`), with `rand`'s
//! uniform distributions.

use std::io::{self, Read as _, Write as _};
use std::net::{Ipv4Addr, Shutdown, TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use rand::{RngExt as _, SeedableRng as _};
use rand_xoshiro::Xoshiro256StarStar;
use serialport::{SerialPort, TTYPort};

/// Why a pseudo-terminal emulator could not be opened or plugged back.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PtyError {
    /// The pseudo-terminal pair could not be created.
    #[error("PtyError::Create: cannot create a pseudo-terminal: {0}")]
    Create(String),
    /// The link name is empty or has a `/`.
    #[error("PtyError::BadLinkName: {0:?} is not a plain file name")]
    BadLinkName(String),
    /// Something that is not a symlink already has the link's path.
    #[error("PtyError::LinkPathTaken: {0} exists and is not a symlink")]
    LinkPathTaken(PathBuf),
    /// Creating or re-pointing the symlink failed.
    #[error("PtyError::Link: cannot point {path} at the pseudo-terminal: {error}")]
    Link {
        /// The symlink's path.
        path: PathBuf,
        /// The OS error.
        error: String,
    },
}

/// Counters of a [`PtyEmulator`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PtyStats {
    /// Bytes the driver side could read.
    pub bytes_written: u64,
    /// Bytes lost: unplugged, no reader, or the reader too slow.
    pub bytes_dropped: u64,
    /// Times [`PtyEmulator::disconnect`] unplugged the device.
    pub unplugs: u64,
    /// Times [`PtyEmulator::reconnect`] plugged it back.
    pub replugs: u64,
}

/// A serial device on a pseudo-terminal. The driver opens
/// [`driver_path`](Self::driver_path) as `serial:<path>` (any baud rate).
///
/// [`disconnect`](Self::disconnect) closes the pseudo-terminal, as pulling
/// the USB cable would: the driver's reads fail and the slave path
/// vanishes. [`reconnect`](Self::reconnect) creates a new pair, whose slave
/// has a new path; with [`open_with_link`](Self::open_with_link) a symlink
/// of a fixed name is re-pointed at the new slave (what udev's
/// `/dev/serial/by-id` links do), so a driver configured with the symlink
/// finds the device again.
#[derive(Debug)]
pub struct PtyEmulator {
    master: Option<TTYPort>,
    slave_path: Option<PathBuf>,
    stable_link: Option<PathBuf>,
    write_timeout: Duration,
    stats: PtyStats,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

fn create_pair() -> Result<(TTYPort, PathBuf), PtyError> {
    let (master, slave) = TTYPort::pair().map_err(|e| PtyError::Create(e.to_string()))?;
    let path = slave
        .name()
        .map(PathBuf::from)
        .ok_or_else(|| PtyError::Create("the slave has no path".to_owned()))?;
    // The emulator does not keep the slave open: like a real port, the
    // device is only read while a driver has it open.
    drop(slave);
    // Writes must never block the emulator: a full buffer loses bytes.
    nix::fcntl::fcntl(
        master.as_raw_fd(),
        nix::fcntl::FcntlArg::F_SETFL(nix::fcntl::OFlag::O_NONBLOCK),
    )
    .map_err(|e| PtyError::Create(format!("setting O_NONBLOCK: {e}")))?;
    // Not inherited by the processes the emulator's owner starts (the
    // group it feeds): a copy of the master held open there would keep the
    // device plugged in after `disconnect`.
    nix::fcntl::fcntl(
        master.as_raw_fd(),
        nix::fcntl::FcntlArg::F_SETFD(nix::fcntl::FdFlag::FD_CLOEXEC),
    )
    .map_err(|e| PtyError::Create(format!("setting FD_CLOEXEC: {e}")))?;
    Ok((master, path))
}

/// Points `link` at `target`, replacing any symlink there atomically.
fn point_link(link: &Path, target: &Path) -> Result<(), PtyError> {
    let link_err = |e: io::Error| PtyError::Link {
        path: link.to_owned(),
        error: e.to_string(),
    };
    let mut tmp_name = link.file_name().unwrap_or_default().to_owned();
    tmp_name.push(format!(".{}.tmp", std::process::id()));
    let tmp = link.with_file_name(tmp_name);
    match std::fs::remove_file(&tmp) {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => return Err(link_err(e)),
    }
    std::os::unix::fs::symlink(target, &tmp).map_err(link_err)?;
    std::fs::rename(&tmp, link).map_err(link_err)
}

impl PtyEmulator {
    /// A device on a new pseudo-terminal, without a stable path.
    ///
    /// # Errors
    /// [`PtyError::Create`] when no pseudo-terminal can be made.
    pub fn open() -> Result<Self, PtyError> {
        let (master, slave_path) = create_pair()?;
        Ok(Self {
            master: Some(master),
            slave_path: Some(slave_path),
            stable_link: None,
            write_timeout: Duration::from_millis(50),
            stats: PtyStats::default(),
        })
    }

    /// A device on a new pseudo-terminal with a symlink `dir/name` that
    /// follows it across [`reconnect`](Self::reconnect)s. The symlink is
    /// removed while unplugged and when the emulator is dropped.
    ///
    /// # Errors
    /// [`PtyError::BadLinkName`] for a name that is not a plain file name,
    /// [`PtyError::LinkPathTaken`] when `dir/name` is a file or directory,
    /// [`PtyError::Link`] when the symlink cannot be made, and
    /// [`PtyError::Create`].
    pub fn open_with_link(dir: &Path, name: &str) -> Result<Self, PtyError> {
        if name.is_empty() || name.contains('/') || name == "." || name == ".." {
            return Err(PtyError::BadLinkName(name.to_owned()));
        }
        let link = dir.join(name);
        if let Ok(meta) = std::fs::symlink_metadata(&link) {
            if !meta.file_type().is_symlink() {
                return Err(PtyError::LinkPathTaken(link));
            }
        }
        let mut emulator = Self::open()?;
        if let Some(slave) = &emulator.slave_path {
            point_link(&link, slave)?;
        }
        emulator.stable_link = Some(link);
        Ok(emulator)
    }

    /// Sets how long a [`write`](Self::write) waits for room in the kernel
    /// buffer before the rest is lost (default 50 ms).
    pub fn set_write_timeout(&mut self, timeout: Duration) {
        self.write_timeout = timeout;
    }

    /// The path a driver should open: the symlink if there is one, else the
    /// current slave. `None` while unplugged without a symlink.
    #[must_use]
    pub fn driver_path(&self) -> Option<&Path> {
        self.stable_link.as_deref().or(self.slave_path.as_deref())
    }

    /// The current slave device (`/dev/pts/N`), `None` while unplugged.
    #[must_use]
    pub fn slave_path(&self) -> Option<&Path> {
        self.slave_path.as_deref()
    }

    /// The symlink that follows the slave, if any.
    #[must_use]
    pub fn stable_path(&self) -> Option<&Path> {
        self.stable_link.as_deref()
    }

    /// Whether the device is plugged in.
    #[must_use]
    pub fn is_connected(&self) -> bool {
        self.master.is_some()
    }

    /// Counters so far.
    #[must_use]
    pub fn stats(&self) -> PtyStats {
        self.stats
    }

    /// Sends `bytes` to the driver side; returns how many went out. The
    /// rest is lost: the device is unplugged, no driver has the port open,
    /// or the buffer stayed full for the write timeout.
    pub fn write(&mut self, bytes: &[u8]) -> usize {
        let mut done = 0_usize;
        if let Some(master) = self.master.as_mut() {
            let deadline = Instant::now() + self.write_timeout;
            while let Some(rest) = bytes.get(done..).filter(|r| !r.is_empty()) {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() || master.set_timeout(left).is_err() {
                    break;
                }
                match master.write(rest) {
                    Ok(0) => break,
                    Ok(n) => done = done.saturating_add(n),
                    Err(e)
                        if matches!(
                            e.kind(),
                            io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
                        ) => {}
                    Err(_) => break,
                }
            }
        }
        self.stats.bytes_written = self.stats.bytes_written.saturating_add(done as u64);
        let lost = bytes.len().saturating_sub(done);
        self.stats.bytes_dropped = self.stats.bytes_dropped.saturating_add(lost as u64);
        done
    }

    /// Reads what the driver wrote (commands), waiting at most `timeout`;
    /// 0 when nothing came, nobody has the port open, or unplugged.
    pub fn read(&mut self, buf: &mut [u8], timeout: Duration) -> usize {
        let Some(master) = self.master.as_mut() else {
            return 0;
        };
        if buf.is_empty() || master.set_timeout(timeout).is_err() {
            return 0;
        }
        master.read(buf).unwrap_or(0)
    }

    /// Unplugs the device: closes the pseudo-terminal and removes the
    /// symlink. Nothing happens when already unplugged.
    pub fn disconnect(&mut self) {
        if self.master.take().is_none() {
            return;
        }
        self.slave_path = None;
        self.stats.unplugs = self.stats.unplugs.saturating_add(1);
        if let Some(link) = &self.stable_link {
            let _ = std::fs::remove_file(link);
        }
    }

    /// Plugs the device back in on a new pseudo-terminal (a new slave path)
    /// and re-points the symlink. Nothing happens when already plugged in.
    ///
    /// # Errors
    /// [`PtyError::Create`] or [`PtyError::Link`]; the device stays
    /// unplugged.
    pub fn reconnect(&mut self) -> Result<(), PtyError> {
        if self.master.is_some() {
            return Ok(());
        }
        let (master, slave_path) = create_pair()?;
        if let Some(link) = &self.stable_link {
            point_link(link, &slave_path)?;
        }
        self.master = Some(master);
        self.slave_path = Some(slave_path);
        self.stats.replugs = self.stats.replugs.saturating_add(1);
        Ok(())
    }
}

impl Drop for PtyEmulator {
    fn drop(&mut self) {
        if let Some(link) = &self.stable_link {
            let _ = std::fs::remove_file(link);
        }
    }
}

/// How a [`TcpEmulator`] behaves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TcpEmulatorConfig {
    /// Port on 127.0.0.1 (0: any free port, see [`TcpEmulator::port`]).
    pub port: u16,
    /// Lines a client must send, in order, before the stream starts (line
    /// endings ignored). Empty: stream at once.
    pub expect_lines: Vec<String>,
    /// How long a client has to send them before it is dropped.
    pub handshake_timeout: Duration,
    /// How long a write to a slow client may block before the client is
    /// dropped.
    pub write_timeout: Duration,
}

impl Default for TcpEmulatorConfig {
    fn default() -> Self {
        Self {
            port: 0,
            expect_lines: Vec::new(),
            handshake_timeout: Duration::from_secs(2),
            write_timeout: Duration::from_millis(200),
        }
    }
}

/// Why a [`TcpEmulator`] could not start or reopen its port.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TcpEmulatorError {
    /// Binding 127.0.0.1:port failed.
    #[error("TcpEmulatorError::Bind: cannot listen on 127.0.0.1:{port}: {error}")]
    Bind {
        /// The port asked for.
        port: u16,
        /// The OS error.
        error: String,
    },
    /// The accepting thread could not start.
    #[error("TcpEmulatorError::Spawn: cannot start the accepting thread: {0}")]
    Spawn(String),
}

/// Counters of a [`TcpEmulator`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TcpStats {
    /// Clients that completed the handshake and got the stream.
    pub clients: u64,
    /// Clients dropped for a wrong or late handshake.
    pub handshake_failures: u64,
    /// Bytes written to clients.
    pub bytes_written: u64,
    /// Bytes lost: no client, or the client failed.
    pub bytes_dropped: u64,
    /// Clients dropped by [`TcpEmulator::disconnect`].
    pub disconnects: u64,
}

#[derive(Debug, Default)]
struct TcpCounters {
    clients: AtomicU64,
    handshake_failures: AtomicU64,
    bytes_written: AtomicU64,
    bytes_dropped: AtomicU64,
    disconnects: AtomicU64,
}

#[derive(Debug)]
struct TcpShared {
    config: TcpEmulatorConfig,
    port: u16,
    listener: Mutex<Option<TcpListener>>,
    /// `Instant` offset (ns since `epoch`) when a timed refusal ends; 0: no
    /// timed refusal.
    reopen_at_ns: AtomicU64,
    epoch: Instant,
    client: Mutex<Option<TcpStream>>,
    lines: Mutex<Vec<String>>,
    stop: AtomicBool,
    counters: TcpCounters,
}

fn bind(port: u16) -> Result<TcpListener, TcpEmulatorError> {
    let bind_err = |e: io::Error| TcpEmulatorError::Bind {
        port,
        error: e.to_string(),
    };
    let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, port)).map_err(bind_err)?;
    listener.set_nonblocking(true).map_err(bind_err)?;
    Ok(listener)
}

impl TcpShared {
    fn since_epoch_ns(&self) -> u64 {
        u64::try_from(self.epoch.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }

    /// Reads the expected lines from a new client. Returns whether they all
    /// came, in order, within the handshake timeout.
    fn handshake(&self, stream: &mut TcpStream) -> bool {
        let expect = &self.config.expect_lines;
        if expect.is_empty() {
            return true;
        }
        let deadline = Instant::now() + self.config.handshake_timeout;
        let mut line: Vec<u8> = Vec::with_capacity(128);
        let mut matched = 0_usize;
        let mut buf = [0_u8; 256];
        while matched < expect.len() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() || stream.set_read_timeout(Some(left)).is_err() {
                return false;
            }
            let n = match stream.read(&mut buf) {
                Ok(0) => return false,
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(_) => return false,
            };
            for &b in buf.get(..n).unwrap_or_default() {
                if b != b'\n' {
                    if line.len() < 1024 {
                        line.push(b);
                    }
                    continue;
                }
                let text = String::from_utf8_lossy(&line)
                    .trim_end_matches('\r')
                    .to_owned();
                line.clear();
                let want = expect
                    .get(matched)
                    .map(|w| w.trim_end_matches(['\r', '\n']));
                let ok = want == Some(text.as_str());
                lock(&self.lines).push(text);
                if !ok {
                    return false;
                }
                matched = matched.saturating_add(1);
                if matched == expect.len() {
                    break;
                }
            }
        }
        true
    }

    fn accept_loop(&self) {
        while !self.stop.load(Ordering::Relaxed) {
            let reopen_at = self.reopen_at_ns.load(Ordering::Relaxed);
            if reopen_at != 0 && self.since_epoch_ns() >= reopen_at {
                let mut listener = lock(&self.listener);
                if listener.is_none() {
                    if let Ok(l) = bind(self.port) {
                        *listener = Some(l);
                        self.reopen_at_ns.store(0, Ordering::Relaxed);
                    }
                } else {
                    self.reopen_at_ns.store(0, Ordering::Relaxed);
                }
            }
            let accepted = match lock(&self.listener).as_ref().map(TcpListener::accept) {
                Some(Ok((stream, _))) => Some(stream),
                _ => None,
            };
            let Some(mut stream) = accepted else {
                std::thread::sleep(Duration::from_millis(2));
                continue;
            };
            let ready = stream.set_nonblocking(false).is_ok()
                && stream.set_nodelay(true).is_ok()
                && stream
                    .set_write_timeout(Some(self.config.write_timeout))
                    .is_ok()
                && self.handshake(&mut stream);
            if ready {
                if let Some(old) = lock(&self.client).replace(stream) {
                    let _ = old.shutdown(Shutdown::Both);
                }
                self.counters.clients.fetch_add(1, Ordering::Relaxed);
            } else {
                self.counters
                    .handshake_failures
                    .fetch_add(1, Ordering::Relaxed);
                let _ = stream.shutdown(Shutdown::Both);
            }
        }
    }
}

/// A TCP server on 127.0.0.1 that streams bytes to one client at a time
/// (a newer client replaces the current one), after the client has sent the
/// expected command lines, like an Eliko RTLS server.
#[derive(Debug)]
pub struct TcpEmulator {
    shared: Arc<TcpShared>,
    acceptor: Option<JoinHandle<()>>,
}

impl TcpEmulator {
    /// Listens and starts accepting clients on a thread.
    ///
    /// # Errors
    /// [`TcpEmulatorError::Bind`] or [`TcpEmulatorError::Spawn`].
    pub fn start(config: TcpEmulatorConfig) -> Result<Self, TcpEmulatorError> {
        let listener = bind(config.port)?;
        let port = listener
            .local_addr()
            .map_err(|e| TcpEmulatorError::Bind {
                port: config.port,
                error: e.to_string(),
            })?
            .port();
        let shared = Arc::new(TcpShared {
            config,
            port,
            listener: Mutex::new(Some(listener)),
            reopen_at_ns: AtomicU64::new(0),
            epoch: Instant::now(),
            client: Mutex::new(None),
            lines: Mutex::new(Vec::new()),
            stop: AtomicBool::new(false),
            counters: TcpCounters::default(),
        });
        let thread_shared = Arc::clone(&shared);
        let acceptor = std::thread::Builder::new()
            .name("tcp-emulator".to_owned())
            .spawn(move || thread_shared.accept_loop())
            .map_err(|e| TcpEmulatorError::Spawn(e.to_string()))?;
        Ok(Self {
            shared,
            acceptor: Some(acceptor),
        })
    }

    /// The port listened on (the one picked when the config said 0).
    #[must_use]
    pub fn port(&self) -> u16 {
        self.shared.port
    }

    /// Whether a client has completed the handshake and gets the stream.
    #[must_use]
    pub fn has_client(&self) -> bool {
        lock(&self.shared.client).is_some()
    }

    /// Waits up to `timeout` for a client to be streaming; returns whether
    /// one is.
    #[must_use]
    pub fn wait_for_client(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        loop {
            if self.has_client() {
                return true;
            }
            if Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// The lines clients sent during handshakes, in order, all clients
    /// together (line endings removed).
    #[must_use]
    pub fn received_lines(&self) -> Vec<String> {
        lock(&self.shared.lines).clone()
    }

    /// Counters so far.
    #[must_use]
    pub fn stats(&self) -> TcpStats {
        let c = &self.shared.counters;
        TcpStats {
            clients: c.clients.load(Ordering::Relaxed),
            handshake_failures: c.handshake_failures.load(Ordering::Relaxed),
            bytes_written: c.bytes_written.load(Ordering::Relaxed),
            bytes_dropped: c.bytes_dropped.load(Ordering::Relaxed),
            disconnects: c.disconnects.load(Ordering::Relaxed),
        }
    }

    /// Sends `bytes` to the streaming client; returns how many went out
    /// (all or none). Without a client, or when the client fails (it is then
    /// dropped), the bytes are lost.
    pub fn write(&self, bytes: &[u8]) -> usize {
        let c = &self.shared.counters;
        let mut client = lock(&self.shared.client);
        let sent = match client.as_mut().map(|s| s.write_all(bytes)) {
            Some(Ok(())) => bytes.len(),
            Some(Err(_)) => {
                if let Some(s) = client.take() {
                    let _ = s.shutdown(Shutdown::Both);
                }
                0
            }
            None => 0,
        };
        c.bytes_written.fetch_add(sent as u64, Ordering::Relaxed);
        c.bytes_dropped
            .fetch_add(bytes.len().saturating_sub(sent) as u64, Ordering::Relaxed);
        sent
    }

    /// Drops the current client (it sees the end of the stream); new
    /// clients are accepted as before.
    pub fn disconnect(&self) {
        if let Some(s) = lock(&self.shared.client).take() {
            let _ = s.shutdown(Shutdown::Both);
            self.shared
                .counters
                .disconnects
                .fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Drops the current client and closes the listening socket, so that
    /// connecting is refused, for `refuse_for`; then listens again on the
    /// same port.
    pub fn disconnect_for(&self, refuse_for: Duration) {
        self.refuse_connections();
        let at = self
            .shared
            .since_epoch_ns()
            .saturating_add(u64::try_from(refuse_for.as_nanos()).unwrap_or(u64::MAX))
            .max(1);
        self.shared.reopen_at_ns.store(at, Ordering::Relaxed);
    }

    /// Drops the current client and refuses connections until
    /// [`accept_connections`](Self::accept_connections).
    pub fn refuse_connections(&self) {
        self.shared.reopen_at_ns.store(0, Ordering::Relaxed);
        drop(lock(&self.shared.listener).take());
        self.disconnect();
    }

    /// Listens again after [`refuse_connections`](Self::refuse_connections)
    /// (nothing happens if already listening).
    ///
    /// # Errors
    /// [`TcpEmulatorError::Bind`] when the port was taken meanwhile.
    pub fn accept_connections(&self) -> Result<(), TcpEmulatorError> {
        let mut listener = lock(&self.shared.listener);
        if listener.is_none() {
            *listener = Some(bind(self.shared.port)?);
        }
        self.shared.reopen_at_ns.store(0, Ordering::Relaxed);
        Ok(())
    }
}

impl Drop for TcpEmulator {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        self.disconnect();
        if let Some(t) = self.acceptor.take() {
            let _ = t.join();
        }
    }
}

/// A device the [`Player`] writes to.
pub trait DeviceSink: Send + 'static {
    /// Writes one chunk; returns the bytes that went out (the rest is lost).
    fn write_chunk(&mut self, bytes: &[u8]) -> usize;
    /// Unplugs the device.
    fn unplug(&mut self);
    /// Plugs it back in; the error text when it cannot come back.
    ///
    /// # Errors
    /// The reason, as text.
    fn replug(&mut self) -> Result<(), String>;
}

impl DeviceSink for PtyEmulator {
    fn write_chunk(&mut self, bytes: &[u8]) -> usize {
        self.write(bytes)
    }
    fn unplug(&mut self) {
        self.disconnect();
    }
    fn replug(&mut self) -> Result<(), String> {
        self.reconnect().map_err(|e| e.to_string())
    }
}

impl DeviceSink for TcpEmulator {
    fn write_chunk(&mut self, bytes: &[u8]) -> usize {
        self.write(bytes)
    }
    fn unplug(&mut self) {
        self.refuse_connections();
    }
    fn replug(&mut self) -> Result<(), String> {
        self.accept_connections().map_err(|e| e.to_string())
    }
}

/// Periodic unplugging: the device goes away for `length` every `every`,
/// the first time `every` after the start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Outage {
    /// Time between the starts of two outages.
    pub every: Duration,
    /// How long each lasts.
    pub length: Duration,
}

/// Faults a [`Player`] injects, drawn from a PRNG seeded with `seed` (the
/// same seed and chunks give the same faults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Faults {
    /// PRNG seed.
    pub seed: u64,
    /// Probability, per chunk, of a burst of random bytes before it.
    pub garbage_prob: f64,
    /// Longest garbage burst (bytes, at least 1 when bursts happen).
    pub garbage_max_len: usize,
    /// Probability, per chunk, of losing a run of its bytes.
    pub drop_prob: f64,
    /// Longest run lost (bytes).
    pub drop_max_len: usize,
    /// Periodic unplugging, if any.
    pub outage: Option<Outage>,
}

impl Faults {
    /// No faults.
    #[must_use]
    pub fn none() -> Self {
        Self {
            seed: 0,
            garbage_prob: 0.0,
            garbage_max_len: 0,
            drop_prob: 0.0,
            drop_max_len: 0,
            outage: None,
        }
    }
}

/// Why a [`Player`] could not start or finish.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PlayerError {
    /// A probability is outside 0..=1 (or not a number).
    #[error("PlayerError::BadProbability: {0} is not in 0..=1")]
    BadProbability(String),
    /// An outage does not end before the next one starts, or is empty.
    #[error("PlayerError::BadOutage: an outage must last > 0 and less than its period")]
    BadOutage,
    /// The playing thread could not start.
    #[error("PlayerError::Spawn: cannot start the playing thread: {0}")]
    Spawn(String),
    /// The playing thread panicked.
    #[error("PlayerError::Panicked: the playing thread panicked")]
    Panicked,
}

/// What a [`Player`] did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PlayReport {
    /// Chunks handed to the device.
    pub chunks_played: u64,
    /// Chunks due while unplugged (not written).
    pub chunks_lost_in_outage: u64,
    /// Bytes handed to the device (garbage included, dropped runs not).
    pub bytes_offered: u64,
    /// Of those, bytes the device got out.
    pub bytes_delivered: u64,
    /// Garbage bursts inserted.
    pub garbage_bursts: u64,
    /// Garbage bytes inserted.
    pub garbage_bytes: u64,
    /// Runs of bytes dropped.
    pub drop_events: u64,
    /// Bytes dropped by those runs.
    pub bytes_dropped: u64,
    /// Outages (unplug, replug) performed.
    pub outages: u64,
    /// Replugs that failed (text of the last one).
    pub replug_errors: Option<String>,
    /// Worst lateness of a chunk against its due time (ns).
    pub max_late_ns: u64,
    /// Whether [`Player::stop`] ended the play early.
    pub stopped: bool,
}

/// A garbage burst before a chunk, drawn from `rng`: pushes its bytes to
/// `out` and returns how many (0 when no burst is drawn).
fn draw_garbage(rng: &mut Xoshiro256StarStar, faults: &Faults, out: &mut Vec<u8>) -> usize {
    if faults.garbage_prob <= 0.0 || rng.random::<f64>() >= faults.garbage_prob {
        return 0;
    }
    let n = rng.random_range(1..=faults.garbage_max_len.max(1));
    out.extend((0..n).map(|_| rng.random::<u8>()));
    n
}

/// A run of bytes lost from a chunk of `len` bytes, drawn from `rng`: its
/// start and length (`None` when no loss is drawn).
fn draw_drop(rng: &mut Xoshiro256StarStar, faults: &Faults, len: usize) -> Option<(usize, usize)> {
    if faults.drop_prob <= 0.0 || len == 0 || rng.random::<f64>() >= faults.drop_prob {
        return None;
    }
    let n = rng.random_range(1..=faults.drop_max_len.min(len).max(1));
    let at = rng.random_range(0..=len - n);
    Some((at, n))
}

/// Plays timed byte chunks to a [`DeviceSink`] on a thread.
#[derive(Debug)]
pub struct Player<S> {
    thread: JoinHandle<(S, PlayReport)>,
    stop: Arc<AtomicBool>,
}

/// Sleeps until `clock() >= target` (or `stop`): a long sleep to about 1 ms
/// before, then short sleeps, never spinning.
fn sleep_until(clock: fn() -> u64, target: u64, stop: &AtomicBool) {
    loop {
        let now = clock();
        if now >= target || stop.load(Ordering::Relaxed) {
            return;
        }
        let left = target - now;
        let nap = if left > 2_000_000 {
            // Long sleeps are cut to 100 ms so that `stop` is seen.
            (left - 1_000_000).min(100_000_000)
        } else {
            left.min(100_000)
        };
        std::thread::sleep(Duration::from_nanos(nap));
    }
}

fn dur_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

impl<S: DeviceSink> Player<S> {
    /// Starts playing: chunk `(due_ns, bytes)` is written when the clock
    /// reaches `epoch_ns + due_ns`, in list order (a chunk due before the one
    /// ahead of it is written right after it, counted late). `clock` is
    /// CLOCK_MONOTONIC in ns.
    ///
    /// # Errors
    /// [`PlayerError::BadProbability`], [`PlayerError::BadOutage`],
    /// [`PlayerError::Spawn`].
    pub fn start(
        sink: S,
        chunks: Vec<(u64, Vec<u8>)>,
        epoch_ns: u64,
        clock: fn() -> u64,
        faults: Faults,
    ) -> Result<Self, PlayerError> {
        for (name, p) in [
            ("garbage_prob", faults.garbage_prob),
            ("drop_prob", faults.drop_prob),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(PlayerError::BadProbability(format!("{name} = {p}")));
            }
        }
        if let Some(o) = faults.outage {
            if o.length.is_zero() || o.length >= o.every {
                return Err(PlayerError::BadOutage);
            }
        }
        let stop = Arc::new(AtomicBool::new(false));
        let thread_stop = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("device-player".to_owned())
            .spawn(move || play(sink, &chunks, epoch_ns, clock, &faults, &thread_stop))
            .map_err(|e| PlayerError::Spawn(e.to_string()))?;
        Ok(Self { thread, stop })
    }

    /// Asks the player to stop soon (within about 100 ms).
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Whether the play is over.
    #[must_use]
    pub fn is_finished(&self) -> bool {
        self.thread.is_finished()
    }

    /// Waits for the end of the play; gives back the device and the report.
    ///
    /// # Errors
    /// [`PlayerError::Panicked`].
    pub fn join(self) -> Result<(S, PlayReport), PlayerError> {
        self.thread.join().map_err(|_| PlayerError::Panicked)
    }
}

fn play<S: DeviceSink>(
    mut sink: S,
    chunks: &[(u64, Vec<u8>)],
    epoch_ns: u64,
    clock: fn() -> u64,
    faults: &Faults,
    stop: &AtomicBool,
) -> (S, PlayReport) {
    let mut rng = Xoshiro256StarStar::seed_from_u64(faults.seed);
    let mut report = PlayReport::default();
    let mut scratch: Vec<u8> = Vec::new();
    let mut plugged = true;
    let mut outage_end = 0_u64;
    let mut next_outage = faults
        .outage
        .map(|o| epoch_ns.saturating_add(dur_ns(o.every)));
    for (due_ns, bytes) in chunks {
        let due = epoch_ns.saturating_add(*due_ns);
        loop {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            if !plugged && outage_end <= due {
                sleep_until(clock, outage_end, stop);
                if let Err(e) = sink.replug() {
                    report.replug_errors = Some(e);
                }
                plugged = true;
            }
            if let (true, Some(start), Some(o)) = (plugged, next_outage, faults.outage) {
                if start <= due {
                    sleep_until(clock, start, stop);
                    sink.unplug();
                    plugged = false;
                    report.outages = report.outages.saturating_add(1);
                    outage_end = start.saturating_add(dur_ns(o.length));
                    next_outage = Some(start.saturating_add(dur_ns(o.every)));
                    continue;
                }
            }
            break;
        }
        if stop.load(Ordering::Relaxed) {
            report.stopped = true;
            break;
        }
        if !plugged {
            report.chunks_lost_in_outage = report.chunks_lost_in_outage.saturating_add(1);
            continue;
        }
        scratch.clear();
        let n = draw_garbage(&mut rng, faults, &mut scratch);
        if n > 0 {
            report.garbage_bursts = report.garbage_bursts.saturating_add(1);
            report.garbage_bytes = report.garbage_bytes.saturating_add(n as u64);
        }
        let mut body: &[u8] = bytes;
        let mut tail: &[u8] = &[];
        if let Some((at, n)) = draw_drop(&mut rng, faults, bytes.len()) {
            body = bytes.get(..at).unwrap_or_default();
            tail = bytes.get(at.saturating_add(n)..).unwrap_or_default();
            report.drop_events = report.drop_events.saturating_add(1);
            report.bytes_dropped = report.bytes_dropped.saturating_add(n as u64);
        }
        scratch.extend_from_slice(body);
        scratch.extend_from_slice(tail);
        sleep_until(clock, due, stop);
        let now = clock();
        report.max_late_ns = report.max_late_ns.max(now.saturating_sub(due));
        let sent = sink.write_chunk(&scratch);
        report.chunks_played = report.chunks_played.saturating_add(1);
        report.bytes_offered = report.bytes_offered.saturating_add(scratch.len() as u64);
        report.bytes_delivered = report.bytes_delivered.saturating_add(sent as u64);
    }
    if !plugged {
        sleep_until(clock, outage_end, stop);
        if let Err(e) = sink.replug() {
            report.replug_errors = Some(e);
        }
    }
    (sink, report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fault_draws_are_seeded_and_in_range() {
        let faults = Faults {
            seed: 7,
            garbage_prob: 0.5,
            garbage_max_len: 5,
            drop_prob: 0.5,
            drop_max_len: 4,
            outage: None,
        };
        let draws = |seed| {
            let mut rng = Xoshiro256StarStar::seed_from_u64(seed);
            let mut bytes = Vec::new();
            let (mut bursts, mut drops) = (Vec::new(), Vec::new());
            for len in (0..10_000).map(|k| k % 7) {
                bursts.push(draw_garbage(&mut rng, &faults, &mut bytes));
                drops.push(draw_drop(&mut rng, &faults, len).map(|d| (len, d)));
            }
            (bytes, bursts, drops)
        };
        let (bytes, bursts, drops) = draws(7);
        assert_eq!(draws(7), (bytes.clone(), bursts.clone(), drops.clone()));
        assert_ne!(draws(8).1, bursts);
        assert_eq!(bytes.len(), bursts.iter().sum::<usize>());
        assert!(bursts.iter().all(|&n| n <= 5));
        let some = bursts.iter().filter(|&&n| n > 0).count();
        assert!((4_500..5_500).contains(&some), "{some}");
        for (len, (at, n)) in drops.iter().flatten() {
            assert!(
                (1..=4).contains(n) && n <= len && at + n <= *len,
                "{len} {at} {n}"
            );
        }
        let none = Faults::none();
        let mut rng = Xoshiro256StarStar::seed_from_u64(1);
        let before = rng.clone();
        assert_eq!(draw_garbage(&mut rng, &none, &mut Vec::new()), 0);
        assert_eq!(draw_drop(&mut rng, &none, 10), None);
        assert_eq!(rng, before, "no faults: nothing drawn");
    }

    #[test]
    fn link_names_are_checked() {
        let dir = std::env::temp_dir();
        for bad in ["", "a/b", ".", ".."] {
            assert_eq!(
                PtyEmulator::open_with_link(&dir, bad).err(),
                Some(PtyError::BadLinkName(bad.to_owned()))
            );
        }
    }
}
