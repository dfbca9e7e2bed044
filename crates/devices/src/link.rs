//! Byte links to devices that come and go: a serial port or a TCP
//! connection behind one [`Link`] that notices when the device disappears
//! (USB unplug, pseudo-terminal master closed, TCP EOF or reset) and
//! reconnects with capped exponential backoff, without ever holding the
//! caller longer than the timeout it passed to [`Link::read`].
//!
//! ```no_run
//! use std::time::Duration;
//! use insuwb_devices::link::{Link, LinkSpec, Read, ReconnectPolicy};
//!
//! # fn clock() -> u64 { 0 }
//! let spec: LinkSpec = "tcp:192.168.1.10:25025".parse()?;
//! let eliko_start = b"$PEKIO,EULA,ACCEPT\r\n$PEKIO,SET_REPORT_LIST,COORD\r\n".to_vec();
//! let mut link = Link::new(spec, 0, ReconnectPolicy::default(), eliko_start, clock)?;
//! let mut buf = [0_u8; 1024];
//! match link.read(&mut buf, Duration::from_millis(100))? {
//!     Read::Data { n, host_time_ns } => { /* hand buf[..n] to the decoder */ }
//!     Read::Timeout => {}
//!     Read::Down { retry_in } => { /* publish health: device down */ }
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The link knows bytes only. Whether the bytes make sense (wrong baud rate,
//! wrong protocol) is for the decoder to say: the driver stage compares the
//! frames decoded with [`LinkStats::bytes_read`].
//!
//! A read that returns data or times out allocates nothing. Errors (going
//! down, a failed connect) record their text in [`LinkStats::last_error`],
//! which allocates.
//!
//! Serial latency: FTDI USB adapters hold received bytes for up to their
//! latency timer (16 ms by default) before sending a USB packet; set it to
//! 1 ms (`/sys/bus/usb-serial/devices/ttyUSB0/latency_timer`) for IMUs, or
//! every sample arrives up to 16 ms late and in bursts.

use std::fmt;
use std::io::{self, Read as _, Write as _};
use std::net::{IpAddr, SocketAddr, TcpStream, ToSocketAddrs};
use std::os::fd::{AsRawFd, RawFd};
use std::os::raw::c_int;
use std::path::PathBuf;
use std::str::FromStr;
use std::time::Duration;

use nix::errno::Errno;
use nix::poll::{poll, PollFd, PollFlags};
use serialport::{DataBits, FlowControl, Parity, StopBits, TTYPort};

/// Where a device is: a serial port path or a TCP server.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkSpec {
    /// A serial port (a tty device, a pseudo-terminal, or a symlink to one
    /// such as `/dev/serial/by-id/...`). The baud rate is given apart.
    Serial {
        /// Path of the tty device.
        path: PathBuf,
    },
    /// A TCP server the link connects to as a client.
    Tcp {
        /// Host name or IP address (IPv6 without brackets).
        host: String,
        /// TCP port.
        port: u16,
    },
}

/// Why a link specification string was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LinkSpecError {
    /// The string has no `scheme:` prefix.
    #[error("LinkSpecError::MissingScheme: {0:?} has no scheme; write serial:/dev/ttyUSB0 or tcp:HOST:PORT")]
    MissingScheme(String),
    /// The scheme is neither `serial` nor `tcp`.
    #[error("LinkSpecError::UnknownScheme: scheme {0:?} is not serial or tcp")]
    UnknownScheme(String),
    /// `serial:` with nothing after it.
    #[error("LinkSpecError::EmptyPath: serial: needs a device path, e.g. serial:/dev/ttyUSB0")]
    EmptyPath,
    /// `tcp:` without a `:PORT` at the end.
    #[error("LinkSpecError::MissingPort: {0:?} has no :PORT; write tcp:HOST:PORT")]
    MissingPort(String),
    /// The port is not a number in 1..=65535.
    #[error("LinkSpecError::BadPort: port {0:?} is not a number in 1..=65535")]
    BadPort(String),
    /// `tcp::PORT`: the host is empty.
    #[error("LinkSpecError::EmptyHost: tcp: needs a host before :PORT")]
    EmptyHost,
}

