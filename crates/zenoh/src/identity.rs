//! A robot speaks only for itself: the station's `[station.identity]`,
//! turned into Zenoh's access control at the station's router, and the
//! refusals that access control makes, counted.
//!
//! With `robots = ["r1", "r2"]` a peer whose TLS client certificate has the
//! common name `r1` (what `tools/fleet_certs.sh` writes) may put and delete
//! only under `insuwb/r1/**`; its other puts are dropped at the router, and
//! a peer whose certificate names no listed robot (or that has none) gets
//! nothing through at all. `loopback_robots` lists robots allowed without
//! TLS, only over plain TCP on the loopback interface (a simulator or a
//! test bench on the station's machine). Declarations, queries and
//! liveliness pass for the listed robots, and everything the station sends
//! goes out. The JSON is generated here ([`IdentitySettings::access_control_json`]),
//! so nobody writes Zenoh's ACL by hand.
//!
//! Zenoh reports each refusal as a `TRACE` event of its access-control
//! interceptor (target [`ACL_TARGET`]) and a peer that matches no subject
//! as an `INFO` event when it connects; nothing else in its API tells. A
//! [`RefusalLayer`] (installed in the station's `tracing` subscriber,
//! filtered to that target) parses those events into [`Refusals`]: a total,
//! a count per robot and key, and the first of each for the station to log
//! once. Written by hand because no crate reads Zenoh's access-control
//! decisions; the texts parsed are those of zenoh 1.10
//! (`net/routing/interceptor/access_control.rs`), checked by a unit test
//! here and by the station's process test against a real router.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};

use serde::{Deserialize, Serialize};
use serde_json::json;

/// The `tracing` target of Zenoh's access-control interceptor.
pub const ACL_TARGET: &str = "zenoh::net::routing::interceptor::access_control";

/// The most (robot, key) pairs counted one by one; further ones count in
/// the total only, so that a peer cycling through keys cannot grow the
/// station's memory.
pub const MAX_REFUSAL_KEYS: usize = 1000;

/// The messages a listed robot may send on any key (everything but data).
const CONTROL_MESSAGES: [&str; 7] = [
    "declare_subscriber",
    "declare_queryable",
    "query",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
];

/// `[station.identity]`: which robot may speak under which keys.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IdentitySettings {
    /// Robots by the common name of their TLS client certificate: each may
    /// put only under `insuwb/<id>/**`.
    pub robots: Vec<String>,
    /// Robots allowed without TLS, over plain TCP on the loopback interface
    /// only: any local process may put under their keys.
    pub loopback_robots: Vec<String>,
}

/// A `[station.identity]` value the station cannot use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("key 'station.identity.{key}': {reason}")]
pub struct IdentityError {
    /// `robots` or `loopback_robots`.
    pub key: &'static str,
    /// What is wrong, with the value.
    pub reason: String,
}

impl IdentitySettings {
    /// Whether identity is bound at all (a robot listed).
    #[must_use]
    pub fn enabled(&self) -> bool {
        !self.robots.is_empty() || !self.loopback_robots.is_empty()
    }

    /// Every id a valid robot id, none twice in a list.
    ///
    /// # Errors
    /// [`IdentityError`] naming the list and the id.
    pub fn validate(&self) -> Result<(), IdentityError> {
        for (key, ids) in [
            ("robots", &self.robots),
            ("loopback_robots", &self.loopback_robots),
        ] {
            for (i, id) in ids.iter().enumerate() {
                if let Err(e) = insuwb_fleet::keys::check_robot_id(id) {
                    return Err(IdentityError {
                        key,
                        reason: e.to_string(),
                    });
                }
                if ids.get(..i).is_some_and(|seen| seen.contains(id)) {
                    return Err(IdentityError {
                        key,
                        reason: format!("robot id {id:?} is listed twice"),
                    });
                }
            }
        }
        Ok(())
    }

