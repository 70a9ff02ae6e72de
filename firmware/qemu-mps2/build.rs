//! Puts this crate's directory on the linker's search path: its `memory.x` (the MPS2
//! AN500's memory map) and `device.x` (cortex-m-rt's `device` feature: the interrupt vectors
//! are `mps2::__INTERRUPTS`), and an empty `defmt.x`, since the workspace's rustflags for
//! the target pass `-Tdefmt.x` and this image logs as text, without defmt.

use std::path::Path;

fn main() {
    let manifest_dir = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into());
    let dir = Path::new(&manifest_dir);
    println!("cargo:rustc-link-search={}", dir.display());
    for file in ["memory.x", "device.x", "defmt.x"] {
        println!("cargo:rerun-if-changed={}", dir.join(file).display());
    }
    println!("cargo:rerun-if-changed=build.rs");
}
