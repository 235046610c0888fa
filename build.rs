//! Build script: links the firmware (`--bin fpc` for `thumbv7em-none-eabihf`) with
//! cortex-m-rt's `link.x`, defmt's `defmt.x` and our `memory.x`.
//!
//! The link arguments live here, scoped to this package's binaries and to `target_os =
//! "none"`, rather than as `rustflags` in `.cargo/config.toml`: cargo merges config files
//! from every parent directory, so rustflags there would also reach `bench/cm4` (its own
//! workspace, with its own memory map and no defmt) and break its link. Host builds (tests,
//! `hal-sim`) never see any of it. The rerun line makes an edit of `memory.x` alone relink.

use std::env;
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=memory.x");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").expect("set by cargo"));
        println!("cargo:rustc-link-search={}", dir.display());
        // --nmagic: sections need not be page-aligned in the file (flash is not paged).
        println!("cargo:rustc-link-arg-bins=--nmagic");
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
