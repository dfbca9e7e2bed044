//! Inspection and cleanup of a deployment's iceoryx2 resources: nodes
//! (alive/dead, pid), services (publisher/subscriber counts), removal of dead
//! nodes' resources and of a whole prefix's files.

use std::path::{Path as StdPath, PathBuf};

use iceoryx2::config::Config;
use iceoryx2::node::{NodeCreationFailure, NodeListFailure, NodeView};
use iceoryx2::prelude::*;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern as StaticPattern;
use iceoryx2::service::ServiceListError;
use insuwb_msg::topics;

use crate::config::{is_plain_name, RuntimeConfig, MAX_PREFIX_LEN};
use crate::port::{open_existing_event, open_existing_pubsub};
use crate::stage::{iceoryx_config, StageError};

/// Where iceoryx2 keeps shared memory.
pub const SHM_DIR: &str = "/dev/shm";

/// Why an inspection or cleanup failed.
#[derive(Debug, thiserror::Error)]
pub enum CleanupError {
    /// The configuration is not valid.
    #[error(transparent)]
    Config(#[from] StageError),
    /// The prefix would match more than one deployment's files.
    #[error("refusing to remove files of prefix {0:?}: must be 1..={MAX_PREFIX_LEN} ASCII letters, digits, '_' or '-'")]
    Prefix(String),
    /// iceoryx2 could not list the nodes.
    #[error("cannot list iceoryx2 nodes: {0}")]
    List(NodeListFailure),
    /// iceoryx2 could not list the services.
    #[error("cannot list iceoryx2 services: {0}")]
    ListServices(ServiceListError),
    /// The inspection node could not be created.
    #[error("cannot create the inspection node: {0}")]
    Node(NodeCreationFailure),
    /// A file or folder could not be read or removed.
    #[error("cannot remove {path:?}: {error}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The I/O error.
        error: std::io::Error,
    },
}

/// Liveness of a node as iceoryx2 sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeLiveness {
    /// Its process runs.
    Alive,
    /// Its process died without cleaning up (see [`cleanup_dead_nodes`]).
    Dead,
    /// This process may not inspect it.
    Inaccessible,
    /// Its records are inconsistent.
    Undefined,
}

/// One iceoryx2 node of a deployment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeInfo {
    /// iceoryx2's unique node id.
    pub id: String,
    /// Node (stage) name; empty when unknown.
    pub name: String,
    /// Owning process id (`None` when unknown).
    pub pid: Option<i32>,
    /// Executable of the owning process; empty when unknown.
    pub executable: String,
    /// Alive or dead.
    pub state: NodeLiveness,
}

/// Messaging pattern of a service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServiceKind {
    /// Publish-subscribe (a topic).
    PublishSubscribe,
    /// Event (a topic's wake-up service).
    Event,
    /// Request-response, blackboard or another pattern.
    Other,
}

/// One iceoryx2 service of a deployment (what `iox2 service` shows).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceInfo {
    /// Service name (a topic, or `<topic>.ev`).
    pub name: String,
    /// Messaging pattern.
    pub kind: ServiceKind,
    /// Nodes registered on it, with their liveness.
    pub nodes: Vec<(String, NodeLiveness)>,
    /// Publishers (publish-subscribe services of known topics; `None` otherwise).
    pub publishers: Option<usize>,
    /// Subscribers (as `publishers`).
    pub subscribers: Option<usize>,
    /// Notifiers (event services of known topics).
    pub notifiers: Option<usize>,
    /// Listeners (as `notifiers`).
    pub listeners: Option<usize>,
}

fn liveness<S: iceoryx2::service::Service>(s: &NodeState<S>) -> NodeLiveness {
    match s {
        NodeState::Alive(_) => NodeLiveness::Alive,
        NodeState::Dead(_) => NodeLiveness::Dead,
        NodeState::Inaccessible(_) => NodeLiveness::Inaccessible,
        NodeState::Undefined(_) => NodeLiveness::Undefined,
    }
}

fn node_info(state: &NodeState<crate::service::Ipc>) -> NodeInfo {
    let id = format!("{:?}", state.node_id());
    let details = match state {
        NodeState::Alive(v) => v.details().clone(),
        NodeState::Dead(v) => v.details().clone(),
        NodeState::Inaccessible(_) | NodeState::Undefined(_) => None,
    };
    let (name, pid, executable) = match details {
        Some(d) => (
            d.name().to_string(),
            Some(d.process_id().value()),
            d.executable().to_string(),
        ),
        None => (String::new(), None, String::new()),
    };
    NodeInfo {
        id,
        name,
        pid,
        executable,
        state: liveness(state),
    }
}

