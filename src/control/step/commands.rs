//! Host commands: what each may change, and when. A command is checked against a read-only
//! view of the machine ([`MachineView`]) into the [`Change`] it makes, or refused; the step
//! applies an accepted change (`ControlStep::command`), so a refused command changes nothing.

use super::modes::Mode;
use super::safe_state::FaultedBrake;
use super::sense::Sensing;
use crate::control::calibration::record::CalibrationStatus;
use crate::control::calibration::{Calibration, Routine, SenseMonitor};
#[cfg(feature = "bench")]
use crate::control::command::{BenchOp, BENCH_DUTY_RANGE, BENCH_MAX_SECONDS, BENCH_SERVO_FRACTION};
use crate::control::command::{Command, Parameter, Refusal};
use crate::control::config::ControlConfig;
use crate::motion::stroke::StrokeGenerator;
use crate::motion::synchroniser::Rotation;
use crate::motion::trajectory::PointToPoint;
use crate::motion::volume_ratio::RatioTarget;
use crate::safety::absent::{Absent, Part};
use crate::safety::faults::FaultSet;
use crate::sensing::homing::Homing;

/// What a command may look at.
pub(super) struct MachineView<'a> {
    pub config: &'a ControlConfig,
    pub mode: &'a Mode,
    pub faults: &'a FaultSet,
    /// The zero is known.
    pub homed: bool,
    /// The master position in its encoder's raw frame as last measured, m.
    pub raw_position_m: f32,
    /// The position as last measured, m.
    pub position_m: f32,
    /// Whether the machine may `Start` on its calibration.
    pub calibration: CalibrationStatus,
    /// The phase currents with the outputs off.
    pub sense_monitor: &'a SenseMonitor,
    /// The sense stage (what the encoders and the pressure sensors say of their faults).
    pub sensing: &'a Sensing,
    /// The power-good input as last read.
    pub supply_good: bool,
    /// The parts absent since boot (empty once the outputs were enabled).
    pub absent: Absent,
    /// What the faulted state does with the outputs.
    pub brake: FaultedBrake,
    /// The strokes' dead-point correction gain in use.
    pub dead_point_gain: f32,
}

/// What an accepted command changes.
#[derive(Clone, Debug)]
pub(super) enum Change {
    /// Nothing (the command asks for what already is).
    Nothing,
    /// The host watchdog restarted (the first heartbeat arms it).
    Heartbeat,
    /// A new mode: a move, a calibration routine.
    Mode(Mode),
    /// Homing starts; the zero is forgotten.
    Home(Homing),
    /// Strokes start with this generator: the rotation's first half cycle, the pressure
    /// plausibility watch afresh.
    Start(StrokeGenerator),
    /// The running strokes' peak speed, m/s.
    Speed(f32),
    /// A tunable parameter's new value.
    Parameter(Parameter, f32),
    /// Compressor or expander from the next half cycle.
    Rotation(Rotation),
    /// How the volume ratio is chosen.
    VolumeRatio(RatioTarget),
    /// The running strokes end at their next dead point; any other motion stops and holds.
    Stop,
    /// The latched faults cleared, every section back in service; the machine idle.
    ClearFaults,
}

