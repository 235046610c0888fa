//! Links with cortex-m-rt's `link.x` and this crate's `memory.x` (the QEMU mps2-an386 map),
//! put first on the search path so the firmware's STM32 map in the root is never picked up.
//!
//! The link argument lives here rather than in `.cargo/config.toml` so that it applies
//! whatever directory cargo runs from (config files are looked up from the current
//! directory, not from the manifest's).

use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::copy("memory.x", out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    // Editing memory.x alone must relink.
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
}