impl FromStr for LinkSpec {
    type Err = LinkSpecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (scheme, rest) = s
            .split_once(':')
            .ok_or_else(|| LinkSpecError::MissingScheme(s.to_owned()))?;
        match scheme {
            "serial" => {
                if rest.is_empty() {
                    return Err(LinkSpecError::EmptyPath);
                }
                Ok(Self::Serial {
                    path: PathBuf::from(rest),
                })
            }
            "tcp" => {
                let (host, port) = rest
                    .rsplit_once(':')
                    .ok_or_else(|| LinkSpecError::MissingPort(rest.to_owned()))?;
                let port: u16 = port
                    .parse()
                    .ok()
                    .filter(|p| *p != 0)
                    .ok_or_else(|| LinkSpecError::BadPort(port.to_owned()))?;
                let host = host
                    .strip_prefix('[')
                    .and_then(|h| h.strip_suffix(']'))
                    .unwrap_or(host);
                if host.is_empty() {
                    return Err(LinkSpecError::EmptyHost);
                }
                Ok(Self::Tcp {
                    host: host.to_owned(),
                    port,
                })
            }
            other => Err(LinkSpecError::UnknownScheme(other.to_owned())),
        }
    }
}

impl fmt::Display for LinkSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Serial { path } => write!(f, "serial:{}", path.display()),
            Self::Tcp { host, port } if host.contains(':') => write!(f, "tcp:[{host}]:{port}"),
            Self::Tcp { host, port } => write!(f, "tcp:{host}:{port}"),
        }
    }
}

/// How a [`Link`] retries a device that is down.
///
/// After the `k`-th failed attempt in a row the next one comes
/// `min(initial_backoff * 2^(k-1), max_backoff)` later. A device that
/// returns is therefore found again at most `max_backoff` (plus the read
/// timeout the caller uses) after it is back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReconnectPolicy {
    /// Wait before the first retry after the link went down, and after the
    /// first failed attempt.
    pub initial_backoff: Duration,
    /// The cap on the wait between attempts.
    pub max_backoff: Duration,
    /// The longest a TCP connect may take (also capped by the time left of
    /// the read that makes the attempt).
    pub connect_timeout: Duration,
    /// The longest a write (commands, `on_connect` bytes) may block.
    pub write_timeout: Duration,
}

impl Default for ReconnectPolicy {
    /// 50 ms first retry, doubling up to 500 ms; 1 s connect and write
    /// timeouts.
    fn default() -> Self {
        Self {
            initial_backoff: Duration::from_millis(50),
            max_backoff: Duration::from_millis(500),
            connect_timeout: Duration::from_secs(1),
            write_timeout: Duration::from_secs(1),
        }
    }
}

impl ReconnectPolicy {
    /// The wait after `failures` failed attempts in a row (0: the link just
    /// went down).
    #[must_use]
    pub fn backoff(&self, failures: u32) -> Duration {
        let doublings = failures.saturating_sub(1).min(31);
        let factor = 1_u32 << doublings;
        self.initial_backoff
            .checked_mul(factor)
            .unwrap_or(self.max_backoff)
            .min(self.max_backoff)
    }
}

/// Why [`Link::new`] refused a policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LinkConfigError {
    /// `initial_backoff` is zero: the link would retry in a tight loop.
    #[error("LinkConfigError::ZeroBackoff: initial_backoff must be > 0")]
    ZeroBackoff,
    /// `max_backoff` is below `initial_backoff`.
    #[error("LinkConfigError::MaxBelowInitial: max_backoff {max:?} is below initial_backoff {initial:?}")]
    MaxBelowInitial {
        /// The policy's initial backoff.
        initial: Duration,
        /// The policy's max backoff.
        max: Duration,
    },
    /// `connect_timeout` or `write_timeout` is zero.
    #[error("LinkConfigError::ZeroTimeout: connect_timeout and write_timeout must be > 0")]
    ZeroTimeout,
}