/// Every node of the deployment `cfg` (prefix and root path).
pub fn list_nodes(cfg: &RuntimeConfig) -> Result<Vec<NodeInfo>, CleanupError> {
    let iox = iceoryx_config(cfg)?;
    let mut out = Vec::new();
    Node::<crate::service::Ipc>::list(&iox, |state| {
        out.push(node_info(&state));
        CallbackProgression::Continue
    })
    .map_err(CleanupError::List)?;
    Ok(out)
}

/// Removes the resources of every dead node of `cfg`; returns how many were removed.
pub fn cleanup_dead_nodes(cfg: &RuntimeConfig) -> Result<usize, CleanupError> {
    cleanup_dead_nodes_of(&iceoryx_config(cfg)?)
}

pub(crate) fn cleanup_dead_nodes_of(iox: &Config) -> Result<usize, CleanupError> {
    let mut dead = Vec::new();
    Node::<crate::service::Ipc>::list(iox, |state| {
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    })
    .map_err(CleanupError::List)?;
    let mut removed = 0;
    for view in dead {
        let id = format!("{:?}", view.id());
        match view.try_remove_stale_resources() {
            Ok(()) => removed += 1,
            Err(e) => tracing::debug!(node = %id, error = %e, "dead node not removed"),
        }
    }
    Ok(removed)
}

/// The topics whose sample type this crate knows (for port counts).
const KNOWN_TOPICS: [&str; 10] = [
    topics::IMU,
    topics::UWB_TDOA,
    topics::UWB_FIX,
    topics::NAV,
    topics::FUSED,
    topics::DIAG,
    topics::CORRECTION,
    topics::HEALTH,
    topics::TRUTH,
    topics::BODY_VEL,
];

fn pubsub_counts(node: &Node<crate::service::Ipc>, topic: &str) -> Option<(usize, usize)> {
    use insuwb_msg::*;
    fn counts<T: ZeroCopySend + core::fmt::Debug + 'static>(
        node: &Node<crate::service::Ipc>,
        topic: &str,
    ) -> Option<(usize, usize)> {
        let svc = open_existing_pubsub::<T>(node, topic).ok()?.ok()?;
        let d = svc.dynamic_config();
        Some((d.number_of_publishers(), d.number_of_subscribers()))
    }
    match topic {
        topics::IMU => counts::<ImuSample>(node, topic),
        topics::UWB_TDOA => counts::<UwbTdoa>(node, topic),
        topics::UWB_FIX => counts::<UwbFix>(node, topic),
        topics::NAV => counts::<NavState>(node, topic),
        topics::FUSED => counts::<FusedState>(node, topic),
        topics::DIAG => counts::<FilterDiag>(node, topic),
        topics::CORRECTION => counts::<InsCorrection>(node, topic),
        topics::HEALTH => counts::<Health>(node, topic),
        topics::TRUTH => counts::<GroundTruth>(node, topic),
        topics::BODY_VEL => counts::<BodyVelocity>(node, topic),
        _ => None,
    }
}

fn event_counts(node: &Node<crate::service::Ipc>, topic: &str) -> Option<(usize, usize)> {
    let svc = open_existing_event(node, topic).ok()?.ok()?;
    let d = svc.dynamic_config();
    Some((d.number_of_notifiers(), d.number_of_listeners()))
}

/// Every service of the deployment `cfg`, with its nodes and, for the
/// project's topics, port counts. Opening a service to count its ports needs
/// a node: a short-lived node named `insuwb-inspect` is created (and counted
/// in the node lists of the services while it lives).
pub fn list_services(cfg: &RuntimeConfig) -> Result<Vec<ServiceInfo>, CleanupError> {
    let iox = iceoryx_config(cfg)?;
    let mut out = Vec::new();
    <crate::service::Ipc as iceoryx2::service::Service>::list(&iox, |details| {
        let sc = &details.static_details;
        let kind = match sc.messaging_pattern() {
            StaticPattern::PublishSubscribe(_) => ServiceKind::PublishSubscribe,
            StaticPattern::Event(_) => ServiceKind::Event,
            _ => ServiceKind::Other,
        };
        let nodes = details
            .dynamic_details
            .as_ref()
            .map(|d| {
                d.nodes
                    .iter()
                    .map(|n| (format!("{:?}", n.node_id()), liveness(n)))
                    .collect()
            })
            .unwrap_or_default();
        out.push(ServiceInfo {
            name: sc.name().to_string(),
            kind,
            nodes,
            publishers: None,
            subscribers: None,
            notifiers: None,
            listeners: None,
        });
        CallbackProgression::Continue
    })
    .map_err(CleanupError::ListServices)?;

    let wants_counts = out.iter().any(|s| topic_of(s).is_some());
    if wants_counts {
        let name = NodeName::new("insuwb-inspect").map_err(|_| {
            CleanupError::Config(StageError::IceoryxConfig {
                key: "stage_name",
                value: "insuwb-inspect".into(),
            })
        })?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(&iox)
            .create::<crate::service::Ipc>()
            .map_err(CleanupError::Node)?;
        for s in &mut out {
            let Some(topic) = topic_of(s) else { continue };
            match s.kind {
                ServiceKind::PublishSubscribe => {
                    if let Some((p, q)) = pubsub_counts(&node, &topic) {
                        s.publishers = Some(p);
                        s.subscribers = Some(q);
                    }
                }
                ServiceKind::Event => {
                    if let Some((n, l)) = event_counts(&node, &topic) {
                        s.notifiers = Some(n);
                        s.listeners = Some(l);
                    }
                }
                ServiceKind::Other => {}
            }
        }
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(out)
}

/// The project topic a service belongs to (its own name, or `<topic>.ev`).
fn topic_of(s: &ServiceInfo) -> Option<String> {
    let base = match s.kind {
        ServiceKind::PublishSubscribe => s.name.as_str(),
        ServiceKind::Event => s.name.strip_suffix(".ev")?,
        ServiceKind::Other => return None,
    };
    KNOWN_TOPICS
        .iter()
        .find(|t| **t == base)
        .map(|t| (*t).to_owned())
}

/// What [`remove_prefix_files`] removed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Removed {
    /// Files removed from `/dev/shm`.
    pub shm_files: usize,
    /// Files removed under the root folder.
    pub root_files: usize,
}

