//! The live view between real iceoryx2 and a real WebSocket client: UWB
//! ranges published on `uwb_range` reach `/insuwb/uwb_range` and their
//! anchors `/insuwb/anchors`. The loop's drains are called one by one, so
//! that each step is known; the client is written from the protocol's
//! specification (`foxglove.sdk.v1`: JSON text frames, binary `messageData`
//! frames of opcode 1, subscription id and log time).

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use foxglove::Decode;
use insuwb_msg::Header;
use insuwb_report::report_loop::ReportOutputs;
use insuwb_runtime::cleanup;
use serde_json::Value;

use super::*;

/// A message from the server.
enum Msg {
    /// A JSON text frame.
    Text(Value),
    /// `messageData`: subscription id, log time, payload.
    Data(u32, u64, Vec<u8>),
}

/// A client of the Foxglove WebSocket protocol that keeps what it received
/// and has not been asked for yet.
struct Client {
    s: TcpStream,
    kept: Vec<Msg>,
}

impl Client {
    fn connect(addr: SocketAddr) -> Self {
        let mut s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        write!(
            s,
            "GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
             Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
        )
        .unwrap();
        // The response, byte by byte: the frames after it stay unread.
        let mut head = Vec::new();
        while !head.ends_with(b"\r\n\r\n") {
            let mut b = [0u8; 1];
            s.read_exact(&mut b).unwrap();
            head.push(b[0]);
        }
        let head = String::from_utf8_lossy(&head);
        assert!(head.starts_with("HTTP/1.1 101"), "{head}");
        assert!(head.contains("foxglove.sdk.v1"), "{head}");
        Self {
            s,
            kept: Vec::new(),
        }
    }

    /// Sends a text frame (masked, as a client must; a zero key).
    fn send(&mut self, v: &Value) {
        let p = v.to_string().into_bytes();
        let mut f = vec![0x81];
        match u16::try_from(p.len()) {
            Ok(n) if n < 126 => f.push(0x80 | n as u8),
            Ok(n) => {
                f.push(0x80 | 126);
                f.extend(n.to_be_bytes());
            }
            Err(_) => panic!("frame too long"),
        }
        f.extend([0u8; 4]);
        f.extend(p);
        self.s.write_all(&f).unwrap();
    }

    /// The next message of the server (pings and pongs skipped).
    fn read(&mut self) -> Msg {
        loop {
            let mut h = [0u8; 2];
            self.s.read_exact(&mut h).expect("a frame within 5 s");
            assert_eq!(h[0] & 0x80, 0x80, "a fragmented frame");
            assert_eq!(h[1] & 0x80, 0, "a masked server frame");
            let len = match h[1] & 0x7f {
                126 => {
                    let mut b = [0u8; 2];
                    self.s.read_exact(&mut b).unwrap();
                    usize::from(u16::from_be_bytes(b))
                }
                127 => {
                    let mut b = [0u8; 8];
                    self.s.read_exact(&mut b).unwrap();
                    usize::try_from(u64::from_be_bytes(b)).unwrap()
                }
                n => usize::from(n),
            };
            let mut p = vec![0u8; len];
            self.s.read_exact(&mut p).unwrap();
            match h[0] & 0x0f {
                1 => return Msg::Text(serde_json::from_slice(&p).unwrap()),
                2 => {
                    assert_eq!(p[0], 1, "binary opcode {}", p[0]);
                    let sub = u32::from_le_bytes(p[1..5].try_into().unwrap());
                    let t = u64::from_le_bytes(p[5..13].try_into().unwrap());
                    return Msg::Data(sub, t, p[13..].to_vec());
                }
                9 | 10 => {}
                op => panic!("frame opcode {op}: {}", String::from_utf8_lossy(&p)),
            }
        }
    }

    /// The first message, kept or next, that `pick` accepts.
    fn wait<T>(&mut self, mut pick: impl FnMut(&Msg) -> Option<T>) -> T {
        let mut i = 0;
        loop {
            if i == self.kept.len() {
                let m = self.read();
                self.kept.push(m);
            }
            if let Some(v) = pick(&self.kept[i]) {
                self.kept.remove(i);
                return v;
            }
            i += 1;
        }
    }

    /// The id of channel `topic` at its advertisement, with the
    /// advertisement's other topics.
    fn advertised(&mut self, topic: &str) -> (u64, Vec<String>) {
        self.wait(|m| {
            let Msg::Text(v) = m else { return None };
            if v["op"] != "advertise" {
                return None;
            }
            let chans = v["channels"].as_array()?;
            let ch = chans.iter().find(|c| c["topic"] == topic)?;
            let topics = chans
                .iter()
                .filter_map(|c| c["topic"].as_str().map(str::to_owned))
                .collect();
            Some((ch["id"].as_u64()?, topics))
        })
    }

    fn subscribe(&mut self, sub: u32, channel: u64) {
        self.send(&serde_json::json!({
            "op": "subscribe",
            "subscriptions": [{"id": sub, "channelId": channel}],
        }));
    }
}

/// The test's iceoryx2 files, removed at the end.
struct Files {
    prefix: String,
    root: PathBuf,
}