/// What one [`Link::read`] brought.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Read {
    /// `n` bytes are in the front of the buffer.
    Data {
        /// Number of bytes read.
        n: usize,
        /// CLOCK_MONOTONIC (from the link's clock) when the read returned.
        host_time_ns: u64,
    },
    /// The link is up but no byte came within the timeout.
    Timeout,
    /// The device is not connected; the next attempt comes in `retry_in`.
    Down {
        /// Time until the next connection attempt.
        retry_in: Duration,
    },
}

/// Why [`Link::read`] could not even try. A device that fails is not an
/// error: it is [`Read::Down`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LinkReadError {
    /// The buffer is empty: a zero-byte read cannot tell data from EOF.
    #[error("LinkReadError::EmptyBuffer: read needs a buffer of at least one byte")]
    EmptyBuffer,
}

/// Why [`Link::write_all`] did not write everything.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LinkWriteError {
    /// The link is down; nothing was written.
    #[error("LinkWriteError::NotConnected: the device is not connected")]
    NotConnected,
    /// The write failed; the link is now down and will reconnect.
    #[error("LinkWriteError::Io: write failed, link down: {0}")]
    Io(String),
}

/// Whether the link is up, for the health topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkState {
    /// Connected since `since_ns` (link clock).
    Connected {
        /// When the connection was made.
        since_ns: u64,
    },
    /// Down since `since_ns` (link clock: creation or loss of the
    /// connection), after `attempts` failed connection attempts.
    Disconnected {
        /// When the link went down (or was created).
        since_ns: u64,
        /// Failed attempts since then.
        attempts: u32,
    },
}

/// Counters of a link's life, for the health topic.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Successful connections (the first one included).
    pub connects: u64,
    /// Connections lost (read or write errors, EOF).
    pub disconnects: u64,
    /// Failed connection attempts.
    pub connect_failures: u64,
    /// Bytes read from the device, over all connections.
    pub bytes_read: u64,
    /// Bytes written to the device (`on_connect` bytes included).
    pub bytes_written: u64,
    /// The text of the last error (connect, read or write), if any.
    pub last_error: Option<String>,
}

/// An open device.
#[derive(Debug)]
enum Conn {
    Serial(TTYPort),
    Tcp {
        stream: TcpStream,
        /// The read timeout now set on the socket, to skip the syscall when
        /// it does not change.
        read_timeout: Duration,
    },
}

#[derive(Debug)]
enum LinkInner {
    Up {
        conn: Conn,
        since_ns: u64,
    },
    Down {
        since_ns: u64,
        attempts: u32,
        next_attempt_ns: u64,
    },
}

/// A connection to a device that may be down. See the [module](self) docs.
#[derive(Debug)]
pub struct Link {
    spec: LinkSpec,
    baud: u32,
    policy: ReconnectPolicy,
    on_connect: Vec<u8>,
    clock: fn() -> u64,
    inner: LinkInner,
    stats: LinkStats,
}

fn dur_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

fn is_timeout(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
    )
}

