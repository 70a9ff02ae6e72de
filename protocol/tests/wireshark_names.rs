//! The Wireshark dissector (`tools/wireshark/arm_controller.lua`, Lua: it cannot use the
//! crate) keeps its own tables of tag, state and status names: they must be the crate's,
//! value for value.

use std::collections::BTreeMap;

use protocol::{State, StatusCode, Tag};

const DISSECTOR: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tools/wireshark/arm_controller.lua"
);

/// The `[value] = "NAME"` entries of the Lua table `local <table> = { ... }`.
fn lua_names(table: &str) -> BTreeMap<u8, String> {
    let source = std::fs::read_to_string(DISSECTOR).expect("the dissector");
    let start = source
        .find(&format!("local {table} = {{"))
        .unwrap_or_else(|| panic!("no table {table} in the dissector"));
    let body = &source[start..];
    let body = &body[..body.find('}').expect("the table's end")];
    body.split('[')
        .skip(1)
        .map(|entry| {
            let (value, rest) = entry.split_once(']').expect("[value]");
            let value = match value.strip_prefix("0x") {
                Some(hex) => u8::from_str_radix(hex, 16),
                None => value.parse(),
            }
            .expect("a byte");
            let name = rest.split('"').nth(1).expect("a quoted name");
            (value, name.to_owned())
        })
        .collect()
}

fn crate_names<T: Copy + Into<u8>>(all: &[T], name: fn(T) -> &'static str) -> BTreeMap<u8, String> {
    all.iter()
        .map(|&c| (c.into(), name(c).to_owned()))
        .collect()
}

#[test]
fn dissector_tag_names_are_the_crates() {
    let mut lua = lua_names("tag_names");
    // 0x13 is named for both directions there ("LOCATION_SETTING/LOCATION").
    let location = lua.get_mut(&(Tag::Location as u8)).expect("0x13");
    assert_eq!(location, "LOCATION_SETTING/LOCATION");
    *location = Tag::Location.name().to_owned();
    assert_eq!(lua, crate_names(Tag::ALL, Tag::name));
}

#[test]
fn dissector_state_and_status_names_are_the_crates() {
    assert_eq!(
        lua_names("state_names"),
        crate_names(State::ALL, State::name)
    );
    assert_eq!(
        lua_names("status_names"),
        crate_names(StatusCode::ALL, StatusCode::name)
    );
}
