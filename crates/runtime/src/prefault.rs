//! Paging in a stage's iceoryx2 shared memory ahead of use.
//!
//! iceoryx2 maps each publisher's data segment (megabytes: the pool holds the
//! history, every subscriber's buffer and the loans) into the publisher and
//! into every subscriber, and hands out its chunks in turn. Without help, each
//! page of a segment is faulted in when a sample first lands on it, on the
//! 10 Hz path, for as long as the first pass through the pool lasts (minutes
//! for the IMU topic): one fault every few samples in every stage, each a few
//! microseconds, and in a virtual machine sometimes far more. [`ShmPrefault`]
//! finds the mappings of the deployment's files (`/dev/shm/<prefix>*`) in
//! `/proc/self/maps` and populates them with `madvise(MADV_POPULATE_WRITE)`
//! (writable) or `MADV_POPULATE_READ` (read-only mappings of other
//! processes' segments) once each, before the samples need them. A scan
//! allocates nothing: the maps are read into a buffer made at construction.
//! The heartbeat drives it ([`crate::HealthReporter`]): every heartbeat for
//! the first seconds (while the neighbours' segments are being mapped), then
//! every few seconds (a restarted neighbour's new segment).

use crate::monotonic_ns;

/// Size of the buffer `/proc/self/maps` is read into (a stage has a few
/// hundred mappings, about 100 bytes each); a longer file is scanned up to it.
pub const MAPS_BUFFER: usize = 256 * 1024;

/// Mappings remembered as populated (more are populated again when seen).
const DONE_SLOTS: usize = 256;

/// Scans in the first [`EARLY_NS`] after construction: at every call.
const EARLY_NS: u64 = 5_000_000_000;
/// Later, at most one scan per this period.
const LATE_PERIOD_NS: u64 = 5_000_000_000;

/// Why a scan failed.
#[derive(Debug, thiserror::Error)]
pub enum PrefaultError {
    /// `/proc/self/maps` could not be read.
    #[error("cannot read /proc/self/maps: {0}")]
    Maps(std::io::Error),
    /// The kernel does not know `MADV_POPULATE_*` (Linux before 5.14):
    /// pages are faulted in on first use, as without the prefault.
    #[error("madvise(MADV_POPULATE_*) is not supported by this kernel: {0}")]
    Unsupported(std::io::Error),
}

/// What one scan did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PrefaultReport {
    /// Mappings of the deployment's files seen.
    pub mappings: usize,
    /// Of those, populated by this scan (not seen before).
    pub populated: usize,
    /// Bytes populated by this scan.
    pub bytes: usize,
}

/// Populates the deployment's shared-memory mappings of this process (see
/// the module documentation).
#[derive(Debug)]
pub struct ShmPrefault {
    /// `/dev/shm/<prefix>` as bytes.
    path_prefix: Vec<u8>,
    buf: Vec<u8>,
    /// `(start, end, inode)` of mappings populated already.
    done: [(usize, usize, u64); DONE_SLOTS],
    n_done: usize,
    next_slot: usize,
    created_ns: u64,
    next_ns: u64,
    disabled: bool,
}

impl ShmPrefault {
    /// A prefaulter for the files of service prefix `prefix`.
    #[must_use]
    pub fn new(prefix: &str) -> Self {
        let mut path_prefix = b"/dev/shm/".to_vec();
        path_prefix.extend_from_slice(prefix.as_bytes());
        let now = monotonic_ns();
        Self {
            path_prefix,
            buf: vec![0; MAPS_BUFFER],
            done: [(0, 0, 0); DONE_SLOTS],
            n_done: 0,
            next_slot: 0,
            created_ns: now,
            next_ns: now,
            disabled: false,
        }
    }