impl Link {
    /// A link to `spec` (`baud` is used for serial ports only), down until
    /// the first [`read`](Self::read) connects it. `on_connect` is written
    /// after every connection (e.g. the Eliko start commands); `clock` is
    /// CLOCK_MONOTONIC in ns (`insuwb_runtime::monotonic_ns`).
    ///
    /// # Errors
    /// [`LinkConfigError`] when the policy has a zero backoff or timeout, or
    /// a cap below its start.
    pub fn new(
        spec: LinkSpec,
        baud: u32,
        policy: ReconnectPolicy,
        on_connect: Vec<u8>,
        clock: fn() -> u64,
    ) -> Result<Self, LinkConfigError> {
        if policy.initial_backoff.is_zero() {
            return Err(LinkConfigError::ZeroBackoff);
        }
        if policy.max_backoff < policy.initial_backoff {
            return Err(LinkConfigError::MaxBelowInitial {
                initial: policy.initial_backoff,
                max: policy.max_backoff,
            });
        }
        if policy.connect_timeout.is_zero() || policy.write_timeout.is_zero() {
            return Err(LinkConfigError::ZeroTimeout);
        }
        let now = clock();
        Ok(Self {
            spec,
            baud,
            policy,
            on_connect,
            clock,
            inner: LinkInner::Down {
                since_ns: now,
                attempts: 0,
                next_attempt_ns: now,
            },
            stats: LinkStats::default(),
        })
    }

    /// Where the link goes.
    #[must_use]
    pub fn spec(&self) -> &LinkSpec {
        &self.spec
    }

    /// Whether the link is up, and since when.
    #[must_use]
    pub fn state(&self) -> LinkState {
        match &self.inner {
            LinkInner::Up { since_ns, .. } => LinkState::Connected {
                since_ns: *since_ns,
            },
            LinkInner::Down {
                since_ns, attempts, ..
            } => LinkState::Disconnected {
                since_ns: *since_ns,
                attempts: *attempts,
            },
        }
    }

    /// Counters since the link was made.
    #[must_use]
    pub fn stats(&self) -> &LinkStats {
        &self.stats
    }

    /// Reads what the device sent, waiting at most about `timeout`.
    ///
    /// Connected: returns [`Read::Data`] as soon as bytes arrive, or
    /// [`Read::Timeout`]. When the device fails during the read, the link
    /// goes down and the read returns [`Read::Down`] at once. Down: the read
    /// sleeps until the next attempt if that comes within `timeout`, tries to
    /// connect, and reads with the time left; otherwise it sleeps the whole
    /// `timeout` and returns [`Read::Down`], so a loop over `read` never
    /// spins. A zero `timeout` returns [`Read::Timeout`] without reading.
    ///
    /// # Errors
    /// [`LinkReadError::EmptyBuffer`] for an empty `buf`.
    pub fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<Read, LinkReadError> {
        if buf.is_empty() {
            return Err(LinkReadError::EmptyBuffer);
        }
        if matches!(self.inner, LinkInner::Up { .. }) {
            // The whole timeout: a TCP socket keeps its read timeout set
            // when every call passes the same one.
            return Ok(self.read_up(buf, timeout));
        }
        let start = (self.clock)();
        let deadline = start.saturating_add(dur_ns(timeout));
        loop {
            let now = (self.clock)();
            match &mut self.inner {
                LinkInner::Up { .. } => {
                    let left = Duration::from_nanos(deadline.saturating_sub(now));
                    return Ok(self.read_up(buf, left));
                }
                LinkInner::Down {
                    next_attempt_ns, ..
                } => {
                    let next = *next_attempt_ns;
                    if next > now {
                        if next > deadline {
                            let left = deadline.saturating_sub(now);
                            std::thread::sleep(Duration::from_nanos(left));
                            let after = (self.clock)();
                            return Ok(Read::Down {
                                retry_in: Duration::from_nanos(next.saturating_sub(after)),
                            });
                        }
                        std::thread::sleep(Duration::from_nanos(next - now));
                    }
                    let left = Duration::from_nanos(deadline.saturating_sub((self.clock)()));
                    if !self.try_connect(left) {
                        if let LinkInner::Down {
                            next_attempt_ns, ..
                        } = &self.inner
                        {
                            if *next_attempt_ns > deadline {
                                let after = (self.clock)();
                                return Ok(Read::Down {
                                    retry_in: Duration::from_nanos(
                                        next_attempt_ns.saturating_sub(after),
                                    ),
                                });
                            }
                        }
                    }
                }
            }
        }
    }