    /// Zenoh's `access_control` object for these robots: default deny;
    /// per certificate common name (and for plain TCP on `lo`, the
    /// loopback robots), put and delete on its own keys, the control
    /// messages on any key; everything egress.
    #[must_use]
    pub fn access_control_json(&self) -> serde_json::Value {
        let own = |ids: &[String]| -> Vec<String> {
            ids.iter().map(|r| format!("insuwb/{r}/**")).collect()
        };
        let mut rules = vec![
            json!({"id": "control", "messages": CONTROL_MESSAGES, "flows": ["ingress", "egress"],
                   "permission": "allow", "key_exprs": ["**"]}),
            json!({"id": "egress_data", "messages": ["put", "delete"], "flows": ["egress"],
                   "permission": "allow", "key_exprs": ["**"]}),
        ];
        let mut subjects = Vec::new();
        let mut policies = Vec::new();
        for r in &self.robots {
            rules.push(
                json!({"id": format!("put_{r}"), "messages": ["put", "delete"],
                              "flows": ["ingress"], "permission": "allow",
                              "key_exprs": own(std::slice::from_ref(r))}),
            );
            subjects.push(json!({"id": format!("cn_{r}"), "cert_common_names": [r]}));
            policies.push(json!({"id": format!("robot_{r}"),
                                 "rules": ["control", "egress_data", format!("put_{r}")],
                                 "subjects": [format!("cn_{r}")]}));
        }
        if !self.loopback_robots.is_empty() {
            rules.push(json!({"id": "put_loopback", "messages": ["put", "delete"],
                              "flows": ["ingress"], "permission": "allow",
                              "key_exprs": own(&self.loopback_robots)}));
            subjects.push(json!({"id": "loopback_tcp", "interfaces": ["lo"],
                                 "link_protocols": ["tcp"]}));
            policies.push(json!({"id": "loopback",
                                 "rules": ["control", "egress_data", "put_loopback"],
                                 "subjects": ["loopback_tcp"]}));
        }
        json!({"enabled": true, "default_permission": "deny",
               "rules": rules, "subjects": subjects, "policies": policies})
    }
}

/// One refusal worth a log line: the first of its robot and key, or a
/// peer that matched no listed robot.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    /// `robot` (its certificate's common name, else how Zenoh names the
    /// peer) may not put on `key`.
    Put {
        /// The certificate's common name, or Zenoh's name of the peer.
        robot: String,
        /// The key expression refused.
        key: String,
    },
    /// A peer (Zenoh id) connected that matches no listed robot:
    /// everything it sends is refused.
    Unknown {
        /// Its Zenoh id.
        zid: String,
    },
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Put { robot, key } => write!(
                f,
                "{robot} may not put on {key}: refused at the router (identity bound to the certificate; further refusals of it only counted)"
            ),
            Self::Unknown { zid } => write!(
                f,
                "peer {zid} is no listed robot (no certificate of one, or not over plain TCP on the loopback for a loopback robot): everything it sends is refused"
            ),
        }
    }
}

#[derive(Debug, Default)]
struct State {
    total: u64,
    per_key: BTreeMap<(String, String), u64>,
    /// Robot name of each Zenoh id seen in a full refusal (for the cached
    /// form, which names the id only).
    names: BTreeMap<String, String>,
    unknown_peers: u64,
    fresh: Vec<Refusal>,
    /// The key whose permissions Zenoh is deciding ahead of its messages
    /// (`caching permissions for`), and how many of those decisions are
    /// still to come: they are not messages and are not counted.
    priming: Option<(String, u8)>,
}

/// The decisions Zenoh makes when it caches a key's permissions (query,
/// reply, put, delete, and five declarations).
const PRIMING_DECISIONS: u8 = 9;

/// The refusals of the station's access control (shared between the
/// [`RefusalLayer`] and the station).
#[derive(Debug, Default)]
pub struct Refusals {
    state: Mutex<State>,
}

