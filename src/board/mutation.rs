//! Deliberate mistakes, for the mutation tests only (`scripts/fw-mutants.sh`, `fpc-pil
//! mutants`, `docs/testing.md`): each proves that the emulator and the boot check catch the
//! firmware getting that part of the chip's configuration wrong.
//!
//! A mutant is the release build with `FPC_MUTATION=<name>` in the environment. Only this
//! binary crate reads the variable (`option_env!`), so a mutant rebuilds and relinks the
//! firmware binary alone, never the library or a dependency. The release ELF is built without
//! it: every [`is`] is then a constant `false` and its branch is not compiled in.

/// The mutation this build carries, if any.
const ACTIVE: Option<&str> = option_env!("FPC_MUTATION");

/// Every mutation, by name (a build with any other name fails to compile).
pub const ALL: [&str; 14] = [
    "ossi-clear",
    "ois-high",
    "bke-off",
    "break-polarity-inverted",
    "dead-time-zero",
    "iwdg-key-order-swapped",
    "rlr-before-rvu",
    "jsqr-while-jadstart",
    "dma-psize-16",
    "flash-over-stale-flags",
    "bor-zero-accepted",
    "stack-overflow",
    "late-duties",
    "control-critical-section",
];

const fn same(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

const fn known(name: &str) -> bool {
    let mut i = 0;
    while i < ALL.len() {
        if same(ALL[i], name) {
            return true;
        }
        i += 1;
    }
    false
}

const _: () = assert!(
    match ACTIVE {
        Some(name) => known(name),
        None => true,
    },
    "FPC_MUTATION names no mutation (see board::mutation::ALL)"
);

/// Whether this build carries mutation `name` (a compile-time constant).
pub const fn is(name: &str) -> bool {
    match ACTIVE {
        Some(active) => same(active, name),
        None => false,
    }
}
