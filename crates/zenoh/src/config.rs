//! The `[zenoh]` table of the robot config: the robot id, how the bridge
//! reaches the fleet's station (mode, endpoints, TLS), what it publishes,
//! the clock of the stamps.
//!
//! Nothing is opened or scouted unless configured: no listening endpoint
//! by default, the endpoints to connect to are explicit, and multicast
//! scouting and gossip are always off (there is no key to turn them on).
//!
//! ```
//! use insuwb_zenoh::config::ZenohConfig;
//! let c: ZenohConfig = toml::from_str(
//!     "robot = \"r1\"\nconnect = [\"tcp/192.168.1.10:7447\"]\npublish_fixes = true",
//! )
//! .unwrap();
//! c.validate_enabled().unwrap();
//! assert!(c.listen.is_empty());
//! let bad: ZenohConfig = toml::from_str("connect = [\"udp/10.0.0.1:7447\"]").unwrap();
//! assert_eq!(
//!     bad.validate().unwrap_err().to_string(),
//!     "key 'zenoh.connect': endpoint \"udp/10.0.0.1:7447\": the protocol must be tcp or tls"
//! );
//! ```

use std::path::{Path, PathBuf};

use insuwb_fleet::keys::{check_robot_id, Key, Kind};
use insuwb_report::clock::StampClock;
use serde::{Deserialize, Serialize};

/// The protocols an endpoint may name (the transports the crate builds).
pub const PROTOCOLS: [&str; 2] = ["tcp", "tls"];

/// The role of a session in the Zenoh network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// A peer (the bridge's default): connects to the endpoints of
    /// `connect`, retrying in the background while one is down, and
    /// accepts on `listen`.
    #[default]
    Peer,
    /// A client: one connection, to the first reachable endpoint of
    /// `connect` (opening fails while none is), re-established when lost.
    Client,
    /// A router (a station that serves the fleet): routes between the
    /// sessions connected to it.
    Router,
}

impl Mode {
    /// Its name in the Zenoh configuration: `peer`, `client`, `router`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Peer => "peer",
            Self::Client => "client",
            Self::Router => "router",
        }
    }
}

/// `[zenoh.tls]`: the certificates of the `tls/` endpoints (PEM files).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TlsConfig {
    /// The certificate authority that signs the other side's certificate
    /// (the station's, or a robot's for a listening side).
    pub root_ca_certificate: Option<PathBuf>,
    /// This side's certificate: presented when listening, and when
    /// connecting with `mutual`.
    pub certificate: Option<PathBuf>,
    /// The private key of `certificate`.
    pub private_key: Option<PathBuf>,
    /// Mutual TLS: a listening side refuses a client without a certificate
    /// the CA signed, and a connecting side presents its own.
    pub mutual: bool,
    /// A connecting side checks that the other's certificate names the
    /// host of the endpoint (its DNS name or IP address).
    pub verify_name: bool,
}

impl Default for TlsConfig {
    fn default() -> Self {
        Self {
            root_ca_certificate: None,
            certificate: None,
            private_key: None,
            mutual: true,
            verify_name: true,
        }
    }
}

impl TlsConfig {
    /// Makes the certificate paths absolute under `base` (the folder of
    /// the config file).
    pub fn resolve_paths(&mut self, base: &Path) {
        for p in [
            &mut self.root_ca_certificate,
            &mut self.certificate,
            &mut self.private_key,
        ]
        .into_iter()
        .flatten()
        {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        }
    }
}

/// How a session reaches the others: what [`crate::session`] opens, the
/// part of `[zenoh]` that the station's configuration shares.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct LinkConfig {
    /// The session's role.
    pub mode: Mode,
    /// Endpoints to connect to, `tcp/HOST:PORT` or `tls/HOST:PORT`.
    pub connect: Vec<String>,
    /// Endpoints to listen on (none: no port is opened).
    pub listen: Vec<String>,
    /// The certificates of the `tls/` endpoints.
    pub tls: TlsConfig,
    /// Refuse a plain `tcp/` endpoint off the loopback
    /// ([`LinkConfig::plain_off_loopback`]) instead of warning about it.
    pub require_tls: bool,
}