impl Refusals {
    /// An empty count, shared.
    #[must_use]
    pub fn new() -> Arc<Self> {
        Arc::new(Self::default())
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Puts and deletes refused so far.
    #[must_use]
    pub fn total(&self) -> u64 {
        self.lock().total
    }

    /// Peers that matched no listed robot so far.
    #[must_use]
    pub fn unknown_peers(&self) -> u64 {
        self.lock().unknown_peers
    }

    /// Refusals of `robot` on `key` so far.
    #[must_use]
    pub fn count(&self, robot: &str, key: &str) -> u64 {
        self.lock()
            .per_key
            .get(&(robot.to_owned(), key.to_owned()))
            .copied()
            .unwrap_or(0)
    }

    /// The refusals not yet handed out that deserve a log line (the first
    /// of each robot and key, each unknown peer).
    #[must_use]
    pub fn take_fresh(&self) -> Vec<Refusal> {
        std::mem::take(&mut self.lock().fresh)
    }

    /// Takes one message of Zenoh's access-control interceptor; returns
    /// whether it was a refusal or an unknown peer.
    pub fn observe(&self, message: &str) -> bool {
        if let Some(zid) = message
            .split_once(" did not match any configured ACL subject")
            .map(|(z, _)| z.trim())
        {
            let mut s = self.lock();
            s.unknown_peers += 1;
            if s.fresh.len() < MAX_REFUSAL_KEYS {
                s.fresh.push(Refusal::Unknown {
                    zid: zid.to_owned(),
                });
            }
            return true;
        }
        if let Some(key) = message
            .strip_prefix("ACL (ingress): caching permissions for `")
            .and_then(|r| r.split_once('`'))
            .map(|(k, _)| k)
        {
            self.lock().priming = Some((key.to_owned(), PRIMING_DECISIONS));
            return false;
        }
        let primed = self.priming_decision(message);
        let Some(parsed) = parse_refusal(message) else {
            return false;
        };
        let mut s = self.lock();
        let robot = match parsed.subject {
            Some(subject) => {
                let name = common_name(subject).unwrap_or(subject).to_owned();
                if s.names.len() < MAX_REFUSAL_KEYS || s.names.contains_key(parsed.zid) {
                    s.names.insert(parsed.zid.to_owned(), name.clone());
                }
                name
            }
            None => s
                .names
                .get(parsed.zid)
                .cloned()
                .unwrap_or_else(|| parsed.zid.to_owned()),
        };
        let k = (robot, parsed.key.to_owned());
        let add = u64::from(!primed);
        s.total += add;
        if let Some(n) = s.per_key.get_mut(&k) {
            *n += add;
        } else if s.per_key.len() < MAX_REFUSAL_KEYS {
            s.fresh.push(Refusal::Put {
                robot: k.0.clone(),
                key: k.1.clone(),
            });
            s.per_key.insert(k, add);
        }
        !primed
    }

    /// Whether `message` is one of the decisions Zenoh makes while caching
    /// a key's permissions (a full-form decision on the key being primed).
    fn priming_decision(&self, message: &str) -> bool {
        if message.starts_with("Using cached result: ") {
            return false;
        }
        let Some((_, key)) = message
            .split_once(" is unauthorized to ")
            .or_else(|| message.split_once(" is authorized to "))
            .and_then(|(_, rest)| rest.rsplit_once(" on "))
        else {
            return false;
        };
        let mut s = self.lock();
        match &mut s.priming {
            Some((k, left)) if k.as_str() == key.trim() && *left > 0 => {
                *left -= 1;
                if *left == 0 {
                    s.priming = None;
                }
                true
            }
            _ => false,
        }
    }
}

/// A refusal as Zenoh words it.
struct Parsed<'a> {
    zid: &'a str,
    /// `Interface(lo)+CertCommonName(r1)+Transport(Tls)+ZID` (absent in
    /// the cached form).
    subject: Option<&'a str>,
    key: &'a str,
}