impl Drop for Files {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix_files(&self.prefix, Some(&self.root));
    }
}

fn until(what: &str, mut ok: impl FnMut() -> bool) {
    let end = Instant::now() + Duration::from_secs(5);
    while !ok() {
        assert!(Instant::now() < end, "not within 5 s: {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn anchor_ids(payload: &[u8]) -> Vec<String> {
    SceneUpdate::decode(payload)
        .unwrap()
        .entities
        .into_iter()
        .map(|e| e.id)
        .collect()
}

#[test]
fn uwb_ranges_and_their_anchors_reach_a_websocket_client() {
    let prefix = format!("iwfx{}_", std::process::id());
    let files = Files {
        root: std::env::temp_dir().join(format!("{prefix}iox2")),
        prefix,
    };
    let cfg = |stage: &str| RuntimeConfig {
        prefix: files.prefix.clone(),
        root_path: Some(files.root.clone()),
        stage_name: stage.into(),
        ..RuntimeConfig::default()
    };
    let uwb = Stage::new(cfg("uwb")).unwrap();
    let mut ranges = uwb.publisher::<UwbRange>(topics::UWB_RANGE).unwrap();
    let range = |anchor: u32, range_m: f64, flags: u32| {
        let mut r = UwbRange {
            header: Header::new(0, monotonic_ns()),
            anchor,
            quality: 90,
            range_m,
            anchor_pos_m: [f64::from(anchor), -1.0, 2.0],
        };
        r.header.flags = flags;
        r
    };
    // Published before the view opens: its anchor is shown, the range not.
    ranges.publish(range(3, 4.0, 0)).unwrap();

    let mut view = LiveView::open(LiveSetup {
        runtime: cfg("foxglove"),
        foxglove: FoxgloveConfig {
            bind: "127.0.0.1:0".into(),
            ..FoxgloveConfig::default()
        },
        stages: Vec::new(),
        server_name: "test".into(),
        anchors: Vec::new(),
        truth: false,
    })
    .unwrap();
    let mut client = Client::connect(view.addr());
    let (anchors_id, first) = client.advertised("/insuwb/anchors");
    assert!(
        !first.iter().any(|t| t == "/insuwb/uwb_range"),
        "no range yet, no channel: {first:?}"
    );
    client.subscribe(1, anchors_id);
    until("the anchors' subscription", || {
        view.out.anchors_ch.has_sinks()
    });

    let mut group = GroupSeen::new(&[]);
    let clock = ClockOffset::ZERO;
    let mut drain = |view: &mut LiveView| {
        view.out.drain(&view.inputs, &clock, &mut group).unwrap();
        view.out.between_reports(&clock);
    };
    ranges.update_connections().unwrap();
    drain(&mut view);
    assert_eq!((view.out.stats.old, view.out.stats.ranges), (1, 0));
    assert!(matches!(view.out.uwb_range, LazyChannel::NotYet));
    let ids = client.wait(|m| match m {
        Msg::Data(1, _, p) => Some(anchor_ids(p)),
        _ => None,
    });
    assert_eq!(ids, ["anchor/3"]);

    // A NaN range is refused; a good one makes the channel.
    ranges.publish(range(5, f64::NAN, 0)).unwrap();
    ranges
        .publish(range(7, 6.5, UwbRange::FLAG_QUALITY))
        .unwrap();
    drain(&mut view);
    assert_eq!((view.out.stats.invalid, view.out.stats.ranges), (1, 1));
    let (range_id, _) = client.advertised("/insuwb/uwb_range");
    client.subscribe(2, range_id);
    let anchors = [3, 5, 7].map(|a| format!("anchor/{a}"));
    client.wait(|m| match m {
        Msg::Data(1, _, p) => (anchor_ids(p) == anchors).then_some(()),
        _ => None,
    });
    until("the ranges' subscription", || match &view.out.uwb_range {
        LazyChannel::Open(ch) => ch.0.has_sinks(),
        _ => false,
    });

    let sent = range(7, 6.25, UwbRange::FLAG_OFFSET_REMOVED);
    ranges.publish(sent).unwrap();
    drain(&mut view);
    let (t, json) = client.wait(|m| match m {
        Msg::Data(2, t, p) => Some((*t, serde_json::from_slice::<Value>(p).unwrap())),
        _ => None,
    });
    let meas = sent.header.meas_time_ns;
    assert_eq!(t, meas, "logged at its measurement time");
    assert_eq!(json["timestamp"]["sec"], meas / 1_000_000_000);
    assert_eq!(json["timestamp"]["nsec"], meas % 1_000_000_000);
    assert_eq!(json["anchor"], 7);
    assert_eq!(json["range_m"], 6.25);
    assert!(json["quality"].is_null(), "{json}");
    assert_eq!(json["offset_removed"], true);
    assert_eq!(json["anchor_pos_m"], serde_json::json!([7.0, -1.0, 2.0]));

    let c = view.out.counters(&view.inputs);
    assert_eq!((c.received, c.published), (4, 2));
    assert_eq!((c.dropped_invalid, c.dropped_time), (1, 1));
    view.out.stop();
    drop(view);
    drop(ranges);
    drop(uwb);
    drop(files);
}
