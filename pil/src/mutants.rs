//! Mutation tests: deliberate mistakes in the firmware's configuration of the chip
//! (`src/board/mutation.rs`), each built as a test ELF (`scripts/fw-mutants.sh`), each of
//! which a check here must catch — a check that the release ELF passes, so what it catches
//! is the mistake and not the check.
//!
//! | check | what it runs | what it demands |
//! |---|---|---|
//! | [`Check::Boot`] | power-on, 60 ms | no boot check failed, no board-level violation (gates floating or held on, dead time), no break, no lock-up, both ADCs' regular codes in RAM |
//! | [`Check::TripAtRest`] | the boot, then a phase current of 120 A with the outputs off | TIM1's break input trips within a PWM period |
//! | [`Check::HangAtRest`] | the boot, the first feed, then the control task hung | the watchdog resets within 5 ms of the hang |
//! | [`Check::TornSave`] | [`crate::faults::Scenario::TornSaveStaleFlag`] | the previous record loads |
//! | [`Check::FactoryBrownOut`] | [`crate::faults::Scenario::FactoryBrownOut`] | the boot refuses to run |
//! | [`Check::Deadline`] | the boot, then 0.1 s of homing (the bridges switching) | every sample's duties in the compare registers before their update event ([`crate::chip::deadline`]); no global critical section entered at the control priorities (the firmware's `CONTROL_LEVEL_ENTRIES`) |

use std::path::Path;

use fpc::control::command::Command;

use crate::board::CurrentStep;
use crate::chip::{DeadlineFigures, ResetKind};
use crate::elf::Image;
use crate::faults::{self, Scenario};
use crate::session::Session;

/// A check a mutant must fail and the release ELF pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Check {
    /// The boot, at rest.
    Boot,
    /// An over-current with the outputs off.
    TripAtRest,
    /// A hung control task at rest.
    HangAtRest,
    /// A torn save with a stale flash flag at the repair.
    TornSave,
    /// The option bytes as shipped.
    FactoryBrownOut,
    /// The duties against their update events while the bridges switch.
    Deadline,
}

/// Every mutation (`src/board/mutation.rs`'s `ALL`) and the check that must catch it.
pub const MUTATIONS: [(&str, Check); 14] = [
    ("ossi-clear", Check::Boot),
    ("ois-high", Check::Boot),
    ("bke-off", Check::TripAtRest),
    ("break-polarity-inverted", Check::Boot),
    ("dead-time-zero", Check::Boot),
    ("iwdg-key-order-swapped", Check::HangAtRest),
    ("rlr-before-rvu", Check::HangAtRest),
    ("jsqr-while-jadstart", Check::Boot),
    ("dma-psize-16", Check::Boot),
    ("flash-over-stale-flags", Check::TornSave),
    ("bor-zero-accepted", Check::FactoryBrownOut),
    ("stack-overflow", Check::Boot),
    ("late-duties", Check::Deadline),
    ("control-critical-section", Check::Deadline),
];

/// What the boot must not show: `Err` names what it showed.
fn boot_is_clean(s: &Session) -> Result<(), String> {
    let soc = s.chip.soc_ref();
    if let Some((_, l)) = s
        .log
        .lines
        .iter()
        .find(|(_, l)| l.contains("boot check failed"))
    {
        return Err(l.clone());
    }
    if let Some(t) = soc.lockups.first() {
        return Err(format!(
            "the core locked up at {t:.6} s (a stack overflow below SRAM?)"
        ));
    }
    if let Some(b) = soc.breaks.first() {
        return Err(format!(
            "TIM{}'s break input active at rest, with no current ({:.6} s)",
            [1, 8][b.timer],
            b.crossed_at_s
        ));
    }
    if !s
        .log
        .lines
        .iter()
        .any(|(_, l)| l.contains("running: control"))
    {
        return Err("the tasks never started".into());
    }
    regular_codes_in_ram(s)
}

/// The regular pairs the DMA wrote (CMAR, four words) carry ADC2's codes in their high
/// halves: its encoder cos channels and pressures never read 0 on the reference machine.
fn regular_codes_in_ram(s: &Session) -> Result<(), String> {
    let cmar = s.chip.soc_ref().dma_memory_address(0);
    let mut buf = [0u8; 16];
    s.chip.read_mem(cmar, &mut buf).map_err(|e| e.to_string())?;
    let words: Vec<u32> = buf
        .chunks(4)
        .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
        .collect();
    if words.iter().any(|w| w >> 16 == 0) {
        return Err(format!(
            "the regular burst in RAM at {cmar:#010x} lacks ADC2's codes (high halves): {words:08x?}"
        ));
    }
    Ok(())
}