/// Checks `command` against the machine: the change it makes, or why it is refused.
pub(super) fn check(command: Command, m: &MachineView) -> Result<Change, Refusal> {
    match command {
        Command::Heartbeat => Ok(Change::Heartbeat),
        Command::Home => {
            present(m)?;
            if !m.faults.is_empty() {
                return Err(Refusal::FaultActive);
            }
            current_sense(m)?;
            if !matches!(m.mode, Mode::Idle | Mode::Holding(_)) {
                return Err(Refusal::Busy);
            }
            Ok(Change::Home(Homing::new(m.config.homing, m.raw_position_m)))
        }
        Command::MoveTo {
            position_m,
            peak_speed_mps,
        } => move_to(m, position_m, peak_speed_mps),
        Command::Start { peak_speed_mps } => start(m, peak_speed_mps),
        Command::SetSpeed { peak_speed_mps } => {
            speed(m.config, peak_speed_mps)?;
            match m.mode {
                Mode::Running(_) => Ok(Change::Speed(peak_speed_mps)),
                _ => Err(Refusal::Busy),
            }
        }
        Command::SetParameter { parameter, value } => {
            if !value.is_finite() {
                return Err(Refusal::NotFinite);
            }
            let (lo, hi) = parameter.range();
            if !(lo..=hi).contains(&value) {
                return Err(Refusal::OutOfRange);
            }
            // Not while compressing: a gain change mid-stroke is not a tested transition.
            if matches!(m.mode, Mode::Running(_)) {
                return Err(Refusal::Busy);
            }
            Ok(Change::Parameter(parameter, value))
        }
        Command::SetRotation { rotation } => Ok(Change::Rotation(rotation)),
        Command::SetVolumeRatio { target } => {
            if let RatioTarget::Fixed { pressure_ratio } = target {
                if !pressure_ratio.is_finite() {
                    return Err(Refusal::NotFinite);
                }
                if !(1.0..=10.0).contains(&pressure_ratio) {
                    return Err(Refusal::OutOfRange);
                }
            }
            Ok(Change::VolumeRatio(target))
        }
        Command::Stop => Ok(Change::Stop),
        Command::Calibrate { routine } => calibrate(m, routine),
        Command::ClearFaults => clear_faults(m),
        // Checked and started out of line, before this (`ControlStep::bench_command`).
        #[cfg(feature = "bench")]
        Command::Bench { op, seconds } => check_bench(m, op, seconds).map(|_| Change::Nothing),
    }
}

fn move_to(m: &MachineView, position_m: f32, peak_speed_mps: f32) -> Result<Change, Refusal> {
    if !(position_m.is_finite() && peak_speed_mps.is_finite()) {
        return Err(Refusal::NotFinite);
    }
    let c = m.config;
    let lo = c.target_clearance_m;
    let hi = c.travel_m - c.target_clearance_m;
    let speed_ok = peak_speed_mps > 0.0 && peak_speed_mps <= c.max_speed_mps;
    if !((lo..=hi).contains(&position_m) && speed_ok) {
        return Err(Refusal::OutOfRange);
    }
    present(m)?;
    if !m.faults.is_empty() {
        return Err(Refusal::FaultActive);
    }
    if !m.homed {
        return Err(Refusal::NotHomed);
    }
    let from = match m.mode {
        Mode::Holding(sp) => sp.position_m,
        _ => return Err(Refusal::Busy),
    };
    Ok(Change::Mode(Mode::Moving {
        path: PointToPoint::new(from, position_m, peak_speed_mps),
        elapsed_s: 0.0,
    }))
}

fn start(m: &MachineView, peak_speed_mps: f32) -> Result<Change, Refusal> {
    speed(m.config, peak_speed_mps)?;
    present(m)?;
    if !m.faults.is_empty() {
        return Err(Refusal::FaultActive);
    }
    // Before the homing check: homing does not help a machine with no calibration.
    if m.calibration != CalibrationStatus::Calibrated {
        return Err(Refusal::NotCalibrated);
    }
    if !m.homed {
        return Err(Refusal::NotHomed);
    }
    let Mode::Holding(sp) = m.mode else {
        return Err(Refusal::Busy);
    };
    let mut stroke = m.config.stroke;
    stroke.correction_gain = m.dead_point_gain;
    stroke.peak_speed_mps = peak_speed_mps;
    Ok(Change::Start(StrokeGenerator::new(stroke, sp.position_m)))
}

fn calibrate(m: &MachineView, routine: Routine) -> Result<Change, Refusal> {
    if !routine.in_this_build() {
        return Err(Refusal::BenchBuildOnly);
    }
    present(m)?;
    if !m.faults.is_empty() {
        return Err(Refusal::FaultActive);
    }
    if routine != Routine::CurrentSense {
        current_sense(m)?;
    }
    if routine.needs_homing() && !m.homed {
        return Err(Refusal::NotHomed);
    }
    let from = match m.mode {
        Mode::Holding(sp) => sp.position_m,
        Mode::Idle => m.position_m,
        _ => return Err(Refusal::Busy),
    };
    let calibration = Calibration::new(routine, m.config, m.homed.then_some(from))
        .map_err(|_| Refusal::OutOfRange)?;
    Ok(Change::Mode(Mode::Calibrating(calibration)))
}

