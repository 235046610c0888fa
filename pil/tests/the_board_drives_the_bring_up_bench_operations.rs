//! The bring-up's bench operations on the bench build's ELF in the emulated STM32G474, its
//! bridges on a 12 V bench supply (power-good low since boot, as `docs/bring-up.md` §2 has
//! it): a fixed duty on one phase of one section (§2) and a torque to the servo drive
//! (§9.3). What the host prints (`fpc-sim link send bench …`'s code over the emulated
//! board's RTT channels) is the guide's console blocks, byte for byte; what the printout
//! says the chip drives is read back from the chip — the output stages (MOE, OSSI, CCxE,
//! CCxNE, polarity), the compare registers, the DAC — and `stop` ends each. The release ELF
//! says which build to flash.
//!
//! The bench ELF is `FPC_BENCH_ELF` if set, else `target/fpc-bench`; the release ELF `FPC_ELF`,
//! else the `cargo fw` output. Build them first (CI does).

use fpc::control::command::BenchOp;
use fpc::safety::absent::Part;
use fpc::status::ModeKind;
use fpc::units::{DacCode, Duty, PerSection, Section, PWM_COMPARE_STEPS};
use fpc_pil::bench::Bench;
use fpc_pil::elf::Image;

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

/// The console block of `docs/bring-up.md` whose first command is `typed`.
fn guide_block(typed: &str) -> String {
    let guide = include_str!("../../docs/bring-up.md");
    let first = format!("$ {typed}\n");
    guide
        .split("```console\n")
        .skip(1)
        .filter_map(|b| b.split("```").next())
        .find(|b| b.starts_with(&first))
        .unwrap_or_else(|| panic!("bring-up.md has no console block starting with {first:?}"))
        .to_string()
}

/// The session as the guide shows it: each command typed, then what the host printed.
fn session(exchanges: &[(&str, &[String])]) -> String {
    let mut text = String::new();
    for (typed, lines) in exchanges {
        text.push_str(&format!("$ {typed}\n"));
        for line in *lines {
            text.push_str(line);
            text.push('\n');
        }
    }
    text
}

/// The number after `key` in `line`.
fn number_after(line: &str, key: &str) -> u32 {
    let rest = line
        .split_once(key)
        .unwrap_or_else(|| panic!("{key:?} not in {line:?}"))
        .1;
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits
        .parse()
        .unwrap_or_else(|_| panic!("no number after {key:?} in {line:?}"))
}

#[test]
fn a_fixed_duty_switches_every_pair_on_the_bench_supply_at_its_compare_value_until_stop() {
    let mut b = Bench::boot(&bench_image()).unwrap_or_else(|e| panic!("{e}"));
    let before = b.driven();
    assert_eq!(
        before.switching,
        PerSection::default(),
        "off before: {before:?}"
    );
    let status = b.session().status;
    assert!(
        status.absent.iter().any(|p| p == Part::Supply),
        "{status:?}"
    );
    assert!(status.faults.is_empty(), "{status:?}");

    let op = BenchOp::FixedDuty {
        section: Section::Master,
        phase: 1,
        duty: 0.3,
    };
    let lines = b
        .send(Some(op), 10.0)
        .unwrap()
        .unwrap_or_else(|e| panic!("{e}"));
    b.run_for(0.02).unwrap();
    let d = b.driven();
    println!("{d:?}");
    let both = PerSection {
        master: true,
        slave: true,
    };
    assert_eq!(d.switching, both, "every pair switching");
    assert_eq!(d.compare.master, [2125, 1275, 2125]);
    assert_eq!(d.compare.slave, [2125; 3]);
    // What the printout says is what the chip drives.
    let printed = number_after(&lines[1], "TIM1 CCR2 = ");
    assert_eq!(printed, d.compare.master[1], "{}", lines[1]);
    assert_eq!(number_after(&lines[2], "CCR = "), d.compare.slave[0]);
    let of = |c| Duty::of_compare(c, u32::from(PWM_COMPARE_STEPS));
    assert_eq!(d.duties.master, [of(2125), of(1275), of(2125)], "in force");
    let status = b.session().status;
    assert_eq!(status.mode, ModeKind::Bench);
    assert!(status.faults.is_empty(), "no fault: {:?}", status.faults);
    assert!(
        status.absent.iter().any(|p| p == Part::Supply),
        "the supply stays absent, not lost: {status:?}"
    );

    let stopped = b.send(None, 0.0).unwrap().unwrap_or_else(|e| panic!("{e}"));
    b.run_for(0.002).unwrap();
    let after = b.driven();
    assert_eq!(after.switching, PerSection::default(), "off after stop");
    assert_eq!(b.session().status.mode, ModeKind::Idle);
    let deadline = b.deadline();
    println!("{deadline}");
    assert_eq!(deadline.missed_updates, 0, "{deadline:?}");

    let printed = session(&[
        (
            "fpc-sim link send bench fixed-duty --section master --phase v --duty 0.3 --seconds 10",
            &lines,
        ),
        ("fpc-sim link send stop", &stopped),
    ]);
    print!("{printed}");
    assert_eq!(
        printed,
        guide_block(
            "fpc-sim link send bench fixed-duty --section master --phase v --duty 0.3 --seconds 10"
        )
    );
}

