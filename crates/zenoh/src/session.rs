//! The Zenoh session of the fleet (the bridge's, and the station's): a
//! `zenoh::Config` made from a [`LinkConfig`] alone ([`zenoh_config`]),
//! opened with the stage's signals blocked in Zenoh's threads ([`open`]),
//! and what a subscriber gets turned into a payload ([`decode_sample`]).
//!
//! What the configuration holds, and nothing else from Zenoh's defaults
//! that would open or scout anything:
//!
//! - `mode`: the link's mode (`peer` by default);
//! - `connect/endpoints`: the link's `connect`, each retried in the
//!   background while it is down (peer and router), then re-established
//!   when lost;
//! - `listen/endpoints`: the link's `listen`, empty by default (Zenoh's own
//!   default would listen on every interface);
//! - `scouting/multicast/enabled` and `scouting/gossip/enabled`: `false`;
//! - where TLS is configured, `transport/link/tls/root_ca_certificate`,
//!   `listen_certificate` and `listen_private_key` (this side's
//!   certificate), `connect_certificate` and `connect_private_key` (the
//!   same, presented when connecting with `mutual`), `enable_mtls`
//!   (`mutual`) and `verify_name_on_connect` (`verify_name`).
//!
//! A station subscribes to every robot's poses with
//! `insuwb_fleet::keys::Kind::Pose.subscription()` (`insuwb/*/pose`) and
//! decodes each sample with [`decode_sample`]:
//!
//! ```no_run
//! use insuwb_fleet::keys::Kind;
//! use insuwb_zenoh::config::{LinkConfig, Mode};
//! use insuwb_zenoh::payload::Payload;
//! use insuwb_zenoh::session;
//! use zenoh::Wait;
//! let link = LinkConfig {
//!     mode: Mode::Router,
//!     listen: vec!["tcp/0.0.0.0:7447".into()],
//!     ..LinkConfig::default()
//! };
//! let s = session::open(&link)?;
//! let poses = s.declare_subscriber(Kind::Pose.subscription()).wait()?;
//! while let Ok(sample) = poses.recv() {
//!     match session::decode_sample(&sample) {
//!         Ok(r) => {
//!             if let Payload::Pose(p) = r.payload {
//!                 println!("{}: {:?}", r.key.robot(), p.sample().pos_m);
//!             }
//!         }
//!         Err(e) => eprintln!("{e}"),
//!     }
//! }
//! # Ok::<(), Box<dyn std::error::Error + Send + Sync>>(())
//! ```

use std::path::Path;

use zenoh::sample::Sample;
use zenoh::{Session, Wait};

use crate::config::{is_tls, LinkConfig, ZenohConfigError};
use crate::payload::{self, DecodeError, Received};

/// Making the configuration or opening the session failed.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The link configuration is invalid.
    #[error("SessionError::Config: {0}")]
    Config(#[from] ZenohConfigError),
    /// Zenoh refused a configuration value.
    #[error("SessionError::ZenohConfig: {key}: {reason}")]
    ZenohConfig {
        /// The Zenoh configuration key.
        key: &'static str,
        /// Zenoh's error.
        reason: String,
    },
    /// Zenoh could not open the session (an endpoint to listen on in use,
    /// a certificate it cannot read, a client with no router reachable).
    #[error("SessionError::Open: {0}")]
    Open(String),
}

fn json<T: serde::Serialize + ?Sized>(v: &T) -> String {
    // Strings, string arrays and booleans always serialize.
    serde_json::to_string(v).unwrap_or_default()
}

fn path_json(p: &Path) -> String {
    json(&p.to_string_lossy())
}

/// The `zenoh::Config` of a link (validated first): see the module's
/// documentation for every key it sets.
///
/// # Errors
/// [`SessionError::Config`] for an invalid link, [`SessionError::ZenohConfig`]
/// for a value Zenoh refuses.
pub fn zenoh_config(link: &LinkConfig) -> Result<zenoh::Config, SessionError> {
    link.validate()?;
    let mut c = zenoh::Config::default();
    let mut set = |key: &'static str, value: String| {
        c.insert_json5(key, &value)
            .map_err(|e| SessionError::ZenohConfig {
                key,
                reason: e.to_string(),
            })
    };
    set("mode", json(link.mode.name()))?;
    set("connect/endpoints", json(&link.connect))?;
    set("listen/endpoints", json(&link.listen))?;
    set("scouting/multicast/enabled", "false".into())?;
    set("scouting/gossip/enabled", "false".into())?;
    let t = &link.tls;
    let uses_tls = link.connect.iter().chain(&link.listen).any(|e| is_tls(e));
    if uses_tls || t.root_ca_certificate.is_some() {
        if let Some(ca) = &t.root_ca_certificate {
            set("transport/link/tls/root_ca_certificate", path_json(ca))?;
        }
        if let (Some(cert), Some(key)) = (&t.certificate, &t.private_key) {
            set("transport/link/tls/listen_certificate", path_json(cert))?;
            set("transport/link/tls/listen_private_key", path_json(key))?;
            set("transport/link/tls/connect_certificate", path_json(cert))?;
            set("transport/link/tls/connect_private_key", path_json(key))?;
        }
        set("transport/link/tls/enable_mtls", json(&t.mutual))?;
        set(
            "transport/link/tls/verify_name_on_connect",
            json(&t.verify_name),
        )?;
    }
    Ok(c)
}