/// Runs `check` on `image`: `Ok` if it passes, `Err` with what it saw otherwise.
pub fn run(image: &Image, check: Check) -> Result<(), String> {
    match check {
        Check::Boot => {
            let mut s = crate::run::at_rest(image)?;
            s.run_until(0.06).map_err(|e| format!("emulation: {e}"))?;
            boot_is_clean(&s)
        }
        Check::TripAtRest => {
            let mut s = crate::run::at_rest(image)?;
            s.run_until(0.06)?;
            let at = s.chip.time_s();
            s.chip.soc().board.current_step = Some(CurrentStep {
                section: 0,
                phase: 0,
                amps: 120.0,
            });
            s.run_until(at + 100e-6)?;
            match s.chip.soc_ref().breaks.iter().find(|b| b.timer == 0) {
                Some(b) if b.crossed_at_s >= at => Ok(()),
                Some(b) => Err(format!(
                    "TIM1's break came before the current ({:.6} s)",
                    b.crossed_at_s
                )),
                None => Err("no break on TIM1 from a 120 A phase current (trip at 85 A)".into()),
            }
        }
        Check::HangAtRest => {
            let mut s = crate::run::at_rest(image)?;
            s.run_until(0.1)?;
            let at = s.chip.time_s();
            s.chip.soc().hang_pending = true;
            s.run_until(at + 0.03)?;
            let reset = s
                .chip
                .soc_ref()
                .resets
                .iter()
                .find(|r| r.kind == ResetKind::Watchdog && r.at_s > at)
                .map(|r| r.at_s);
            match reset {
                Some(t) if t - at <= 5e-3 => Ok(()),
                Some(t) => Err(format!(
                    "the watchdog reset {:.1} ms after the control task hung (its window is 2 ms)",
                    (t - at) * 1e3
                )),
                None => Err("no watchdog reset within 30 ms of the control task hanging".into()),
            }
        }
        Check::TornSave => {
            let r = faults::run(image, Scenario::TornSaveStaleFlag)?;
            let ecc = r.lines("flash double ECC error");
            match ecc.first() {
                Some((_, l))
                    if l.contains("Zeroed") && r.lines("calibration_missing").is_empty() =>
                {
                    Ok(())
                }
                Some((_, l)) => Err(format!("the torn word was not repaired: {l}")),
                None => Err("the next boot never met the torn word".into()),
            }
        }
        Check::Deadline => {
            let mut s = crate::run::at_rest(image)?;
            s.run_until(0.02)?;
            s.chip.soc().recording = true;
            while !s.send(Command::Home) {
                s.step()?;
            }
            let t = s.chip.time_s() + 0.1;
            s.run_until(t)?;
            let d = DeadlineFigures::of(&s.chip.soc_ref().samples);
            let entries = crate::run::read_symbol_word(&s.chip, "CONTROL_LEVEL_ENTRIES");
            if entries != Some(0) {
                Err(format!(
                    "global critical sections entered at the control priorities: {entries:?}"
                ))
            } else if d.worst_cycle_cycles == 0 {
                Err("no compare written while homing".into())
            } else if d.missed_updates > 0 || d.worst_cycle_cycles > d.deadline_cycles {
                Err(format!(
                    "{} of {} samples' duties missed their update (last write {} cycles after \
                     the burst's end, deadline {})",
                    d.missed_updates, d.timed_samples, d.worst_cycle_cycles, d.deadline_cycles
                ))
            } else {
                Ok(())
            }
        }
        Check::FactoryBrownOut => {
            let r = faults::run(image, Scenario::FactoryBrownOut)?;
            if r.lines("boot check failed: BrownOutLevel").is_empty() {
                Err("the firmware ran with the brown-out reset at level 0 (≈ 1.7 V)".into())
            } else {
                Ok(())
            }
        }
    }
}

/// The mutants' verdicts: `release` must pass every check; each mutant ELF in `dir`
/// (`fpc-<name>`) must fail its own. Returns one line per mutation; `Err` if the release ELF
/// fails a check, or a mutant is missing or not caught.
pub fn verdicts(release: &Image, dir: &Path) -> Result<Vec<String>, String> {
    let mut lines = Vec::new();
    for check in [
        Check::Boot,
        Check::TripAtRest,
        Check::HangAtRest,
        Check::TornSave,
        Check::FactoryBrownOut,
        Check::Deadline,
    ] {
        run(release, check).map_err(|e| format!("the release ELF fails {check:?}: {e}"))?;
    }
    let mut missed = Vec::new();
    for (name, check) in MUTATIONS {
        let path = dir.join(format!("fpc-{name}"));
        let image = Image::read(&path)?;
        match run(&image, check) {
            Err(seen) => lines.push(format!("caught {name} ({check:?}): {seen}")),
            Ok(()) => {
                missed.push(name);
                lines.push(format!("NOT CAUGHT {name} ({check:?})"));
            }
        }
    }
    if missed.is_empty() {
        Ok(lines)
    } else {
        Err(format!(
            "{}\nnot caught: {}",
            lines.join("\n"),
            missed.join(", ")
        ))
    }
}