    /// Scans when one is due (every call in the first seconds, then every
    /// few seconds); `Ok(None)` when none was due. After
    /// [`PrefaultError::Unsupported`] it never scans again.
    pub fn run_if_due(&mut self, now_ns: u64) -> Result<Option<PrefaultReport>, PrefaultError> {
        if self.disabled || now_ns < self.next_ns {
            return Ok(None);
        }
        self.next_ns = if now_ns.saturating_sub(self.created_ns) < EARLY_NS {
            now_ns
        } else {
            now_ns.saturating_add(LATE_PERIOD_NS)
        };
        self.run().map(Some)
    }

    /// Populates every mapping of the deployment's files not populated yet.
    pub fn run(&mut self) -> Result<PrefaultReport, PrefaultError> {
        let len = read_maps(&mut self.buf).map_err(PrefaultError::Maps)?;
        let mut report = PrefaultReport::default();
        let mut first_error = None;
        let text = self.buf.get(..len).unwrap_or_default();
        // Only whole lines: a buffer cut mid-line leaves the rest for later.
        let whole = text
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(&[][..], |i| text.get(..=i).unwrap_or_default());
        let mut found: [(usize, usize, u64, bool); 64] = [(0, 0, 0, false); 64];
        let mut n_found = 0usize;
        for line in whole.split(|&b| b == b'\n') {
            let Some(m) = parse_line(line, &self.path_prefix) else {
                continue;
            };
            report.mappings += 1;
            if let Some(slot) = found.get_mut(n_found) {
                *slot = m;
                n_found += 1;
            }
        }
        for &(start, end, inode, writable) in found.iter().take(n_found) {
            let key = (start, end, inode);
            if self.done.iter().take(self.n_done).any(|d| *d == key) {
                continue;
            }
            match populate(start, end - start, writable) {
                Ok(()) => {
                    report.populated += 1;
                    report.bytes += end - start;
                    self.remember(key);
                }
                Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
                    self.disabled = true;
                    return Err(PrefaultError::Unsupported(e));
                }
                // Unmapped meanwhile, or not populatable: tried again next scan.
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
        if let Some(e) = first_error {
            tracing::debug!("prefault: a mapping could not be populated: {e}");
        }
        Ok(report)
    }

    fn remember(&mut self, key: (usize, usize, u64)) {
        if self.n_done < DONE_SLOTS {
            if let Some(d) = self.done.get_mut(self.n_done) {
                *d = key;
            }
            self.n_done += 1;
        } else {
            if let Some(d) = self.done.get_mut(self.next_slot) {
                *d = key;
            }
            self.next_slot = (self.next_slot + 1) % DONE_SLOTS;
        }
    }
}

/// Reads `/proc/self/maps` into `buf`; the bytes read.
fn read_maps(buf: &mut [u8]) -> std::io::Result<usize> {
    // SAFETY: a NUL-terminated path; the descriptor is closed below.
    #[allow(unsafe_code)]
    let fd = unsafe {
        libc::open(
            c"/proc/self/maps".as_ptr(),
            libc::O_RDONLY | libc::O_CLOEXEC,
        )
    };
    if fd < 0 {
        return Err(std::io::Error::last_os_error());
    }
    let mut len = 0usize;
    let result = loop {
        let Some(rest) = buf.get_mut(len..) else {
            break Ok(len);
        };
        if rest.is_empty() {
            break Ok(len);
        }
        // SAFETY: `rest` is valid for writes of its length.
        #[allow(unsafe_code)]
        let n = unsafe { libc::read(fd, rest.as_mut_ptr().cast(), rest.len()) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            break Err(e);
        }
        if n == 0 {
            break Ok(len);
        }
        len += usize::try_from(n).unwrap_or(0);
    };
    // SAFETY: `fd` is owned here and closed once.
    #[allow(unsafe_code)]
    unsafe {
        libc::close(fd);
    }
    result
}

/// `(start, end, inode, writable)` of a maps line naming a file that starts
/// with `path_prefix`.
fn parse_line(line: &[u8], path_prefix: &[u8]) -> Option<(usize, usize, u64, bool)> {
    let mut fields = line.split(|&b| b == b' ').filter(|f| !f.is_empty());
    let range = fields.next()?;
    let perms = fields.next()?;
    let _offset = fields.next()?;
    let _dev = fields.next()?;
    let inode = fields.next()?;
    let path = fields.next()?;
    if !path.starts_with(path_prefix) {
        return None;
    }
    let dash = range.iter().position(|&b| b == b'-')?;
    let start = hex(range.get(..dash)?)?;
    let end = hex(range.get(dash + 1..)?)?;
    let inode = core::str::from_utf8(inode).ok()?.parse().ok()?;
    (end > start).then_some((start, end, inode, perms.get(1) == Some(&b'w')))
}

fn hex(s: &[u8]) -> Option<usize> {
    usize::from_str_radix(core::str::from_utf8(s).ok()?, 16).ok()
}

fn populate(start: usize, len: usize, writable: bool) -> std::io::Result<()> {
    let advice = if writable {
        libc::MADV_POPULATE_WRITE
    } else {
        libc::MADV_POPULATE_READ
    };
    // SAFETY: the range is a whole mapping of this process as listed by the
    // kernel; populating changes no content (a write-populate maps pages
    // writable without writing to them). A range unmapped since the listing
    // fails with ENOMEM, reported.
    #[allow(unsafe_code)]
    let rc = unsafe { libc::madvise(start as *mut libc::c_void, len, advice) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_lines_of_the_prefix_are_parsed_with_their_access() {
        let p = b"/dev/shm/insuwb_x_";
        let rw = b"7f3a1c000000-7f3a1c9b8000 rw-s 00000000 00:1a 1234                       /dev/shm/insuwb_x_0354a2";
        assert_eq!(
            parse_line(rw, p),
            Some((0x7f3a_1c00_0000, 0x7f3a_1c9b_8000, 1234, true))
        );
        let ro = b"7f3a1c000000-7f3a1c001000 r--s 00000000 00:1a 99 /dev/shm/insuwb_x_b9fc";
        assert_eq!(parse_line(ro, p).map(|m| m.3), Some(false));
        let other = b"7f3a1c000000-7f3a1c001000 rw-s 00000000 00:1a 99 /dev/shm/insuwb_y_b9fc";
        assert_eq!(parse_line(other, p), None);
        assert_eq!(parse_line(b"55d0-55e0 r-xp 0 08:01 5 /usr/bin/x", p), None);
        assert_eq!(parse_line(b"garbage", p), None);
        assert_eq!(parse_line(b"", p), None);
    }

    #[test]
    fn a_mapping_of_the_prefix_is_populated_once() {
        let prefix = format!("insuwb_prefault{}_", std::process::id());
        let path = format!("/dev/shm/{prefix}seg");
        let size = 1 << 20;
        let f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&path)
            .unwrap();
        f.set_len(size as u64).unwrap();
        use std::os::fd::AsRawFd;
        // SAFETY: a fresh shared mapping of a file this test owns.
        #[allow(unsafe_code)]
        let addr = unsafe {
            libc::mmap(
                core::ptr::null_mut(),
                size,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                f.as_raw_fd(),
                0,
            )
        };
        assert_ne!(addr, libc::MAP_FAILED);
        let mut pf = ShmPrefault::new(&prefix);
        let first = pf.run().unwrap();
        assert_eq!(
            first,
            PrefaultReport {
                mappings: 1,
                populated: 1,
                bytes: size
            }
        );
        let second = pf.run().unwrap();
        assert_eq!((second.mappings, second.populated), (1, 0));
        // SAFETY: the mapping made above, unmapped once.
        #[allow(unsafe_code)]
        unsafe {
            libc::munmap(addr, size);
        }
        drop(f);
        std::fs::remove_file(&path).unwrap();
    }
}
