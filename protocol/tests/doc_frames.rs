//! `docs/PROTOCOL.md` shows the worked example frames exactly as the crate encodes them,
//! and each of them decodes back to a valid frame.

#[path = "../examples/doc_frames.rs"]
mod doc_frames;

use protocol::{Command, Report};

const DOC: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/PROTOCOL.md");

fn doc_text() -> String {
    std::fs::read_to_string(DOC).unwrap_or_else(|e| panic!("cannot read {DOC}: {e}"))
}

#[test]
fn every_example_frame_is_in_the_document() {
    let doc = doc_text();
    let frames = doc_frames::doc_frames();
    assert!(!frames.is_empty());
    let missing: Vec<String> = frames
        .iter()
        .filter(|f| !doc.contains(&format!("```text\n{}\n```", f.hex_block())))
        .map(|f| format!("{}:\n{}", f.caption, f.hex_block()))
        .collect();
    assert!(
        missing.is_empty(),
        "docs/PROTOCOL.md lacks these frames (regenerate with \
         `cargo run -p protocol --example doc_frames`):\n{}",
        missing.join("\n\n")
    );
}

#[test]
fn every_example_frame_decodes() {
    for f in doc_frames::doc_frames() {
        if f.to_controller {
            let frame = Command::decode(&f.bytes);
            assert!(frame.is_ok(), "{}: {frame:?}", f.caption);
        } else {
            let frame = Report::decode(&f.bytes);
            assert!(frame.is_ok(), "{}: {frame:?}", f.caption);
        }
    }
}

/// Every hex block in the document is a whole frame with a correct CRC, so that no block
/// can be left behind when the examples change.
#[test]
fn every_hex_block_in_the_document_is_an_example_frame() {
    let doc = doc_text();
    let examples: Vec<Vec<u8>> = doc_frames::doc_frames()
        .into_iter()
        .map(|f| f.bytes)
        .collect();
    let mut blocks = 0;
    for block in doc.split("```text\n").skip(1) {
        let body = block.split("\n```").next().unwrap_or_default();
        let bytes: Vec<u8> = body
            .split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap_or_else(|e| panic!("{b:?} in {body}: {e}")))
            .collect();
        assert!(
            examples.contains(&bytes),
            "a hex block of docs/PROTOCOL.md is not an example frame:\n{body}"
        );
        blocks += 1;
    }
    assert_eq!(blocks, examples.len(), "hex blocks in the document");
}
