//! A stage's checkpoint file: TOML in the run directory, written whole
//! (a temporary file renamed over the old one, so a reader never sees half a
//! checkpoint) and read back by the stage's next generation. A stage hands
//! its checkpoints to a [`Writer`] thread, so that no file I/O happens on
//! its loop.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::{de::DeserializeOwned, Serialize};

/// Writes `value` to `path` through `path` with the extension `tmp`.
///
/// # Errors
/// Serialisation, or the file cannot be written or renamed (the message names it).
pub fn write<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, toml::to_string(value)?).with_context(|| format!("{}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("{}", path.display()))?;
    Ok(())
}

/// The checkpoint at `path`; `None` when it is missing or does not parse.
#[must_use]
pub fn read<T: DeserializeOwned>(path: &Path) -> Option<T> {
    toml::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

/// The checkpoint writer thread and the stage's end of its channel (one
/// message deep): the stage offers fixed-size messages `M`, the thread
/// turns each into the checkpoint (`make`, where any allocation happens)
/// and writes it. A message offered while the previous one is still being
/// written is skipped.
#[derive(Debug)]
pub struct Writer<M> {
    tx: crossbeam_channel::Sender<M>,
    thread: std::thread::JoinHandle<()>,
}

impl<M: Send + 'static> Writer<M> {
    /// Starts the thread writing to `path`.
    ///
    /// # Errors
    /// The thread cannot be started.
    pub fn spawn<T: Serialize>(
        path: PathBuf,
        make: impl Fn(M) -> T + Send + 'static,
    ) -> Result<Self> {
        let (tx, rx) = crossbeam_channel::bounded::<M>(1);
        let thread = std::thread::Builder::new()
            .name("checkpoint".into())
            .spawn(move || {
                for m in rx {
                    if let Err(e) = write(&path, &make(m)) {
                        tracing::warn!("checkpoint: {e:#}");
                    }
                }
            })
            .context("starting the checkpoint writer thread")?;
        Ok(Self { tx, thread })
    }

    /// Offers a checkpoint; skipped while the previous one is being written.
    pub fn offer(&self, m: M) {
        let _ = self.tx.try_send(m);
    }

    /// Closes the channel and waits for the last checkpoint to be written.
    pub fn finish(self) {
        drop(self.tx);
        if self.thread.join().is_err() {
            tracing::warn!("the checkpoint writer thread panicked");
        }
    }
}