/// `ZID on SUBJECT is unauthorized to Put (ingress) on KEY`, or `Using
/// cached result: ZID is unauthorized to ACTION on KEY`; puts and deletes
/// coming in only.
fn parse_refusal(message: &str) -> Option<Parsed<'_>> {
    let (who, rest) = message.split_once(" is unauthorized to ")?;
    let (action, key) = rest.rsplit_once(" on ")?;
    let action = action.to_ascii_lowercase();
    if !(action.starts_with("put") || action.starts_with("delete")) || action.contains("egress") {
        return None;
    }
    let who = who.strip_prefix("Using cached result: ").unwrap_or(who);
    let (zid, subject) = match who.split_once(" on ") {
        Some((z, s)) => (z.trim(), Some(s.trim())),
        None => (who.trim(), None),
    };
    Some(Parsed {
        zid,
        subject,
        key: key.trim(),
    })
}

/// The `CertCommonName(...)` of a subject, if any.
fn common_name(subject: &str) -> Option<&str> {
    let (_, rest) = subject.split_once("CertCommonName(")?;
    rest.split_once(')').map(|(cn, _)| cn)
}

/// A `tracing` layer that feeds Zenoh's access-control events into
/// [`Refusals`]. Give it a per-layer filter that lets [`ACL_TARGET`]
/// through at `TRACE` ([`RefusalLayer::filtered`]).
#[derive(Debug, Clone)]
pub struct RefusalLayer {
    refusals: Arc<Refusals>,
}

impl RefusalLayer {
    /// A layer counting into `refusals`.
    #[must_use]
    pub fn new(refusals: Arc<Refusals>) -> Self {
        Self { refusals }
    }

    /// The layer with its filter ([`ACL_TARGET`] at every level, nothing
    /// else), boxed for a subscriber built on a `Registry`.
    #[must_use]
    pub fn filtered(
        refusals: Arc<Refusals>,
    ) -> Box<dyn tracing_subscriber::Layer<tracing_subscriber::Registry> + Send + Sync> {
        use tracing_subscriber::Layer as _;
        let targets = tracing_subscriber::filter::Targets::new()
            .with_target(ACL_TARGET, tracing::Level::TRACE);
        Box::new(Self::new(refusals).with_filter(targets))
    }
}

/// Collects an event's `message` field.
struct Message(String);

