//! The bring-up's bench operations over the link (`fpc-sim link send bench …`,
//! `docs/bring-up.md` §2 and §9.3): the command sent, and once the bench build accepts it,
//! what the board now drives — the timer's compare register or the DAC's code, the pins — and
//! what to measure there. The release firmware has no bench operations: it rejects the
//! command's tag, and the error says which build to flash.

use std::time::Duration;

use fpc::control::command::{BenchOp, Command};
use fpc::drive::servo::{ServoConfig, ServoController};
use fpc::link::frame::FrameError;
use fpc::units::{DacCode, Duty, Section, PWM_COMPARE_STEPS};

use super::session::{describe, outcome_text, send_command, Outcome};
use super::Channels;

/// The PWM period, µs (20 kHz, `src/board/pwm.rs`).
const PERIOD_US: f64 = 50.0;
/// The dead time at each edge of a pair, ns (`src/board/pwm.rs`: DTG 85 × 5.88 ns).
const DEAD_TIME_NS: f64 = 500.0;
/// The DAC's reference, V (VREF+ on the board).
const VREF_V: f64 = 3.3;
/// What the bridges are supplied with for step 2, V (`docs/bring-up.md` §2).
const BENCH_SUPPLY_V: f64 = 12.0;

/// The error when the firmware rejects the bench command's tag.
pub const RELEASE_BUILD: &str = "this firmware has no bench operations (the release build): \
     flash the bench build (cargo fw-bench)";

/// Sends the bench operation `op` for `seconds`; once accepted, the lines to print: the
/// acceptance, then what the board drives and what to measure. A refusal, or a firmware
/// without bench operations, is the error.
pub fn run<C: Channels + ?Sized>(
    channels: &mut C,
    op: BenchOp,
    seconds: f32,
    timeout: Duration,
    other: impl FnMut(String),
) -> Result<Vec<String>, String> {
    let command = Command::Bench { op, seconds };
    let outcome = send_command(channels, &command, timeout, other)?;
    match outcome {
        Outcome::Reply(r) if r.result.is_ok() => {}
        Outcome::Rejected(FrameError::UnknownKind) => {
            return Err(format!("{}: {RELEASE_BUILD}", describe(&command)))
        }
        _ => return Err(outcome_text(&outcome)),
    }
    let mut lines = vec![outcome_text(&outcome)];
    lines.extend(explain(op, seconds));
    Ok(lines)
}

/// What the board drives for `op` and what to measure, in lines.
pub fn explain(op: BenchOp, seconds: f32) -> Vec<String> {
    match op {
        BenchOp::FixedDuty {
            section,
            phase,
            duty,
        } => fixed_duty(section, phase, duty, seconds),
        BenchOp::ServoTorque { torque_nm } => servo_torque(torque_nm, seconds),
    }
}

/// A section's timer and its phases' pins (high side, low side), `docs/bring-up.md` §2.
fn pins(
    section: Section,
) -> (
    &'static str,
    [(&'static str, &'static str, &'static str); 3],
) {
    match section {
        Section::Master => (
            "TIM1",
            [
                ("U1", "PA8", "PA11"),
                ("V1", "PA9", "PB14"),
                ("W1", "PA10", "PB15"),
            ],
        ),
        Section::Slave => (
            "TIM8",
            [
                ("U2", "PC6", "PC10"),
                ("V2", "PC7", "PC11"),
                ("W2", "PC8", "PC12"),
            ],
        ),
    }
}

fn fixed_duty(section: Section, phase: u8, duty: f32, seconds: f32) -> Vec<String> {
    let arr = PWM_COMPARE_STEPS;
    let compare = Duty::from_fraction(duty).compare_value(arr);
    let half = Duty::HALF.compare_value(arr);
    let (timer, phases) = pins(section);
    let (other_timer, _) = pins(match section {
        Section::Master => Section::Slave,
        Section::Slave => Section::Master,
    });
    let (name, high, low) = phases.get(usize::from(phase)).copied().unwrap_or(phases[0]);
    let on_us = |c: u16| f64::from(c) / f64::from(arr) * PERIOD_US - DEAD_TIME_NS / 1000.0;
    let fraction = f64::from(compare) / f64::from(arr);
    let half_fraction = f64::from(half) / f64::from(arr);
    vec![
        format!(
            "{timer} CCR{} = {compare} of ARR {arr} ({:.1} %): {name} high ({high}) on {:.1} µs, \
             {name} low ({low}) on {:.1} µs, each {PERIOD_US:.1} µs period",
            phase + 1,
            100.0 * fraction,
            on_us(compare),
            on_us(arr - compare),
        ),
        format!(
            "{timer}'s other two phases and {other_timer}'s three: CCR = {half} ({:.1} %), \
             {:.1} µs on each side",
            100.0 * half_fraction,
            on_us(half),
        ),
        format!(
            "both timers: MOE set, CC1E..CC3E and CC1NE..CC3NE on; {DEAD_TIME_NS:.0} ns dead \
             time at each edge of every pair, never both sides high"
        ),
        format!(
            "{name} against the other phases: {:+.1} % of the bridge supply ({:+.2} V at \
             {BENCH_SUPPLY_V:.0} V); for {seconds} s, or until stop, a fault or power-good \
             rising, then the outputs off",
            100.0 * (fraction - half_fraction),
            BENCH_SUPPLY_V * (fraction - half_fraction),
        ),
    ]
}

fn servo_torque(torque_nm: f32, seconds: f32) -> Vec<String> {
    let config = ServoConfig::reference();
    let full_scale = config.torque_full_scale_nm;
    let DacCode(code) = ServoController::new(config).command(torque_nm);
    let DacCode(mid) = DacCode::MID;
    let volts = |c: u16| f64::from(c) / 4095.0 * VREF_V;
    let direction = if torque_nm >= 0.0 {
        "positive"
    } else {
        "negative"
    };
    let count = if torque_nm >= 0.0 {
        "increase"
    } else {
        "decrease"
    };
    vec![
        format!(
            "DAC1 channel 1 = {code} (mid-scale {mid} {:+}): {torque_nm:.2} N·m of the \
             {full_scale:.1} N·m full scale, PA4 at {:.2} V ({:.2} V is zero torque)",
            i32::from(code) - i32::from(mid),
            volts(code),
            volts(mid),
        ),
        format!(
            "the shaft turns in the machine's {direction} direction and TIM4's count \
             (probe-rs read b32 0x40000824 1) should {count}; the motor's outputs off"
        ),
        format!(
            "for {seconds} s, or until the shaft has turned a quarter turn ({} counts), stop \
             or a fault, then zero torque ({mid})",
            config.counts_per_rev / 4
        ),
    ]
}
