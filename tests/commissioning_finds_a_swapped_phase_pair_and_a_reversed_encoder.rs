//! The commissioning routine (`calibrate commission`), run by the firmware's control step on
//! the simulated machine wired as a new or rewired machine may be (`hal_sim::board::wiring`:
//! a section's motor leads b and c swapped, an encoder's sin and cos swapped), finds the
//! wiring: all in order when it is, each single fault named, two faults that read alike
//! reported as ambiguous, the N–N pitch against the configured electrical period; it
//! refuses to start with the homed piston too close to a head or with a fault latched; and
//! `docs/bring-up.md` shows what the host prints.

mod support;

use fpc::control::calibration::commission::wiring;
use fpc::control::calibration::{Commissioning, Routine};
use fpc::control::command::{Command, Refusal};
use fpc::units::PerSection;
use hal_sim::board::wiring::Wiring;
use hal_sim::calibration::{check_wiring, commission_lines};
use hal_sim::plant::model::MachineModel;
use support::drive::*;

/// Seed of the sensors' noise.
const SEED: u64 = 41;

/// Commissions the reference machine wired as `w` with the piston at mid-travel; what it
/// found and the host's lines, printed.
fn commission(w: Wiring) -> (Commissioning, Vec<String>) {
    let model = MachineModel::reference();
    let start_m = 0.5 * model.piston.travel_m;
    let (found, stages) = check_wiring(&model, &w, SEED, start_m).expect("commissioning ran");
    let config = hal_sim::run::control_config(&model);
    let lines = commission_lines(&found, &config);
    println!(
        "{w:?}: {:.2} s simulated",
        stages.iter().map(|s| s.duration_s).sum::<f64>()
    );
    for line in &lines {
        println!("  {line}");
    }
    (found, lines)
}

fn one(master: bool, slave: bool) -> PerSection<bool> {
    PerSection { master, slave }
}

/// The pitch of both sections within 1 % of 24 mm: undamped, the mover comes to rest
/// anywhere within static friction's band (±F_s/k = ±0.14 mm at 20 A) at each end of the
/// turn.
fn assert_pitch(found: &Commissioning) {
    for p in [found.pitch_m.master, found.pitch_m.slave] {
        assert!((p / 0.024 - 1.0).abs() < 0.01, "pitch {p} m");
    }
    assert_eq!(found.pitch_ok, one(true, true));
}

#[test]
fn a_correctly_wired_machine_is_reported_in_order() {
    let (found, lines) = commission(Wiring::default());
    assert_eq!((found.reversed, found.ambiguous), (0, false));
    assert_pitch(&found);
    assert_eq!(
        lines[..4],
        [
            "phases in order in section master",
            "phases in order in section slave",
            "master encoder counts with the motion",
            "slave encoder counts with the motion",
        ]
    );
    assert!(
        lines[4].starts_with("N-N pitch in section master 2"),
        "{}",
        lines[4]
    );
    assert!(
        lines[4].ends_with("mm, expected 24.00 mm: ok"),
        "{}",
        lines[4]
    );
    assert!(
        lines[5].starts_with("N-N pitch in section slave 2"),
        "{}",
        lines[5]
    );
}

#[test]
fn each_single_wiring_fault_is_found_and_named() {
    let cases = [
        (
            Wiring {
                swapped_phases: one(true, false),
                ..Wiring::default()
            },
            wiring::MASTER_PHASES,
            "phases swapped in section master",
        ),
        (
            Wiring {
                swapped_phases: one(false, true),
                ..Wiring::default()
            },
            wiring::SLAVE_PHASES,
            "phases swapped in section slave",
        ),
        (
            Wiring {
                reversed_encoder: one(true, false),
                ..Wiring::default()
            },
            wiring::MASTER_ENCODER,
            "master encoder reversed",
        ),
        (
            Wiring {
                reversed_encoder: one(false, true),
                ..Wiring::default()
            },
            wiring::SLAVE_ENCODER,
            "slave encoder reversed",
        ),
    ];
    for (w, fault, named) in cases {
        let (found, lines) = commission(w);
        assert_eq!((found.reversed, found.ambiguous), (fault, false), "{w:?}");
        assert_pitch(&found);
        // Named once, and nothing else reported out of order.
        assert_eq!(lines.iter().filter(|l| *l == named).count(), 1, "{lines:?}");
        let faulty = lines
            .iter()
            .filter(|l| l.contains("swapped") || l.contains("reversed"))
            .count();
        assert_eq!(faulty, 1, "{lines:?}");
    }
}