impl tracing::field::Visit for Message {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            use std::fmt::Write as _;
            let _ = write!(self.0, "{value:?}");
        }
    }

    fn record_str(&mut self, field: &tracing::field::Field, value: &str) {
        if field.name() == "message" {
            self.0.push_str(value);
        }
    }
}

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for RefusalLayer {
    fn on_event(
        &self,
        event: &tracing::Event<'_>,
        _ctx: tracing_subscriber::layer::Context<'_, S>,
    ) {
        if event.metadata().target() != ACL_TARGET {
            return;
        }
        let mut m = Message(String::new());
        event.record(&mut m);
        self.refusals.observe(&m.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ids(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| (*s).to_owned()).collect()
    }

    #[test]
    fn settings_are_checked_and_name_the_list() {
        let s = IdentitySettings {
            robots: ids(&["r1", "r2"]),
            loopback_robots: ids(&["sim"]),
        };
        s.validate().unwrap();
        assert!(s.enabled());
        assert!(!IdentitySettings::default().enabled());
        let bad = IdentitySettings {
            robots: ids(&["r1", "bad id"]),
            ..IdentitySettings::default()
        };
        let e = bad.validate().unwrap_err();
        assert_eq!(e.key, "robots");
        assert!(e.to_string().contains("station.identity.robots"), "{e}");
        let twice = IdentitySettings {
            loopback_robots: ids(&["a", "a"]),
            ..IdentitySettings::default()
        };
        assert_eq!(twice.validate().unwrap_err().key, "loopback_robots");
    }

    #[test]
    fn the_access_control_binds_each_robot_to_its_keys() {
        let s = IdentitySettings {
            robots: ids(&["r1", "r2"]),
            loopback_robots: ids(&["sim"]),
        };
        let j = s.access_control_json();
        assert_eq!(j["default_permission"], "deny");
        assert_eq!(j["subjects"][0]["cert_common_names"][0], "r1");
        let put_r1 = j["rules"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["id"] == "put_r1")
            .unwrap();
        assert_eq!(put_r1["key_exprs"][0], "insuwb/r1/**");
        assert_eq!(put_r1["flows"][0], "ingress");
        assert_eq!(j["policies"][1]["subjects"][0], "cn_r2");
        assert_eq!(j["subjects"][2]["interfaces"][0], "lo");
        assert_eq!(j["subjects"][2]["link_protocols"][0], "tcp");
    }

    /// The texts of zenoh 1.10's interceptor, as a real router printed
    /// them.
    #[test]
    fn refusals_are_counted_per_robot_and_key_and_logged_once() {
        let r = Refusals::default();
        let zid = "a2f826ac87d79df60f48d350c91c0e59";
        // Declaring the key: Zenoh decides its nine permissions ahead of
        // any message; those are not refusals of a message.
        assert!(!r.observe("ACL (ingress): caching permissions for `insuwb/r2/pose` ..."));
        for action in [
            "Query",
            "Reply",
            "Put",
            "Delete",
            "Declare/Undeclare Subscriber",
        ] {
            let verb = if action == "Put" || action == "Delete" {
                "unauthorized"
            } else {
                "authorized"
            };
            assert!(!r.observe(&format!(
                "{zid} on Interface(lo)+CertCommonName(r1)+Transport(Tls)+{zid} is {verb} to {action} (ingress) on insuwb/r2/pose"
            )));
        }
        assert_eq!(r.total(), 0);
        let full = format!(
            "{zid} on Interface(lo)+CertCommonName(r1)+Transport(Tls)+{zid} is unauthorized to Put (ingress) on insuwb/r2/pose"
        );
        // The four other decisions of the cache, then messages.
        for _ in 0..4 {
            assert!(!r.observe(&format!(
                "{zid} on X is authorized to Declare Liveliness Subscriber (ingress) on insuwb/r2/pose"
            )));
        }
        assert!(r.observe(&full));
        assert!(r.observe(&full));
        assert!(r.observe(&format!(
            "Using cached result: {zid} is unauthorized to Put on insuwb/r2/pose"
        )));
        assert!(!r.observe(&format!(
            "{zid} on Interface(lo)+CertCommonName(r1)+Transport(Tls)+{zid} is authorized to Put (ingress) on insuwb/r1/pose"
        )));
        assert!(!r.observe(&format!(
            "{zid} on X is unauthorized to Put (egress) on insuwb/r2/pose"
        )));
        assert!(!r.observe(&format!(
            "{zid} on X is unauthorized to Declare Subscriber (ingress) on insuwb/**"
        )));
        assert_eq!(r.total(), 3);
        assert_eq!(r.count("r1", "insuwb/r2/pose"), 3);
        assert_eq!(
            r.take_fresh(),
            vec![Refusal::Put {
                robot: "r1".into(),
                key: "insuwb/r2/pose".into()
            }]
        );
        assert!(r.take_fresh().is_empty());
        assert!(r.observe(
            "0f00 did not match any configured ACL subject. Default permission `Deny` will be applied on all messages"
        ));
        assert_eq!(r.unknown_peers(), 1);
        assert!(r.take_fresh()[0].to_string().contains("peer 0f00"));
        // A peer cycling through keys: counted, the map bounded.
        for k in 0..(MAX_REFUSAL_KEYS + 10) {
            r.observe(&format!(
                "{zid} on CertCommonName(r1) is unauthorized to Put (ingress) on insuwb/x{k}/pose"
            ));
        }
        assert_eq!(r.total(), 3 + MAX_REFUSAL_KEYS as u64 + 10);
        assert_eq!(r.take_fresh().len(), MAX_REFUSAL_KEYS - 1);
    }
}