/// `[zenoh]`: the Zenoh bridge stage (`insuwb-stage-zenoh`, run when
/// `stages` lists `zenoh`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    /// This robot's id in the fleet: it publishes under
    /// `insuwb/<robot>/...`. Required where `stages` lists `zenoh`.
    pub robot: String,
    /// The session's role: `peer` (default), `client` or `router`.
    pub mode: Mode,
    /// Endpoints to connect to (the station's), `tcp/HOST:PORT` or
    /// `tls/HOST:PORT`.
    pub connect: Vec<String>,
    /// Endpoints to listen on, e.g. `tcp/0.0.0.0:7447` (none by default:
    /// no port is opened).
    pub listen: Vec<String>,
    /// The certificates of the `tls/` endpoints.
    pub tls: TlsConfig,
    /// Refuse to start with a plain `tcp/` endpoint off the loopback
    /// (by default such an endpoint is only warned about).
    pub require_tls: bool,
    /// Publish the UWB fixes on `insuwb/<robot>/fix`.
    pub publish_fixes: bool,
    /// Publish the filter's diagnostics on `insuwb/<robot>/diag`.
    pub publish_diag: bool,
    /// Publish only fused states flagged valid (by default every one, its
    /// flags in the sample's attachment).
    pub only_valid: bool,
    /// Clock of the stamps: `realtime` (default; the station compares them
    /// with its own clock) or `monotonic`.
    pub stamp_clock: StampClock,
    /// Period of the health samples, s.
    pub health_period_s: f64,
    /// A stage whose last heartbeat is older than this is reported down, s.
    pub stale_after_s: f64,
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            robot: String::new(),
            mode: Mode::Peer,
            connect: Vec::new(),
            listen: Vec::new(),
            tls: TlsConfig::default(),
            require_tls: false,
            publish_fixes: false,
            publish_diag: false,
            only_valid: false,
            stamp_clock: StampClock::Realtime,
            health_period_s: 1.0,
            stale_after_s: 1.0,
        }
    }
}

/// A `[zenoh]` key with a value the bridge cannot use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("key 'zenoh.{key}': {reason}")]
pub struct ZenohConfigError {
    /// The key, without `zenoh.` (`tls.certificate` for a key of
    /// `[zenoh.tls]`).
    pub key: &'static str,
    /// What is wrong, with the value.
    pub reason: String,
}

fn bad<T>(key: &'static str, reason: String) -> Result<T, ZenohConfigError> {
    Err(ZenohConfigError { key, reason })
}

/// Checks an endpoint: `tcp/` or `tls/`, then `HOST:PORT` (an IPv6 host in
/// brackets), optionally followed by Zenoh's `?metadata` or `#config`.
///
/// # Errors
/// [`ZenohConfigError`] naming `key`, with the endpoint and what is wrong.
pub fn check_endpoint(key: &'static str, e: &str) -> Result<(), ZenohConfigError> {
    let Some((proto, rest)) = e.split_once('/') else {
        return bad(
            key,
            format!("endpoint {e:?}: must be PROTOCOL/HOST:PORT such as \"tcp/192.168.1.10:7447\""),
        );
    };
    if !PROTOCOLS.contains(&proto) {
        return bad(
            key,
            format!("endpoint {e:?}: the protocol must be tcp or tls"),
        );
    }
    let addr = rest.split(['?', '#']).next().unwrap_or_default();
    let port_ok = addr.rsplit_once(':').is_some_and(|(host, port)| {
        let host_ok = !host.is_empty()
            && !host.contains('/')
            && (host.starts_with('[') == host.ends_with(']'))
            && !host.chars().any(char::is_whitespace);
        host_ok && port.parse::<u16>().is_ok()
    });
    if port_ok {
        Ok(())
    } else {
        bad(
            key,
            format!("endpoint {e:?}: the address must be HOST:PORT (port 0-65535)"),
        )
    }
}

/// Whether `e` is an endpoint of the TLS transport.
#[must_use]
pub fn is_tls(e: &str) -> bool {
    e.starts_with("tls/")
}

