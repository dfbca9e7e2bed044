//! The Foxglove layout in deploy/foxglove/ names only what the live view
//! serves: every topic is one of its channels under the default prefix,
//! every plotted or tabled field is a property of its channel's JSON
//! schema, and the 3D panel follows the body frame.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use insuwb_foxglove::config::TOPICS;
use insuwb_foxglove::convert::{
    BODY_VEL_SCHEMA, DIAG_SCHEMA, ERROR_SCHEMA, HEALTH_SCHEMA, UWB_RANGE_SCHEMA,
};
use insuwb_foxglove::FoxgloveConfig;
use serde_json::Value;

const LAYOUT: &str = include_str!("../../../../deploy/foxglove/insuwb-live.json");

/// The JSON schema's properties of a JSON topic (`None` for protobuf ones).
fn json_properties(topic: &str) -> Option<Value> {
    let schema = match topic {
        "diag" => DIAG_SCHEMA,
        "error" => ERROR_SCHEMA,
        "body_vel" => BODY_VEL_SCHEMA,
        "uwb_range" => UWB_RANGE_SCHEMA,
        "health" => HEALTH_SCHEMA,
        _ => return None,
    };
    let v: Value = serde_json::from_str(schema).unwrap();
    Some(v["properties"].clone())
}

/// `/insuwb/diag.normalized_innovation[0]` -> (`diag`, `normalized_innovation`).
fn split(path: &str) -> (String, String) {
    let c = FoxgloveConfig::default();
    let prefix = format!("{}/", c.topic_prefix);
    let rest = path
        .strip_prefix(&prefix)
        .unwrap_or_else(|| panic!("{path} is not under {prefix}"));
    let (topic, field) = rest.split_once('.').unwrap_or((rest, ""));
    let field = field.split(['[', '.']).next().unwrap_or("");
    (topic.to_owned(), field.to_owned())
}

#[test]
fn the_layout_names_only_what_the_live_view_serves() {
    let layout: Value = serde_json::from_str(LAYOUT).unwrap();
    let panels = layout["configById"].as_object().unwrap();
    let mut fields = Vec::new();
    let mut plots = 0;
    for (id, cfg) in panels {
        if id.starts_with("Plot!") {
            plots += 1;
            for p in cfg["paths"].as_array().unwrap() {
                fields.push(p["value"].as_str().unwrap().to_owned());
            }
        }
        if let Some(t) = cfg["topicPath"].as_str() {
            fields.push(t.to_owned());
        }
        if let Some(topics) = cfg["topics"].as_object() {
            for t in topics.keys() {
                let (topic, field) = split(t);
                assert!(TOPICS.contains(&topic.as_str()), "{id}: {t}");
                assert!(field.is_empty(), "{id}: {t}");
            }
        }
    }
    assert!(plots >= 4, "{plots} plots");
    assert!(!fields.is_empty());
    for path in &fields {
        let (topic, field) = split(path);
        assert!(TOPICS.contains(&topic.as_str()), "{path}");
        let props = json_properties(&topic).unwrap_or_else(|| panic!("{path}: not a JSON topic"));
        assert!(props.get(&field).is_some(), "{path}: no field {field}");
    }
    for want in [
        "fading",
        "outlier_weight",
        "normalized_innovation",
        "horizontal_m",
    ] {
        assert!(fields.iter().any(|f| f.contains(want)), "no plot of {want}");
    }
    // The 3D panel follows the fused pose's transform and shows the anchors.
    let three_d = panels
        .iter()
        .find(|(id, _)| id.starts_with("3D!"))
        .map(|(_, c)| c)
        .unwrap();
    assert_eq!(
        three_d["followTf"],
        FoxgloveConfig::default().child_frame_id
    );
    assert_eq!(three_d["topics"]["/insuwb/anchors"]["visible"], true);
    // Every panel of the arrangement is configured, and the reverse.
    fn leaves<'a>(v: &'a Value, out: &mut Vec<&'a str>) {
        match v {
            Value::String(s) => out.push(s),
            Value::Object(o) => {
                leaves(&o["first"], out);
                leaves(&o["second"], out);
            }
            _ => panic!("bad layout node {v}"),
        }
    }
    let mut ids = Vec::new();
    leaves(&layout["layout"], &mut ids);
    ids.sort_unstable();
    let mut configured: Vec<&str> = panels.keys().map(String::as_str).collect();
    configured.sort_unstable();
    assert_eq!(ids, configured);
}