    /// One read on an open connection with `left` time.
    fn read_up(&mut self, buf: &mut [u8], left: Duration) -> Read {
        let LinkInner::Up { conn, .. } = &mut self.inner else {
            return Read::Timeout;
        };
        if left.is_zero() {
            return Read::Timeout;
        }
        let result = match conn {
            Conn::Serial(port) => serial_read(port.as_raw_fd(), buf, left),
            Conn::Tcp {
                stream,
                read_timeout,
            } => {
                let set = if *read_timeout == left {
                    Ok(())
                } else {
                    stream.set_read_timeout(Some(left)).map(|()| {
                        *read_timeout = left;
                    })
                };
                set.and_then(|()| stream.read(buf))
            }
        };
        match result {
            Ok(0) => self.go_down("end of stream (device closed)"),
            Ok(n) => {
                let host_time_ns = (self.clock)();
                self.stats.bytes_read = self.stats.bytes_read.saturating_add(n as u64);
                Read::Data { n, host_time_ns }
            }
            Err(e) if is_timeout(&e) => Read::Timeout,
            Err(e) => self.go_down(&format!("read: {e}")),
        }
    }

    /// Drops the connection and schedules the first retry.
    fn go_down(&mut self, why: &str) -> Read {
        let now = (self.clock)();
        let retry_in = self.policy.backoff(0);
        let old = std::mem::replace(
            &mut self.inner,
            LinkInner::Down {
                since_ns: now,
                attempts: 0,
                next_attempt_ns: now.saturating_add(dur_ns(retry_in)),
            },
        );
        if let LinkInner::Up { conn, .. } = old {
            close(conn);
            self.stats.disconnects = self.stats.disconnects.saturating_add(1);
        }
        tracing::warn!(link = %self.spec, reason = why, "device link down");
        self.stats.last_error = Some(why.to_owned());
        Read::Down { retry_in }
    }

    /// One connection attempt with at most `left` for a TCP connect. Returns
    /// whether the link is up.
    fn try_connect(&mut self, left: Duration) -> bool {
        let LinkInner::Down {
            since_ns, attempts, ..
        } = self.inner
        else {
            return true;
        };
        let result = self.open(left).and_then(|mut conn| {
            if self.on_connect.is_empty() {
                return Ok(conn);
            }
            match write_conn(&mut conn, &self.on_connect) {
                Ok(()) => {
                    self.stats.bytes_written = self
                        .stats
                        .bytes_written
                        .saturating_add(self.on_connect.len() as u64);
                    Ok(conn)
                }
                Err(e) => {
                    close(conn);
                    Err(format!("writing on-connect bytes: {e}"))
                }
            }
        });
        let now = (self.clock)();
        match result {
            Ok(conn) => {
                self.inner = LinkInner::Up {
                    conn,
                    since_ns: now,
                };
                self.stats.connects = self.stats.connects.saturating_add(1);
                tracing::info!(link = %self.spec, failed_attempts = attempts, "device link up");
                true
            }
            Err(why) => {
                let attempts = attempts.saturating_add(1);
                let wait = self.policy.backoff(attempts);
                self.inner = LinkInner::Down {
                    since_ns,
                    attempts,
                    next_attempt_ns: now.saturating_add(dur_ns(wait)),
                };
                self.stats.connect_failures = self.stats.connect_failures.saturating_add(1);
                tracing::debug!(link = %self.spec, attempts, error = %why, "device connect failed");
                self.stats.last_error = Some(why);
                false
            }
        }
    }