fn clear_faults(m: &MachineView) -> Result<Change, Refusal> {
    if m.faults.is_empty() {
        // Nothing latched: a part absent since boot is what keeps the machine waiting.
        present(m)?;
        return Ok(Change::Nothing);
    }
    // A controlled stop ends on its own (outputs off once holding the piston needs no
    // force): switching off earlier could let the gas throw the piston. Except the hold
    // after a watchdog reset (not homed), which does not end by itself.
    if let Mode::Stopping { setpoint, .. } = m.mode {
        let holding_after_reset = !m.homed
            && setpoint.velocity_mps == 0.0
            && !matches!(m.brake, FaultedBrake::Zeroing(_));
        if !holding_after_reset {
            return Err(Refusal::Busy);
        }
    }
    if m.sensing.cause_present() || !m.supply_good {
        return Err(Refusal::CausePersists);
    }
    Ok(Change::ClearFaults)
}

/// Refuses what would enable the outputs while a part is absent since boot, naming the first.
fn present(m: &MachineView) -> Result<(), Refusal> {
    match m.absent.first() {
        Some(Part::Supply) => Err(Refusal::SupplyAbsent),
        Some(Part::Encoders) => Err(Refusal::EncodersAbsent),
        Some(Part::Pressures) => Err(Refusal::PressuresAbsent),
        None => Ok(()),
    }
}

/// Refuses to switch the outputs on while the phase currents read a current with the
/// outputs off: the current loops would drive that offset into the motor.
fn current_sense(m: &MachineView) -> Result<(), Refusal> {
    if m.sense_monitor.offset_detected(m.config) {
        Err(Refusal::CurrentSenseOffset)
    } else {
        Ok(())
    }
}

/// Refuses a peak speed that is not finite or outside (0, max].
fn speed(c: &ControlConfig, peak_speed_mps: f32) -> Result<(), Refusal> {
    if !peak_speed_mps.is_finite() {
        return Err(Refusal::NotFinite);
    }
    if !(peak_speed_mps > 0.0 && peak_speed_mps <= c.max_speed_mps) {
        return Err(Refusal::OutOfRange);
    }
    Ok(())
}

/// Checks a bench command (the bench build's) against the machine: the operation to run and
/// its cycles, or why not. Refused with a value out of its range (a phase beyond w among
/// them), a fault latched, the machine not idle; a fixed duty also with the DC link up, and
/// once homed closer to a head than half an electrical period (how far a phase's DC current
/// may pull the mover) plus the routines' margins.
#[cfg(feature = "bench")]
pub(super) fn check_bench(
    m: &MachineView,
    op: BenchOp,
    seconds: f32,
) -> Result<(BenchOp, u32), Refusal> {
    let c = m.config;
    let (value, in_range) = match op {
        BenchOp::FixedDuty { phase, duty, .. } => (
            duty,
            phase < 3 && (BENCH_DUTY_RANGE.0..=BENCH_DUTY_RANGE.1).contains(&duty),
        ),
        BenchOp::ServoTorque { torque_nm } => (
            torque_nm,
            torque_nm.abs() <= BENCH_SERVO_FRACTION * c.servo.torque_full_scale_nm,
        ),
    };
    if !(value.is_finite() && seconds.is_finite()) {
        return Err(Refusal::NotFinite);
    }
    if !(in_range && seconds > 0.0 && seconds <= BENCH_MAX_SECONDS) {
        return Err(Refusal::OutOfRange);
    }
    if !m.faults.is_empty() {
        return Err(Refusal::FaultActive);
    }
    if !matches!(m.mode, Mode::Idle) {
        return Err(Refusal::Busy);
    }
    if let BenchOp::FixedDuty { .. } = op {
        if m.supply_good {
            return Err(Refusal::SupplyUp);
        }
        let near =
            c.target_clearance_m + c.calibration.sweep_margin_m + 0.5 * c.motor.electrical_period_m;
        if m.homed && !(near..=c.travel_m - near).contains(&m.position_m) {
            return Err(Refusal::OutOfRange);
        }
    }
    Ok((op, (seconds / c.sample_time_s) as u32))
}