#[test]
fn a_servo_torque_drives_the_dac_and_turns_the_shaft_forward_until_stop() {
    let mut b = Bench::boot(&bench_image()).unwrap_or_else(|e| panic!("{e}"));
    let q0 = b.driven().quadrature;
    let op = BenchOp::ServoTorque { torque_nm: 3.0 };
    let lines = b
        .send(Some(op), 5.0)
        .unwrap()
        .unwrap_or_else(|e| panic!("{e}"));
    b.run_for(0.02).unwrap();
    let d = b.driven();
    println!("{d:?}");
    assert_eq!(d.dac, DacCode(2355));
    assert_eq!(
        u32::from(d.dac.0),
        number_after(&lines[1], "DAC1 channel 1 = ")
    );
    assert_eq!(
        d.switching,
        PerSection::default(),
        "the motor's outputs off"
    );
    let turning = d.quadrature.wrapping_sub(q0) as i16;
    assert!(turning > 0, "TIM4 counted {turning} in 20 ms");
    assert_eq!(b.session().status.mode, ModeKind::Bench);
    // It ends by itself once the shaft has turned a quarter turn, then coasts to rest.
    b.run_for(0.3).unwrap();
    let rest = b.driven();
    let turned = rest.quadrature.wrapping_sub(q0) as i16;
    println!("turned {turned} counts; {:?}", b.session().status);
    assert_eq!(rest.dac, DacCode::MID, "zero torque after a quarter turn");
    assert_eq!(b.session().status.mode, ModeKind::Idle);
    assert!(
        (1024..2048).contains(&turned),
        "{turned} counts: a quarter turn and the coast"
    );

    // Stop ends it sooner.
    let again = b
        .send(Some(op), 5.0)
        .unwrap()
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(again, lines);
    b.run_for(0.005).unwrap();
    assert_eq!(b.driven().dac, DacCode(2355));
    let stopped = b.send(None, 0.0).unwrap().unwrap_or_else(|e| panic!("{e}"));
    b.run_for(0.002).unwrap();
    assert_eq!(b.driven().dac, DacCode::MID, "zero torque after stop");
    assert_eq!(b.session().status.mode, ModeKind::Idle);
    assert_eq!(b.deadline().missed_updates, 0, "{:?}", b.deadline());

    let printed = session(&[
        (
            "fpc-sim link send bench servo-torque --torque 3 --seconds 5",
            &lines,
        ),
        ("fpc-sim link send stop", &stopped),
    ]);
    print!("{printed}");
    assert_eq!(
        printed,
        guide_block("fpc-sim link send bench servo-torque --torque 3 --seconds 5")
    );
}

#[test]
fn the_release_firmware_has_no_bench_operations_and_names_the_bench_build() {
    let mut b = Bench::boot(&release_image()).unwrap_or_else(|e| panic!("{e}"));
    let op = BenchOp::ServoTorque { torque_nm: 3.0 };
    let error = b
        .send(Some(op), 5.0)
        .unwrap()
        .expect_err("the release ELF has none");
    println!("{error}");
    assert!(error.contains("flash the bench build"), "{error}");
    b.run_for(0.01).unwrap();
    assert_eq!(b.driven().dac, DacCode::MID);
}