/// Opens a session on `link` ([`zenoh_config`]), with every asynchronous
/// signal blocked while Zenoh starts its threads, so that SIGTERM and
/// SIGINT reach the stage's own thread.
///
/// Each plain `tcp/` endpoint off the loopback is warned about
/// ([`LinkConfig::plain_off_loopback`]; refused by [`zenoh_config`] under
/// `require_tls`).
///
/// A peer or router returns at once while the endpoints to connect to are
/// down (it retries in the background); a client waits for one.
///
/// # Errors
/// [`SessionError`] naming what failed.
pub fn open(link: &LinkConfig) -> Result<Session, SessionError> {
    open_with_access_control(link, None)
}

/// [`open`] with Zenoh's `access_control` set to `acl` (the station's,
/// [`crate::identity::IdentitySettings::access_control_json`]).
///
/// # Errors
/// [`SessionError`] naming what failed; Zenoh's refusal of the access
/// control as [`SessionError::ZenohConfig`] with key `access_control`.
pub fn open_with_access_control(
    link: &LinkConfig,
    acl: Option<&serde_json::Value>,
) -> Result<Session, SessionError> {
    let mut config = zenoh_config(link)?;
    if let Some(acl) = acl {
        config
            .insert_json5("access_control", &acl.to_string())
            .map_err(|e| SessionError::ZenohConfig {
                key: "access_control",
                reason: e.to_string(),
            })?;
    }
    for (key, e) in link.plain_off_loopback() {
        tracing::warn!(
            "{key}: {}; require_tls = true refuses it",
            crate::config::plain_tcp_text(e)
        );
    }
    insuwb_runtime::signal::with_signals_blocked(|| zenoh::open(config).wait())
        .map_err(|e| SessionError::Open(e.to_string()))
}

/// The key, robot and decoded payload of a received sample
/// ([`payload::decode`] of its key expression, encoding, payload and
/// attachment).
///
/// # Errors
/// [`DecodeError`] for a sample that is not a fleet payload of this
/// version.
pub fn decode_sample(sample: &Sample) -> Result<Received, DecodeError> {
    let attachment = sample.attachment().map(|a| a.to_bytes());
    payload::decode(
        sample.key_expr().as_str(),
        &sample.encoding().to_string(),
        &sample.payload().to_bytes(),
        attachment.as_deref(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Mode, TlsConfig};

    fn get(c: &zenoh::Config, key: &str) -> serde_json::Value {
        serde_json::from_str(&c.get_json(key).unwrap()).unwrap()
    }

    #[test]
    fn nothing_is_listened_on_or_scouted_unless_configured() {
        let link = LinkConfig {
            connect: vec!["tcp/127.0.0.1:7447".into()],
            ..LinkConfig::default()
        };
        let c = zenoh_config(&link).unwrap();
        assert_eq!(get(&c, "mode"), "peer");
        assert_eq!(
            get(&c, "connect/endpoints"),
            serde_json::json!(["tcp/127.0.0.1:7447"])
        );
        assert_eq!(get(&c, "listen/endpoints"), serde_json::json!([]));
        assert_eq!(get(&c, "scouting/multicast/enabled"), false);
        assert_eq!(get(&c, "scouting/gossip/enabled"), false);
        assert!(get(&c, "transport/link/tls/root_ca_certificate").is_null());
        let router = zenoh_config(&LinkConfig {
            mode: Mode::Router,
            listen: vec!["tcp/127.0.0.1:0".into()],
            ..LinkConfig::default()
        })
        .unwrap();
        assert_eq!(get(&router, "mode"), "router");
        assert_eq!(
            get(&router, "listen/endpoints"),
            serde_json::json!(["tcp/127.0.0.1:0"])
        );
    }

    #[test]
    fn tls_settings_name_the_certificates_and_mutual_auth() {
        let dir = std::env::temp_dir().join(format!("insuwb-zenoh-sess-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let [ca, cert, key] = ["ca.pem", "c.pem", "k.pem"].map(|n| {
            let p = dir.join(n);
            std::fs::write(&p, "x").unwrap();
            p
        });
        let link = LinkConfig {
            connect: vec!["tls/127.0.0.1:7447".into()],
            tls: TlsConfig {
                root_ca_certificate: Some(ca.clone()),
                certificate: Some(cert.clone()),
                private_key: Some(key.clone()),
                ..TlsConfig::default()
            },
            ..LinkConfig::default()
        };
        let c = zenoh_config(&link).unwrap();
        let s = |p: &Path| serde_json::Value::from(p.to_string_lossy().into_owned());
        assert_eq!(get(&c, "transport/link/tls/root_ca_certificate"), s(&ca));
        assert_eq!(get(&c, "transport/link/tls/connect_certificate"), s(&cert));
        assert_eq!(get(&c, "transport/link/tls/connect_private_key"), s(&key));
        assert_eq!(get(&c, "transport/link/tls/listen_certificate"), s(&cert));
        assert_eq!(get(&c, "transport/link/tls/enable_mtls"), true);
        assert_eq!(get(&c, "transport/link/tls/verify_name_on_connect"), true);
        let e = zenoh_config(&LinkConfig {
            tls: TlsConfig::default(),
            ..link
        })
        .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("SessionError::Config: key 'zenoh.tls.root_ca_certificate'"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(dir);
    }
}