    /// Opens the device.
    fn open(&self, left: Duration) -> Result<Conn, String> {
        match &self.spec {
            LinkSpec::Serial { path } => {
                let path_str = path.to_string_lossy();
                serialport::new(path_str.as_ref(), self.baud)
                    .data_bits(DataBits::Eight)
                    .parity(Parity::None)
                    .stop_bits(StopBits::One)
                    .flow_control(FlowControl::None)
                    .timeout(self.policy.write_timeout)
                    .open_native()
                    .map(Conn::Serial)
                    .map_err(|e| format!("opening {}: {e}", path.display()))
            }
            LinkSpec::Tcp { host, port } => {
                let budget = self.policy.connect_timeout.min(left);
                if budget.is_zero() {
                    return Err("no time left to connect".to_owned());
                }
                let addrs: Vec<SocketAddr> = match host.parse::<IpAddr>() {
                    Ok(ip) => vec![SocketAddr::new(ip, *port)],
                    Err(_) => (host.as_str(), *port)
                        .to_socket_addrs()
                        .map_err(|e| format!("resolving {host}: {e}"))?
                        .collect(),
                };
                let mut last = format!("{host} resolved to no address");
                for addr in addrs {
                    match TcpStream::connect_timeout(&addr, budget) {
                        Ok(stream) => {
                            let setup = stream
                                .set_nodelay(true)
                                .and_then(|()| {
                                    stream.set_write_timeout(Some(self.policy.write_timeout))
                                })
                                .and_then(|()| stream.set_read_timeout(Some(budget)));
                            return match setup {
                                Ok(()) => Ok(Conn::Tcp {
                                    stream,
                                    read_timeout: budget,
                                }),
                                Err(e) => Err(format!("configuring socket to {addr}: {e}")),
                            };
                        }
                        Err(e) => last = format!("connecting to {addr}: {e}"),
                    }
                }
                Err(last)
            }
        }
    }

    /// Writes all of `bytes` (a command) to the device.
    ///
    /// # Errors
    /// [`LinkWriteError::NotConnected`] while down;
    /// [`LinkWriteError::Io`] when the write fails, which takes the link down.
    pub fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkWriteError> {
        let LinkInner::Up { conn, .. } = &mut self.inner else {
            return Err(LinkWriteError::NotConnected);
        };
        match write_conn(conn, bytes) {
            Ok(()) => {
                self.stats.bytes_written =
                    self.stats.bytes_written.saturating_add(bytes.len() as u64);
                Ok(())
            }
            Err(e) => {
                let why = format!("write: {e}");
                self.go_down(&why);
                Err(LinkWriteError::Io(why))
            }
        }
    }
}

/// One read of a serial port: poll, then read. Not serialport's own read,
/// whose timeout builds an error with text (six allocations) and which
/// drops the bytes still buffered when the device hangs up.
fn serial_read(fd: RawFd, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
    let ms = timeout.as_nanos().div_ceil(1_000_000);
    let ms = c_int::try_from(ms).unwrap_or(c_int::MAX);
    let mut fds = [PollFd::new(fd, PollFlags::POLLIN)];
    match poll(&mut fds, ms) {
        Ok(0) | Err(Errno::EINTR) => return Err(io::ErrorKind::TimedOut.into()),
        Ok(_) => {}
        Err(e) => return Err(e.into()),
    }
    let revents = fds
        .first()
        .and_then(|f| f.revents())
        .unwrap_or(PollFlags::empty());
    if revents.contains(PollFlags::POLLIN) {
        return nix::unistd::read(fd, buf).map_err(io::Error::from);
    }
    if revents.intersects(PollFlags::POLLHUP | PollFlags::POLLERR | PollFlags::POLLNVAL) {
        return Err(io::ErrorKind::BrokenPipe.into());
    }
    Err(io::ErrorKind::TimedOut.into())
}

fn write_conn(conn: &mut Conn, bytes: &[u8]) -> io::Result<()> {
    match conn {
        Conn::Serial(port) => {
            port.write_all(bytes)?;
            port.flush()
        }
        Conn::Tcp { stream, .. } => stream.write_all(bytes),
    }
}