/// Whether `e` (a checked endpoint) names a loopback host: `localhost`,
/// an address of 127.0.0.0/8 or `::1`.
#[must_use]
pub fn is_loopback(e: &str) -> bool {
    let rest = e.split_once('/').map_or(e, |(_, r)| r);
    let addr = rest.split(['?', '#']).next().unwrap_or_default();
    let Some((host, _)) = addr.rsplit_once(':') else {
        return false;
    };
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// Whether `e` carries the fleet in clear text to a host off the loopback:
/// a `tcp/` (or `udp/`, which is no safer, though not built) endpoint
/// whose host is not a loopback one ([`is_loopback`]). `tls/` and any
/// other transport are not: a warning (or the refusal under
/// `require_tls`) is for exactly these.
#[must_use]
pub fn is_plain_off_loopback(e: &str) -> bool {
    (e.starts_with("tcp/") || e.starts_with("udp/")) && !is_loopback(e)
}

/// What a plain `tcp/` endpoint off the loopback exposes and how to close
/// it: the text of the warning, and of the error under `require_tls`.
#[must_use]
pub fn plain_tcp_text(e: &str) -> String {
    format!(
        "endpoint {e:?} is plain TCP off the loopback: anyone on that network can read the \
         fleet's samples and put poses for any robot; use a tls/ endpoint with the TLS \
         section beside this key (root_ca_certificate, certificate, private_key; \
         docs/ZENOH.md, \"TLS\")"
    )
}

impl LinkConfig {
    /// The plain `tcp/` endpoints to connect to or listen on whose host is
    /// not a loopback one, each with its key (`connect` or `listen`): the
    /// stage and the station warn about each when they start, and refuse
    /// them under `require_tls`.
    #[must_use]
    pub fn plain_off_loopback(&self) -> Vec<(&'static str, &str)> {
        self.connect
            .iter()
            .map(|e| ("connect", e.as_str()))
            .chain(self.listen.iter().map(|e| ("listen", e.as_str())))
            .filter(|(_, e)| is_plain_off_loopback(e))
            .collect()
    }

    /// Checks the endpoints and the TLS settings they need; the error names
    /// the first bad key.
    ///
    /// # Errors
    /// [`ZenohConfigError`] naming the key.
    pub fn validate(&self) -> Result<(), ZenohConfigError> {
        for e in &self.connect {
            check_endpoint("connect", e)?;
        }
        for e in &self.listen {
            check_endpoint("listen", e)?;
        }
        if self.require_tls {
            if let Some((key, e)) = self.plain_off_loopback().first() {
                return bad(
                    key,
                    format!("{} (refused: require_tls is set)", plain_tcp_text(e)),
                );
            }
        }
        let t = &self.tls;
        for (key, p) in [
            ("tls.root_ca_certificate", &t.root_ca_certificate),
            ("tls.certificate", &t.certificate),
            ("tls.private_key", &t.private_key),
        ] {
            if let Some(p) = p {
                if !p.is_file() {
                    return bad(key, format!("file {} does not exist", p.display()));
                }
            }
        }
        match (&t.certificate, &t.private_key) {
            (Some(_), None) => {
                return bad(
                    "tls.private_key",
                    "must be set with tls.certificate".to_owned(),
                )
            }
            (None, Some(_)) => {
                return bad(
                    "tls.certificate",
                    "must be set with tls.private_key".to_owned(),
                )
            }
            _ => {}
        }
        let tls_connect = self.connect.iter().any(|e| is_tls(e));
        let tls_listen = self.listen.iter().any(|e| is_tls(e));
        if (tls_connect || tls_listen) && t.root_ca_certificate.is_none() {
            return bad(
                "tls.root_ca_certificate",
                "a tls/ endpoint needs the certificate authority that signs the other side"
                    .to_owned(),
            );
        }
        let own = t.certificate.is_some();
        if tls_listen && !own {
            return bad(
                "tls.certificate",
                "listening on a tls/ endpoint needs this side's certificate and private key"
                    .to_owned(),
            );
        }
        if tls_connect && t.mutual && !own {
            return bad(
                "tls.certificate",
                "mutual TLS (tls.mutual, the default) needs this side's certificate and private key to connect".to_owned(),
            );
        }
        Ok(())
    }
}

impl ZenohConfig {
    /// Checks every key; the error names the first bad one. An empty
    /// `robot` passes (the table of a group that does not run the
    /// bridge): [`ZenohConfig::validate_enabled`] refuses it.
    ///
    /// # Errors
    /// [`ZenohConfigError`] naming the key.
    pub fn validate(&self) -> Result<(), ZenohConfigError> {
        if !self.robot.is_empty() {
            if let Err(e) = check_robot_id(&self.robot) {
                return bad("robot", e.to_string());
            }
        }
        self.link().validate()?;
        for (key, v) in [
            ("health_period_s", self.health_period_s),
            ("stale_after_s", self.stale_after_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 3600.0) {
                return bad(key, format!("must be in (0, 3600] s, got {v}"));
            }
        }
        Ok(())
    }

    /// [`ZenohConfig::validate`], and what the bridge needs besides: a
    /// robot id, and an endpoint to reach the station by.
    ///
    /// # Errors
    /// [`ZenohConfigError`] naming the key.
    pub fn validate_enabled(&self) -> Result<(), ZenohConfigError> {
        self.validate()?;
        if self.robot.is_empty() {
            return bad(
                "robot",
                "required where stages lists zenoh (1 to 64 characters of A-Z a-z 0-9 _ -)"
                    .to_owned(),
            );
        }
        if self.connect.is_empty() && self.listen.is_empty() {
            return bad(
                "connect",
                "the bridge needs an endpoint to connect to (or one to listen on), e.g. [\"tcp/192.168.1.10:7447\"]".to_owned(),
            );
        }
        Ok(())
    }

    /// How the session reaches the others.
    #[must_use]
    pub fn link(&self) -> LinkConfig {
        LinkConfig {
            mode: self.mode,
            connect: self.connect.clone(),
            listen: self.listen.clone(),
            tls: self.tls.clone(),
            require_tls: self.require_tls,
        }
    }

    /// Makes the certificate paths absolute under `base` (the folder of
    /// the config file).
    pub fn resolve_paths(&mut self, base: &Path) {
        self.tls.resolve_paths(base);
    }

    /// The key of this robot's stream `kind`.
    ///
    /// # Errors
    /// [`ZenohConfigError`] for `robot` when it is not a robot id.
    pub fn key(&self, kind: Kind) -> Result<Key, ZenohConfigError> {
        Key::new(&self.robot, kind).map_err(|e| ZenohConfigError {
            key: "robot",
            reason: e.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn enabled() -> ZenohConfig {
        ZenohConfig {
            robot: "r1".into(),
            connect: vec!["tcp/127.0.0.1:7447".into()],
            ..ZenohConfig::default()
        }
    }

    /// Three files that exist, standing for PEM files.
    fn pem_files(tag: &str) -> (PathBuf, [PathBuf; 3]) {
        let dir =
            std::env::temp_dir().join(format!("insuwb-zenoh-cfg-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let files = ["ca.pem", "cert.pem", "key.pem"].map(|n| {
            let p = dir.join(n);
            std::fs::write(&p, "x").unwrap();
            p
        });
        (dir, files)
    }

    #[test]
    fn plain_endpoints_off_the_loopback_are_told_apart() {
        for (e, plain) in [
            ("tcp/127.0.0.1:7447", false),
            ("tcp/127.9.9.9:7447", false),
            ("tcp/[::1]:7447", false),
            ("tcp/localhost:7447", false),
            ("tcp/LocalHost:7447", false),
            ("tcp/127.0.0.1:7447#iface=lo", false),
            ("tls/192.168.1.5:7447", false),
            ("tls/station.lan:7447", false),
            ("udp/127.0.0.1:7447", false),
            ("tcp/192.168.1.5:7447", true),
            ("tcp/0.0.0.0:7447", true),
            ("tcp/[::]:7447", true),
            ("tcp/[fe80::1]:7447", true),
            ("tcp/station.lan:7447", true),
            ("tcp/localhost.evil.example:7447", true),
            ("udp/192.168.1.5:7447", true),
        ] {
            assert_eq!(is_plain_off_loopback(e), plain, "{e}");
        }
    }

    #[test]
    fn plain_tcp_off_the_loopback_is_named_and_refused_under_require_tls() {
        for e in [
            "tcp/127.0.0.1:7447",
            "tcp/127.3.2.1:7447",
            "tcp/[::1]:7447",
            "tcp/localhost:7447",
            "tls/10.0.0.1:7447",
        ] {
            let c = ZenohConfig {
                connect: vec![e.into()],
                require_tls: true,
                ..enabled()
            };
            assert!(c.link().plain_off_loopback().is_empty(), "{e}");
            if !is_tls(e) {
                c.validate().unwrap();
            }
        }
        let c = ZenohConfig {
            connect: vec!["tcp/127.0.0.1:7447".into(), "tcp/10.0.0.1:7447".into()],
            listen: vec!["tcp/0.0.0.0:7447".into(), "tcp/[fe80::1]:7447".into()],
            ..enabled()
        };
        assert_eq!(
            c.link().plain_off_loopback(),
            vec![
                ("connect", "tcp/10.0.0.1:7447"),
                ("listen", "tcp/0.0.0.0:7447"),
                ("listen", "tcp/[fe80::1]:7447"),
            ]
        );
        // Warned about (when the session opens), not refused ...
        c.validate().unwrap();
        // ... unless require_tls is set: the first one is named with its key.
        let e = ZenohConfig {
            require_tls: true,
            ..c
        }
        .validate()
        .unwrap_err();
        assert_eq!(e.key, "connect");
        let text = e.to_string();
        assert!(
            text.starts_with(
                "key 'zenoh.connect': endpoint \"tcp/10.0.0.1:7447\" is plain TCP off the loopback"
            ),
            "{text}"
        );
        assert!(
            text.contains("tls/ endpoint") && text.contains("require_tls is set"),
            "{text}"
        );
        let c: ZenohConfig = toml::from_str("robot = \"r1\"\nrequire_tls = true").unwrap();
        assert!(c.require_tls && c.link().require_tls);
    }

    #[test]
    fn defaults_open_nothing_and_are_valid() {
        let c = ZenohConfig::default();
        c.validate().unwrap();
        assert!(c.connect.is_empty() && c.listen.is_empty());
        assert_eq!(c.mode, Mode::Peer);
        assert!(!c.publish_fixes && !c.publish_diag && !c.only_valid);
        assert_eq!(c.health_period_s, 1.0);
        let e = c.validate_enabled().unwrap_err();
        assert_eq!(e.key, "robot");
        enabled().validate_enabled().unwrap();
        let e = ZenohConfig {
            robot: "r1".into(),
            ..ZenohConfig::default()
        }
        .validate_enabled()
        .unwrap_err();
        assert_eq!(e.key, "connect", "{e}");
        assert_eq!(
            enabled().key(Kind::Pose).unwrap().to_string(),
            "insuwb/r1/pose"
        );
    }

    #[test]
    fn endpoints_are_tcp_or_tls_host_port() {
        for ok in [
            "tcp/127.0.0.1:7447",
            "tls/station.lan:7447",
            "tcp/[::1]:0",
            "tcp/10.0.0.1:7447#iface=eth0",
            "tcp/10.0.0.1:7447?prio=1-7",
        ] {
            check_endpoint("connect", ok).unwrap();
        }
        for badv in [
            "127.0.0.1:7447",
            "udp/127.0.0.1:7447",
            "quic/127.0.0.1:7447",
            "tcp/127.0.0.1",
            "tcp/:7447",
            "tcp/127.0.0.1:70000",
            "tcp/[::1:7447",
            "",
        ] {
            let e = check_endpoint("listen", badv).unwrap_err();
            assert_eq!(e.key, "listen");
            assert!(e.to_string().contains(&format!("{badv:?}")), "{e}");
        }
    }

    #[test]
    fn each_bad_value_names_its_key() {
        let d = enabled;
        let cases: [(&str, ZenohConfig); 7] = [
            (
                "robot",
                ZenohConfig {
                    robot: "r/1".into(),
                    ..d()
                },
            ),
            (
                "connect",
                ZenohConfig {
                    connect: vec!["udp/1.2.3.4:7447".into()],
                    ..d()
                },
            ),
            (
                "listen",
                ZenohConfig {
                    listen: vec!["tcp/0.0.0.0".into()],
                    ..d()
                },
            ),
            (
                "health_period_s",
                ZenohConfig {
                    health_period_s: 0.0,
                    ..d()
                },
            ),
            (
                "stale_after_s",
                ZenohConfig {
                    stale_after_s: f64::NAN,
                    ..d()
                },
            ),
            (
                "tls.root_ca_certificate",
                ZenohConfig {
                    connect: vec!["tls/127.0.0.1:7447".into()],
                    ..d()
                },
            ),
            (
                "tls.certificate",
                ZenohConfig {
                    tls: TlsConfig {
                        certificate: Some("/nonexistent/insuwb/cert.pem".into()),
                        ..TlsConfig::default()
                    },
                    ..d()
                },
            ),
        ];
        for (key, c) in cases {
            let e = c.validate().unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(
                e.to_string().starts_with(&format!("key 'zenoh.{key}': ")),
                "{e}"
            );
        }
    }

    #[test]
    fn tls_needs_the_ca_and_for_mutual_tls_an_own_certificate() {
        let (dir, [ca, cert, key]) = pem_files("tls");
        let tls = |ca: Option<&PathBuf>, own: bool, mutual: bool| TlsConfig {
            root_ca_certificate: ca.cloned(),
            certificate: own.then(|| cert.clone()),
            private_key: own.then(|| key.clone()),
            mutual,
            verify_name: true,
        };
        let with = |connect: &str, listen: &[&str], t: TlsConfig| ZenohConfig {
            connect: vec![connect.into()],
            listen: listen.iter().map(|s| (*s).to_owned()).collect(),
            tls: t,
            ..enabled()
        };
        with("tls/127.0.0.1:7447", &[], tls(Some(&ca), true, true))
            .validate_enabled()
            .unwrap();
        with("tls/127.0.0.1:7447", &[], tls(Some(&ca), false, false))
            .validate_enabled()
            .unwrap();
        let e = with("tls/127.0.0.1:7447", &[], tls(Some(&ca), false, true))
            .validate()
            .unwrap_err();
        assert_eq!(e.key, "tls.certificate", "{e}");
        let e = with(
            "tcp/127.0.0.1:7447",
            &["tls/0.0.0.0:7448"],
            tls(Some(&ca), false, false),
        )
        .validate()
        .unwrap_err();
        assert_eq!(e.key, "tls.certificate", "{e}");
        let mut half = tls(Some(&ca), true, true);
        half.private_key = None;
        let e = with("tls/127.0.0.1:7447", &[], half)
            .validate()
            .unwrap_err();
        assert_eq!(e.key, "tls.private_key", "{e}");
        // Plain TCP needs none of it.
        with("tcp/127.0.0.1:7447", &[], TlsConfig::default())
            .validate()
            .unwrap();
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn relative_certificate_paths_are_under_the_config_folder() {
        let mut c: ZenohConfig = toml::from_str(
            "[tls]\nroot_ca_certificate = \"certs/ca.pem\"\ncertificate = \"/etc/insuwb/r1.pem\"\n",
        )
        .unwrap();
        c.resolve_paths(Path::new("/etc/insuwb"));
        assert_eq!(
            c.tls.root_ca_certificate.as_deref(),
            Some(Path::new("/etc/insuwb/certs/ca.pem"))
        );
        assert_eq!(
            c.tls.certificate.as_deref(),
            Some(Path::new("/etc/insuwb/r1.pem"))
        );
    }

    #[test]
    fn unknown_keys_are_refused() {
        assert!(toml::from_str::<ZenohConfig>("multicast_scouting = true").is_err());
        assert!(toml::from_str::<ZenohConfig>("[tls]\nca = \"x\"").is_err());
        assert!(toml::from_str::<ZenohConfig>("mode = \"gossip\"").is_err());
        let c: ZenohConfig =
            toml::from_str("mode = \"client\"\nstamp_clock = \"monotonic\"").unwrap();
        assert_eq!(
            (c.mode, c.stamp_clock),
            (Mode::Client, StampClock::Monotonic)
        );
    }
}
