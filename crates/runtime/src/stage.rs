//! The stage: one iceoryx2 node with the deployment's prefix and root folder,
//! its identity (name, generation, source id) and the factory of its ports,
//! wait loop and heartbeat.

use core::fmt::Debug;
use core::time::Duration;
use std::path::Path as StdPath;

use iceoryx2::config::Config;
use iceoryx2::node::NodeCreationFailure;
use iceoryx2::prelude::*;
use insuwb_msg::HasHeader;

use crate::cleanup::{cleanup_dead_nodes_of, CleanupError};
use crate::config::{RuntimeConfig, RuntimeConfigError, GENERATION_ENV};
use crate::health::HealthReporter;
use crate::port::{PortError, Pub, Sub};
use crate::waiter::{WaitError, Waiter};

/// Why [`Stage::new`] failed.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    /// The configuration did not validate.
    #[error(transparent)]
    Config(#[from] RuntimeConfigError),
    /// iceoryx2 rejected a value of the configuration.
    #[error("iceoryx2 rejected runtime.{key} = {value:?}")]
    IceoryxConfig {
        /// The configuration key.
        key: &'static str,
        /// The rejected value.
        value: String,
    },
    /// The root folder could not be created.
    #[error("cannot create runtime.root_path {path:?}: {error}")]
    RootPath {
        /// The folder.
        path: String,
        /// The I/O error.
        error: std::io::Error,
    },
    /// `INSUWB_GENERATION` is set but is not a u32.
    #[error("{GENERATION_ENV} must be an unsigned 32-bit integer, got {0:?}")]
    GenerationEnv(String),
    /// The iceoryx2 node could not be created.
    #[error("cannot create iceoryx2 node {name:?}: {error}")]
    Node {
        /// The stage name.
        name: String,
        /// iceoryx2's reason.
        error: NodeCreationFailure,
    },
    /// The SIGINT/SIGTERM handler could not be installed.
    #[error(transparent)]
    Signal(#[from] crate::signal::SignalError),
    /// SIGINT or SIGTERM arrived while the stage was starting: the caller
    /// should exit cleanly (status 0).
    #[error("shutdown requested (SIGINT/SIGTERM) while starting stage {0:?}")]
    ShutdownRequested(String),
    /// The configured CPU affinity or SCHED_FIFO priority was refused.
    #[error("stage {stage:?}: real-time setting refused: {error}")]
    Realtime {
        /// The stage.
        stage: String,
        /// What was refused.
        error: crate::realtime::RealtimeError,
    },
}

/// SIGINT or SIGTERM was received: the stage should stop and exit 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("shutdown requested (SIGINT/SIGTERM)")]
pub struct Shutdown;

/// One stage of the pipeline: an iceoryx2 node and its identity.
///
/// Creating a stage installs iceoryx2's SIGINT/SIGTERM handler for the process:
/// from then on those signals no longer kill it, they are reported by
/// [`Waiter::wait`] ([`crate::Wake::Shutdown`]), [`Stage::sleep`] and
/// [`Stage::shutdown_requested`], and the stage must check one of them and return.
/// (iceoryx2 captures SIGQUIT, SIGTSTP, SIGCONT, SIGUSR1 and a few others the
/// same way: they no longer stop the process; the waiter ignores them.)
pub struct Stage {
    cfg: RuntimeConfig,
    iox: Config,
    node: Node<crate::service::Ipc>,
    generation: u32,
    source_id: u16,
}

impl Debug for Stage {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Stage")
            .field("name", &self.cfg.stage_name)
            .field("prefix", &self.cfg.prefix)
            .field("root_path", &self.cfg.root_path)
            .field("generation", &self.generation)
            .field("source_id", &self.source_id)
            .finish_non_exhaustive()
    }
}

/// Builds the iceoryx2 configuration (prefix, root folder) of `cfg`; does not
/// touch the file system.
pub fn iceoryx_config(cfg: &RuntimeConfig) -> Result<Config, StageError> {
    cfg.validate()?;
    let mut iox = Config::default();
    iox.global.prefix =
        FileName::new(cfg.prefix.as_bytes()).map_err(|_| StageError::IceoryxConfig {
            key: "prefix",
            value: cfg.prefix.clone(),
        })?;
    if let Some(root) = &cfg.root_path {
        let text = root.to_string_lossy().into_owned();
        // iceoryx2 joins entries onto the root: give it a trailing separator.
        let with_sep = if text.ends_with('/') {
            text.clone()
        } else {
            format!("{text}/")
        };
        let path = Path::new(with_sep.as_bytes()).map_err(|_| StageError::IceoryxConfig {
            key: "root_path",
            value: text,
        })?;
        iox.global.set_root_path(&path);
    }
    Ok(iox)
}

/// The generation to stamp: the configured one, else [`GENERATION_ENV`], else 0.
fn resolve_generation(cfg: &RuntimeConfig) -> Result<u32, StageError> {
    if let Some(g) = cfg.generation {
        return Ok(g);
    }
    match std::env::var(GENERATION_ENV) {
        Ok(v) => v
            .trim()
            .parse::<u32>()
            .map_err(|_| StageError::GenerationEnv(v)),
        Err(std::env::VarError::NotPresent) => Ok(0),
        Err(std::env::VarError::NotUnicode(v)) => {
            Err(StageError::GenerationEnv(v.to_string_lossy().into_owned()))
        }
    }
}