/// Closes a connection (a TCP one is shut down first so the server sees
/// the end at once even if the descriptor were shared).
fn close(conn: Conn) {
    match conn {
        Conn::Serial(port) => drop(port),
        Conn::Tcp { stream, .. } => {
            let _ = stream.shutdown(std::net::Shutdown::Both);
        }
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        let old = std::mem::replace(
            &mut self.inner,
            LinkInner::Down {
                since_ns: 0,
                attempts: 0,
                next_attempt_ns: 0,
            },
        );
        if let LinkInner::Up { conn, .. } = old {
            close(conn);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_serial_and_tcp() {
        assert_eq!(
            "serial:/dev/ttyUSB0".parse::<LinkSpec>(),
            Ok(LinkSpec::Serial {
                path: PathBuf::from("/dev/ttyUSB0")
            })
        );
        assert_eq!(
            "tcp:rtls.local:25000".parse::<LinkSpec>(),
            Ok(LinkSpec::Tcp {
                host: "rtls.local".to_owned(),
                port: 25000
            })
        );
        assert_eq!(
            "tcp:[::1]:9".parse::<LinkSpec>(),
            Ok(LinkSpec::Tcp {
                host: "::1".to_owned(),
                port: 9
            })
        );
        for s in ["serial:/dev/ttyACM0", "tcp:10.0.0.2:80", "tcp:[::1]:9"] {
            assert_eq!(
                s.parse::<LinkSpec>().map(|l| l.to_string()),
                Ok(s.to_owned())
            );
        }
    }

    #[test]
    fn errors_name_the_bad_part() {
        let cases = [
            (
                "/dev/ttyUSB0",
                LinkSpecError::MissingScheme("/dev/ttyUSB0".to_owned()),
            ),
            ("udp:x:1", LinkSpecError::UnknownScheme("udp".to_owned())),
            ("serial:", LinkSpecError::EmptyPath),
            ("tcp:host", LinkSpecError::MissingPort("host".to_owned())),
            ("tcp:host:99999", LinkSpecError::BadPort("99999".to_owned())),
            ("tcp:host:0", LinkSpecError::BadPort("0".to_owned())),
            ("tcp:h:http", LinkSpecError::BadPort("http".to_owned())),
            ("tcp::80", LinkSpecError::EmptyHost),
        ];
        for (text, want) in cases {
            assert_eq!(text.parse::<LinkSpec>(), Err(want), "{text}");
        }
        let shown = "tcp:h:http"
            .parse::<LinkSpec>()
            .err()
            .map(|e| e.to_string());
        assert!(shown.is_some_and(|e| e.contains("\"http\"")));
    }

    #[test]
    fn backoff_doubles_then_caps() {
        let p = ReconnectPolicy {
            initial_backoff: Duration::from_millis(10),
            max_backoff: Duration::from_millis(70),
            ..ReconnectPolicy::default()
        };
        let waits: Vec<u128> = (0..8).map(|k| p.backoff(k).as_millis()).collect();
        assert_eq!(waits, [10, 10, 20, 40, 70, 70, 70, 70]);
        assert_eq!(p.backoff(u32::MAX), Duration::from_millis(70));
    }

    #[test]
    fn policy_is_checked() {
        fn clock() -> u64 {
            0
        }
        let spec = LinkSpec::Serial {
            path: PathBuf::from("/nonexistent"),
        };
        let bad = ReconnectPolicy {
            initial_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_millis(10),
            ..ReconnectPolicy::default()
        };
        assert!(matches!(
            Link::new(spec.clone(), 9600, bad, Vec::new(), clock),
            Err(LinkConfigError::MaxBelowInitial { .. })
        ));
        let zero = ReconnectPolicy {
            initial_backoff: Duration::ZERO,
            ..ReconnectPolicy::default()
        };
        assert_eq!(
            Link::new(spec, 9600, zero, Vec::new(), clock).err(),
            Some(LinkConfigError::ZeroBackoff)
        );
    }
}
