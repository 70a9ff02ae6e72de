//! Puts the repository root, where `memory.x` lives, on the linker's search path.
//!
//! cortex-m-rt's `link.x` does `INCLUDE memory.x`; the linker finds it only on its search
//! path, and cargo runs it from an unspecified directory. The link arguments themselves
//! (`--nmagic -Tlink.x -Tdefmt.x`) come from `.cargo/config.toml`.

use std::path::Path;

fn main() {
    let manifest_dir = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into());
    let root = Path::new(&manifest_dir).join("../..");
    let memory_x = root.join("memory.x");
    println!("cargo:rustc-link-search={}", root.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");
}
