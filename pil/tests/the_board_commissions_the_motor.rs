//! The motor's commissioning on the bench build's ELF in the emulated STM32G474: the reference
//! machine wired correctly, with a swapped phase pair in the slave section, and with a
//! reversed master encoder; each found and named in the lines the host prints
//! (`fpc-sim link send calibrate …`'s code over the emulated board's RTT channels), which are
//! `docs/bring-up.md` §10's board blocks, byte for byte, and the control period kept its
//! deadline throughout. The release ELF refuses the commissioning and says why.
//!
//! The bench ELF is `FPC_BENCH_ELF` if set, else `target/fpc-bench`; the release ELF `FPC_ELF`,
//! else the `cargo fw` output. Build them first (CI does).

use fpc::units::PerSection;
use fpc_pil::commission::commission;
use fpc_pil::elf::Image;
use hal_sim::board::wiring::Wiring;

fn bench_image() -> Image {
    Image::built(
        "FPC_BENCH_ELF",
        "target/fpc-bench",
        "build it: bash scripts/fw-test-elf.sh bench",
    )
}

fn release_image() -> Image {
    Image::built(
        "FPC_ELF",
        "target/thumbv7em-none-eabihf/release/fpc",
        "build it: cargo fw",
    )
}

/// The console blocks of `docs/bring-up.md` that run `calibrate commission` on the board, in
/// order.
fn board_blocks() -> Vec<String> {
    let guide = include_str!("../../docs/bring-up.md");
    guide
        .split("```console\n")
        .skip(1)
        .filter_map(|b| b.split("```").next())
        .filter(|b| b.contains("$ fpc-sim link send calibrate commission\n"))
        .map(str::to_string)
        .collect()
}

/// The session as the guide shows it: each command typed, then what the host printed.
fn session(lines: &[String]) -> String {
    let mut text = String::new();
    let mut typed =
        |routine: &str| text.push_str(&format!("$ fpc-sim link send calibrate {routine}\n"));
    let mut out = String::new();
    typed("current-sense");
    for line in lines {
        if line == "accepted: calibrate commission" {
            text.push_str(&out);
            out.clear();
            text.push_str("$ fpc-sim link send calibrate commission\n");
        }
        out.push_str(line);
        out.push('\n');
    }
    text + &out
}

#[test]
fn the_board_finds_and_names_each_wiring_fault_as_the_bring_up_guide_shows() {
    let one = |master, slave| PerSection { master, slave };
    let cases = [
        (Wiring::default(), None),
        (
            Wiring {
                swapped_phases: one(false, true),
                ..Wiring::default()
            },
            Some("phases swapped in section slave"),
        ),
        (
            Wiring {
                reversed_encoder: one(true, false),
                ..Wiring::default()
            },
            Some("master encoder reversed"),
        ),
    ];
    let mut printed_all = Vec::new();
    for (wiring, named) in cases {
        let r = commission(&bench_image(), wiring).unwrap_or_else(|e| panic!("{wiring:?}: {e}"));
        println!("{wiring:?}: {:.2} s emulated; {}", r.end_s, r.deadline);
        let printed = session(&r.lines);
        print!("{printed}");
        assert_eq!(r.error, None, "{wiring:?}");
        let faults: Vec<&String> = r
            .lines
            .iter()
            .filter(|l| l.contains("swapped") || l.contains("reversed"))
            .collect();
        match named {
            None => assert!(faults.is_empty(), "{faults:?}"),
            Some(named) => assert_eq!(faults, [named], "{wiring:?}"),
        }
        assert!(
            r.lines.iter().filter(|l| l.ends_with("mm: ok")).count() == 2,
            "{:?}",
            r.lines
        );
        let d = &r.deadline;
        assert_eq!(d.missed_updates, 0, "{d:?}");
        assert!(d.worst_cycle_cycles * 4 <= d.deadline_cycles * 3, "{d:?}");
        printed_all.push(printed);
    }
    assert_eq!(
        printed_all,
        board_blocks(),
        "bring-up.md §10's board blocks: the correct wiring, the slave's phases, the master \
         encoder"
    );
}

#[test]
fn the_release_firmware_refuses_the_commissioning_and_names_the_bench_build() {
    let r = commission(&release_image(), Wiring::default()).unwrap_or_else(|e| panic!("{e}"));
    print!("{}", session(&r.lines));
    let error = r.error.unwrap_or_default();
    assert!(
        error.contains("flash the bench build"),
        "{error:?} after {:?}",
        r.lines
    );
    assert!(
        r.lines.iter().any(
            |l| l.starts_with("current_sense accepted; this firmware reports no routine's end")
        ),
        "{:?}",
        r.lines
    );
    assert_eq!(r.deadline.missed_updates, 0, "{:?}", r.deadline);
}