#[test]
fn two_faults_that_read_alike_are_reported_as_ambiguous() {
    // The master's phases and the master encoder reversed read as the slave's phases and
    // the slave encoder reversed.
    let w = Wiring {
        swapped_phases: one(true, false),
        reversed_encoder: one(true, false),
    };
    let (found, lines) = commission(w);
    assert!(found.ambiguous);
    let pair = wiring::MASTER_PHASES | wiring::MASTER_ENCODER;
    assert!(found.reversed == pair || found.reversed == wiring::ALL ^ pair);
    assert_pitch(&found);
    assert!(lines[0].starts_with("ambiguous: "), "{lines:?}");
    assert!(
        lines[0].contains("phases swapped in section master and master encoder reversed"),
        "{}",
        lines[0]
    );
    assert!(
        lines[0].contains("phases swapped in section slave and slave encoder reversed"),
        "{}",
        lines[0]
    );
}

#[test]
fn a_pitch_unlike_the_configured_period_fails_the_check() {
    // The controller told a 25 mm period for the 24 mm magnets (4 % off, the tolerance 2 %).
    let model = MachineModel::reference();
    let mut config = uncalibrated_config(&model);
    config.motor.electrical_period_m = 0.025;
    let mut bench = Bench::new(&model, config, SEED, 0.1);
    calibrate(&mut bench, Routine::CurrentSense);
    let found = calibrate(&mut bench, Routine::Commission)
        .commission
        .expect("findings");
    let lines = commission_lines(&found, bench.step.config());
    println!("{lines:?}");
    assert_eq!(found.pitch_ok, one(false, false));
    assert!(
        lines[4].contains("expected 25.00 mm: off by more than 2 %"),
        "{}",
        lines[4]
    );
}

#[test]
fn a_homed_piston_too_close_to_a_head_is_refused() {
    // The reach is half a period, the approach and the turn (1.56 periods, 37.3 mm) either
    // way, plus the clearance and the sweep margin (11 mm): 48.3 mm from each head.
    let model = MachineModel::reference();
    let mut bench = Bench::new(&model, uncalibrated_config(&model), SEED, 0.1);
    bench.home();
    let at = |bench: &mut Bench, x: f32| {
        let to = Command::MoveTo {
            position_m: x,
            peak_speed_mps: 0.2,
        };
        bench.run_command(to, fpc::status::ModeKind::Holding, 10.0);
        bench.command(Command::Calibrate {
            routine: Routine::Commission,
        })
    };
    assert_eq!(at(&mut bench, 0.045), Err(Refusal::OutOfRange));
    assert_eq!(at(&mut bench, 0.160), Err(Refusal::OutOfRange));
    assert_eq!(at(&mut bench, 0.052), Ok(()));
}

/// The simulator's console blocks of `docs/bring-up.md`'s commissioning section: each command and what
/// it prints, in order.
fn documented_sessions() -> Vec<(String, String)> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/bring-up.md");
    let doc = std::fs::read_to_string(path).expect("docs/bring-up.md is readable");
    let start = doc
        .find("## 10. Commissioning")
        .expect("bring-up.md has the commissioning section");
    let section = &doc[start..];
    let end = section[3..].find("\n## ").map_or(section.len(), |e| e + 3);
    let mut sessions: Vec<(String, String)> = Vec::new();
    let mut inside = false;
    for line in section[..end].lines() {
        if line.starts_with("```") {
            inside = line == "```console";
            continue;
        }
        if !inside {
            continue;
        }
        match (line.strip_prefix("$ "), sessions.last_mut()) {
            (Some(command), _) => sessions.push((command.to_string(), String::new())),
            (None, Some((_, printed))) => {
                printed.push_str(line);
                printed.push('\n');
            }
            (None, None) => panic!("output before a command: {line}"),
        }
    }
    // The board's blocks (`fpc-sim link send …`) are the PIL's to check, on the release ELF
    // (`pil/tests/the_board_commissions_the_motor.rs`).
    sessions.retain(|(command, _)| command.starts_with("fpc-sim calibrate "));
    sessions
}

#[test]
fn the_bring_up_guide_shows_what_the_host_prints() {
    let sessions = documented_sessions();
    assert_eq!(sessions.len(), 4, "{sessions:?}");
    for (command, documented) in sessions {
        let argv: Vec<&str> = command.split_whitespace().collect();
        let (code, printed) = hal_sim::console::captured(|| hal_sim::cli::execute(argv));
        assert_eq!(code, 0, "{command}: {printed}");
        assert_eq!(
            printed, documented,
            "`{command}` prints otherwise than bring-up.md"
        );
    }
}