impl Stage {
    /// Validates `cfg`, builds the iceoryx2 configuration, sets the process
    /// umask to 0o077 (a root folder it creates is 0700, [`crate::perm`]),
    /// removes the resources of dead nodes of that configuration, creates the
    /// node named after the stage (then narrows iceoryx2's world-writable
    /// global management segment to 0600) and installs the SIGINT/SIGTERM
    /// handler.
    pub fn new(cfg: RuntimeConfig) -> Result<Self, StageError> {
        let iox = iceoryx_config(&cfg)?;
        let generation = resolve_generation(&cfg)?;
        crate::perm::restrict_umask();
        cfg.realtime
            .apply()
            .map_err(|source| StageError::Realtime {
                stage: cfg.stage_name.clone(),
                error: source,
            })?;
        if let Some(root) = &cfg.root_path {
            // Created now under the umask: 0700. An existing folder is left as
            // it is (it may be shared on purpose), with a warning when others
            // can reach into it.
            let existed = root.is_dir();
            std::fs::create_dir_all(root).map_err(|source| StageError::RootPath {
                path: root.to_string_lossy().into_owned(),
                error: source,
            })?;
            if existed && crate::perm::is_shared(root) {
                tracing::warn!(stage = %cfg.stage_name, "the iceoryx2 root {} has group or other permission bits", root.display());
            }
        }
        match cleanup_dead_nodes_of(&iox) {
            Ok(0) => {}
            Ok(n) => {
                tracing::info!(stage = %cfg.stage_name, removed = n, "removed dead iceoryx2 nodes")
            }
            Err(CleanupError::List(e)) => {
                tracing::warn!(stage = %cfg.stage_name, error = %e, "cannot list iceoryx2 nodes");
            }
            Err(e) => tracing::warn!(stage = %cfg.stage_name, error = %e, "dead node cleanup"),
        }
        let name = NodeName::new(&cfg.stage_name).map_err(|_| StageError::IceoryxConfig {
            key: "stage_name",
            value: cfg.stage_name.clone(),
        })?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(&iox)
            .create::<crate::service::Ipc>()
            .map_err(|source| StageError::Node {
                name: cfg.stage_name.clone(),
                error: source,
            })?;
        // iceoryx2 makes its global management segment world-writable.
        let suffix = String::from_utf8_lossy(iox.global.node.global_mgmt_suffix.as_bytes());
        if let Err(e) = crate::perm::restrict_global_segment(&cfg.prefix, &suffix) {
            tracing::warn!(stage = %cfg.stage_name, "{e}");
        }
        // iceoryx2's signal handler, then ours in front of it (a request
        // iceoryx2 recorded already counts).
        crate::signal::install()?;
        if crate::signal::termination_requested() {
            return Err(StageError::ShutdownRequested(cfg.stage_name.clone()));
        }
        let source_id = cfg.effective_source_id();
        tracing::debug!(stage = %cfg.stage_name, generation, source_id, prefix = %cfg.prefix, "stage started");
        Ok(Self {
            cfg,
            iox,
            node,
            generation,
            source_id,
        })
    }

    /// A publisher on `topic` with the topic's QoS, stamping this stage's
    /// generation and source id.
    pub fn publisher<T>(&self, topic: &str) -> Result<Pub<T>, PortError>
    where
        T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
    {
        Pub::create(&self.node, topic, self.generation, self.source_id)
    }

    /// A subscriber on `topic` with the topic's QoS (requesting its full history).
    pub fn subscriber<T>(&self, topic: &str) -> Result<Sub<T>, PortError>
    where
        T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
    {
        Sub::create(&self.node, topic)
    }

    /// The stage's wait loop: a [`Waiter`] (an epoll set over subscribers'
    /// listeners and interval timers), busy-polling when `busy_poll` is set.
    pub fn waiter(&self) -> Result<Waiter, WaitError> {
        Waiter::new(self.cfg.busy_poll)
    }

    /// The heartbeat publisher on topic `health`, at `heartbeat_period_s`.
    pub fn health_reporter(&self) -> Result<HealthReporter, PortError> {
        Ok(HealthReporter::new(
            self.publisher(insuwb_msg::topics::HEALTH)?,
            &self.cfg.stage_name,
            Duration::from_secs_f64(self.cfg.heartbeat_period_s),
            &self.cfg.prefix,
        ))
    }

    /// `Err(Shutdown)` once SIGINT or SIGTERM was received (for stages that
    /// loop without a [`Waiter`]).
    pub fn shutdown_requested(&self) -> Result<(), Shutdown> {
        self.sleep(Duration::ZERO)
    }

    /// Sleeps for `d`; `Err(Shutdown)` when SIGINT or SIGTERM arrived before
    /// or during the sleep.
    pub fn sleep(&self, d: Duration) -> Result<(), Shutdown> {
        // The stage installed the handler (Stage::new): the sleep ends at once on termination.
        if crate::signal::sleep(d) {
            Err(Shutdown)
        } else {
            Ok(())
        }
    }

    /// The stage name (also the node name).
    #[must_use]
    pub fn name(&self) -> &str {
        &self.cfg.stage_name
    }

    /// The start generation this stage stamps.
    #[must_use]
    pub fn generation(&self) -> u32 {
        self.generation
    }

    /// The source id this stage stamps.
    #[must_use]
    pub fn source_id(&self) -> u16 {
        self.source_id
    }

    /// The configuration the stage was built from.
    #[must_use]
    pub fn config(&self) -> &RuntimeConfig {
        &self.cfg
    }

    /// The iceoryx2 configuration in use.
    #[must_use]
    pub fn iceoryx_config(&self) -> &Config {
        &self.iox
    }

    /// The iceoryx2 root folder in use.
    #[must_use]
    pub fn root_path(&self) -> &StdPath {
        let bytes = self.iox.global.root_path().as_bytes();
        StdPath::new(core::str::from_utf8(bytes).unwrap_or("/tmp/iceoryx2/"))
    }
}
