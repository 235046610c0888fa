//! The PIL's tests on the firmware ELFs, one test binary: each file of `tests/` is a module
//! named after what the board does, and is listed here (`.ci/run` fails on a file that is
//! not). Each test binary is a fat-LTO link of the emulator, the plant and probe-rs, and
//! one binary's tests share its threads, where binaries run one after another.
//!
//!   cargo test --release --target-dir ../target                       # all of them
//!   cargo test --release --target-dir ../target the_host_link        # one file's

mod the_board_commissions_the_motor;
mod the_board_drives_the_bring_up_bench_operations;
mod the_flashed_binary_runs_the_machine;
mod the_host_link_never_halts_the_core;
mod the_timing_build_counts_on_after_a_debugger_detaches;