#[test]
fn a_latched_fault_refuses_the_commissioning_until_cleared() {
    use hal_sim::board::corruption::PressureHold;
    let model = MachineModel::reference();
    let mut bench = Bench::new(&model, uncalibrated_config(&model), SEED, 0.1);
    calibrate(&mut bench, Routine::CurrentSense);
    // Chamber A's transducer goes open circuit: `pressure_sensor` latches.
    bench.world_mut().corruption.chambers[0] = PressureHold::Code(0);
    assert!(bench.run_until(1.0, |_, s| !s.faults.is_empty()));
    let commission = Command::Calibrate {
        routine: Routine::Commission,
    };
    assert_eq!(bench.command(commission), Err(Refusal::FaultActive));
    bench.world_mut().corruption.chambers[0] = PressureHold::Live;
    bench.run_until(0.1, |_, _| false);
    assert_eq!(bench.command(Command::ClearFaults), Ok(()));
    bench.cycle();
    assert_eq!(bench.command(commission), Ok(()));
}

/// A host attached to the simulated board through the RTT channels in its RAM (as a probe
/// reaches the real one); the board runs while the host waits.
struct Attached<'s> {
    board: hal_sim::board::exec::LinkedBoard<'s>,
    block: hal_sim::link::rtt::ControlBlock,
}

impl hal_sim::link::Channels for Attached<'_> {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> std::io::Result<usize> {
        self.block
            .read_up(&mut self.board.world().ram, channel, buf)
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> std::io::Result<usize> {
        self.block
            .write_down(&mut self.board.world().ram, channel, bytes)
    }

    fn pause(&mut self, d: std::time::Duration) {
        for _ in 0..(d.as_secs_f64() * 20_000.0).round() as u64 {
            self.board.step();
        }
    }
}

/// `fpc-sim link send calibrate current-sense`, then `… commission`, on the simulated board
/// (all four firmware tasks) wired as `w`, the piston at mid-travel: the host's lines.
fn commission_over_the_link(w: Wiring) -> Vec<String> {
    use hal_sim::link::report::calibrate;
    use hal_sim::link::rtt::{ControlBlock, Locate};
    let model = MachineModel::reference();
    let mut world = hal_sim::run::world(&model, SEED, 0, 0.5 * model.piston.travel_m);
    world.set_wiring(w);
    let shared = hal_sim::board::exec::SimShared::new();
    let config = hal_sim::run::control_config(&model);
    let board = hal_sim::board::exec::LinkedBoard::boot(world, config, &shared, 0);
    let block = ControlBlock::find(
        &mut board.world().ram,
        &Locate::Scan(vec![hal_sim::board::ram::SimRam::range()]),
    )
    .expect("the control block is found in RAM");
    let mut host = Attached { board, block };
    let timeout = std::time::Duration::from_secs(5);
    let other = |l: String| panic!("unexpected answer {l}");
    let sense = calibrate(&mut host, Routine::CurrentSense, timeout, other).expect("current sense");
    assert_eq!(
        sense,
        ["accepted: calibrate current-sense", "current_sense done"]
    );
    calibrate(&mut host, Routine::Commission, timeout, other).expect("commissioning")
}

#[test]
fn the_board_sends_its_findings_and_the_host_prints_them_as_the_simulator_does() {
    for w in [
        Wiring::default(),
        Wiring {
            swapped_phases: one(false, true),
            ..Wiring::default()
        },
        Wiring {
            reversed_encoder: one(true, false),
            ..Wiring::default()
        },
    ] {
        let lines = commission_over_the_link(w);
        println!("{w:?}: {lines:#?}");
        let (_, simulated) = commission(w);
        assert_eq!(lines[0], "accepted: calibrate commission");
        // The findings word for word; the pitch to the figure's last digit (the board takes
        // the commands a few periods later than the simulator's step: the mover rests
        // elsewhere within static friction's band).
        assert_eq!(lines[1..5], simulated[..4], "{w:?}");
        for (board, sim) in lines[5..].iter().zip(&simulated[4..]) {
            let figure = |l: &str| {
                let mm: f32 = l.split(' ').nth(5).unwrap().parse().unwrap();
                (mm, l.split_once(" mm,").unwrap().1.to_string())
            };
            let (b, s) = (figure(board), figure(sim));
            assert!((b.0 - s.0).abs() <= 0.2, "{board} / {sim}");
            assert_eq!(b.1, s.1, "{board} / {sim}");
        }
        assert_eq!(lines.len(), 7, "{lines:?}");
    }
}