/// Removes every file of `prefix`: `/dev/shm/<prefix>*` and, under the
/// iceoryx2 root folder (`root_path`, or iceoryx2's default `/tmp/iceoryx2/`),
/// every file whose name starts with `prefix` (and the node folders this
/// empties); a given `root_path` is then removed as a whole if it is left
/// empty. For a test run's or a stopped group's files only: live processes of
/// that prefix lose their resources.
///
/// Even after every stage of a prefix shut down cleanly, iceoryx2 0.10 leaves
/// one segment, `/dev/shm/<prefix><hash>_node.<version>.global_mgmt`, and the
/// empty `nodes/` and `services/` folders of the root: this removes them.
pub fn remove_prefix_files(
    prefix: &str,
    root_path: Option<&StdPath>,
) -> Result<Removed, CleanupError> {
    if !is_plain_name(prefix, MAX_PREFIX_LEN) {
        return Err(CleanupError::Prefix(prefix.to_owned()));
    }
    let mut removed = Removed {
        shm_files: remove_matching(StdPath::new(SHM_DIR), prefix, false)?,
        root_files: 0,
    };
    let root = root_path.unwrap_or(StdPath::new("/tmp/iceoryx2"));
    if root.exists() {
        removed.root_files = remove_matching(root, prefix, true)?;
        if root_path.is_some() {
            remove_empty_dirs(root)?;
        }
    }
    Ok(removed)
}

fn io_err(path: &StdPath) -> impl FnOnce(std::io::Error) -> CleanupError + '_ {
    move |source| CleanupError::Io {
        path: path.to_path_buf(),
        error: source,
    }
}

/// Removes the files directly in `dir` (and below, with `recursive`) whose name
/// starts with `prefix`; returns how many.
fn remove_matching(dir: &StdPath, prefix: &str, recursive: bool) -> Result<usize, CleanupError> {
    let mut n = 0;
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(io_err(dir)(e)),
    };
    for entry in entries {
        let entry = entry.map_err(io_err(dir))?;
        let path = entry.path();
        let ft = entry.file_type().map_err(io_err(&path))?;
        if ft.is_dir() {
            if recursive {
                let k = remove_matching(&path, prefix, true)?;
                if k > 0 {
                    // A node folder emptied by this removal goes too (fails,
                    // harmlessly, when other prefixes' files remain).
                    let _ = std::fs::remove_dir(&path);
                }
                n += k;
            }
            continue;
        }
        if entry.file_name().to_string_lossy().starts_with(prefix) {
            match std::fs::remove_file(&path) {
                Ok(()) => n += 1,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(io_err(&path)(e)),
            }
        }
    }
    Ok(n)
}

/// Removes `dir` and its sub-folders bottom-up where they are empty.
fn remove_empty_dirs(dir: &StdPath) -> Result<(), CleanupError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io_err(dir)(e)),
    };
    for entry in entries {
        let entry = entry.map_err(io_err(dir))?;
        if entry.file_type().map_err(io_err(dir))?.is_dir() {
            remove_empty_dirs(&entry.path())?;
        }
    }
    match std::fs::remove_dir(dir) {
        Ok(()) => Ok(()),
        // Not empty (another prefix's files) or already gone.
        Err(_) => Ok(()),
    }
}
