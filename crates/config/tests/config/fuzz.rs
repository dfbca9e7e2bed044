//! Property test of the TOML loader: any text, valid or not, gives a value or
//! an error naming the origin, never a panic.
#![allow(clippy::unwrap_used, clippy::panic)]

use proptest::prelude::*;

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)]
struct Inner {
    gamma: f64,
    names: Vec<String>,
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)]
struct Outer {
    filter: Inner,
    rate_hz: Option<f64>,
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, .. ProptestConfig::default() })]

    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,200}") {
        if let Err(e) = insuwb_config::load_str::<Outer>(&text, "fuzz.toml") {
            prop_assert!(e.to_string().starts_with("fuzz.toml"), "{e}");
        }
    }

    #[test]
    fn toml_shaped_text_never_panics(
        key in "[a-z_.]{1,12}",
        value in prop_oneof!["-?[0-9]{1,6}(\\.[0-9]{1,4})?", "'[^']{0,10}'", "\\[[0-9, ]{0,10}\\]", "nan", "inf", "true"],
        table in "(\\[[a-z_.]{1,10}\\])?",
    ) {
        let text = format!("{table}\n{key} = {value}\n");
        if let Err(e) = insuwb_config::load_str::<Outer>(&text, "fuzz.toml") {
            prop_assert!(e.to_string().starts_with("fuzz.toml"), "{e}");
        }
    }
}
