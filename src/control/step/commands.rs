//! Host commands: what each may change, and when. A refused command changes nothing.

use super::actuate::START_TURN_TIME_S;
use super::modes::{AfterStop, Mode};
use super::safe_state::FaultedBrake;
use super::ControlStep;
use crate::control::calibration::record::CalibrationStatus;
use crate::control::calibration::{Calibration, Routine};
use crate::control::command::{Command, Parameter, Refusal};
use crate::motion::stroke::StrokeGenerator;
use crate::motion::trajectory::PointToPoint;
use crate::motion::volume_ratio::RatioTarget;
use crate::safety::faults::Fault;
use crate::sensing::homing::Homing;
use core::f32::consts::FRAC_PI_2;

impl ControlStep {
    /// Handles a host command. A refused command changes nothing.
    pub fn command(&mut self, command: Command) -> Result<(), Refusal> {
        match command {
            Command::Heartbeat => {
                // The first heartbeat arms the host watchdog; every one restarts it.
                self.supervision.heartbeat_s = Some(0.0);
                Ok(())
            }
            Command::Home => {
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                self.check_current_sense()?;
                if !matches!(self.mode, Mode::Idle | Mode::Holding(_)) {
                    return Err(Refusal::Busy);
                }
                self.mode = Mode::Homing(Homing::new(self.config.homing, self.raw_position_m()));
                self.sensing.zero_raw_m = None;
                Ok(())
            }
            Command::MoveTo {
                position_m,
                peak_speed_mps,
            } => {
                if !(position_m.is_finite() && peak_speed_mps.is_finite()) {
                    return Err(Refusal::NotFinite);
                }
                let lo = self.config.target_clearance_m;
                let hi = self.config.travel_m - self.config.target_clearance_m;
                let speed_ok = peak_speed_mps > 0.0 && peak_speed_mps <= self.config.max_speed_mps;
                if !((lo..=hi).contains(&position_m) && speed_ok) {
                    return Err(Refusal::OutOfRange);
                }
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                if self.sensing.zero_raw_m.is_none() {
                    return Err(Refusal::NotHomed);
                }
                let from = match &self.mode {
                    Mode::Holding(sp) => sp.position_m,
                    _ => return Err(Refusal::Busy),
                };
                self.mode = Mode::Moving {
                    path: PointToPoint::new(from, position_m, peak_speed_mps),
                    elapsed_s: 0.0,
                };
                Ok(())
            }
            Command::Start { peak_speed_mps } => {
                self.check_speed(peak_speed_mps)?;
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                // Before the homing check: homing does not help a machine with no calibration.
                if self.calibration.status != CalibrationStatus::Calibrated {
                    return Err(Refusal::NotCalibrated);
                }
                if self.sensing.zero_raw_m.is_none() {
                    return Err(Refusal::NotHomed);
                }
                let Mode::Holding(sp) = &self.mode else {
                    return Err(Refusal::Busy);
                };
                let mut stroke = self.config.stroke;
                stroke.peak_speed_mps = peak_speed_mps;
                let mut generator = StrokeGenerator::new(stroke, sp.position_m);
                // The first stroke's rotation starts from the phase of the dead point the
                // piston rests at. A rotation nearer the other dead point's phase (a piston
                // moved across the stroke with the rotation still, as homing does) first
                // turns there, the piston held.
                if self.rotary.start_turn_rad(generator.direction()).abs() > FRAC_PI_2 {
                    generator.wait(START_TURN_TIME_S);
                } else {
                    self.begin_half(&generator);
                }
                self.mode = Mode::Running(generator);
                // The plausibility of the chamber pressures is judged over running strokes.
                self.sensing.pressures.restart_stroke_watch();
                Ok(())
            }
            Command::SetSpeed { peak_speed_mps } => {
                self.check_speed(peak_speed_mps)?;
                match &mut self.mode {
                    Mode::Running(g) => {
                        g.set_peak_speed(peak_speed_mps);
                        Ok(())
                    }
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
                if matches!(self.mode, Mode::Running(_)) {
                    return Err(Refusal::Busy);
                }
                let c = &mut self.config;
                match parameter {
                    Parameter::PositionKp => c.position_kp_n_per_m = value,
                    Parameter::PositionKd => c.position_kd_ns_per_m = value,
                    Parameter::HeartbeatTimeout => c.heartbeat_timeout_s = value,
                    Parameter::ParkPosition => c.park_position_m = value,
                    Parameter::DeadPointGain => c.stroke.correction_gain = value,
                }
                Ok(())
            }
            Command::SetRotation { rotation } => {
                self.rotary.direction = rotation;
                Ok(())
            }
            Command::SetVolumeRatio { target } => {
                if let RatioTarget::Fixed { pressure_ratio } = target {
                    if !pressure_ratio.is_finite() {
                        return Err(Refusal::NotFinite);
                    }
                    if !(1.0..=10.0).contains(&pressure_ratio) {
                        return Err(Refusal::OutOfRange);
                    }
                }
                self.rotary.volume_ratio.set_target(target);
                Ok(())
            }
            Command::Stop => {
                match &mut self.mode {
                    Mode::Running(g) => g.request_stop(),
                    _ => self.begin_stop(AfterStop::Hold),
                }
                Ok(())
            }
            Command::Calibrate { routine } => {
                if !self.faults.is_empty() {
                    return Err(Refusal::FaultActive);
                }
                if routine != Routine::CurrentSense {
                    self.check_current_sense()?;
                }
                let homed = self.sensing.zero_raw_m.is_some();
                if routine.needs_homing() && !homed {
                    return Err(Refusal::NotHomed);
                }
                let from = match &self.mode {
                    Mode::Holding(sp) => sp.position_m,
                    Mode::Idle => self.status.position_m,
                    _ => return Err(Refusal::Busy),
                };
                let calibration = Calibration::new(routine, &self.config, homed.then_some(from))
                    .map_err(|_| Refusal::OutOfRange)?;
                self.mode = Mode::Calibrating(calibration);
                Ok(())
            }
            Command::ClearFaults => {
                if self.faults.is_empty() {
                    return Ok(());
                }
                // A controlled stop ends on its own (outputs off once holding the piston needs
                // no force): switching off earlier could let the gas throw the piston. Except
                // the hold after a watchdog reset (not homed), which does not end by itself.
                if let Mode::Stopping { setpoint, .. } = &self.mode {
                    let holding_after_reset = self.sensing.zero_raw_m.is_none()
                        && setpoint.velocity_mps == 0.0
                        && !matches!(self.safe.brake, FaultedBrake::Zeroing(_));
                    if !holding_after_reset {
                        return Err(Refusal::Busy);
                    }
                }
                if self.sensing.encoders.master.cause_present()
                    || self.sensing.encoders.slave.cause_present()
                    || self.sensing.pressures.bad_cycles > 0
                    || !self.supply_good
                {
                    return Err(Refusal::CausePersists);
                }
                self.sensing.encoders.master.clear_fault();
                self.sensing.encoders.slave.clear_fault();
                // An encoder fault loses the zero: homing is required again.
                if self.faults.contains(Fault::EncoderSignal) {
                    self.sensing.zero_raw_m = None;
                }
                self.config.allocation.capability = self.safe.nominal_capability;
                self.sensing.lost_encoder = None;
                if matches!(self.safe.brake, FaultedBrake::Blind(_)) {
                    self.safe.brake = FaultedBrake::None;
                }
                self.sensing.pressures.trusted = true;
                self.faults.clear();
                self.mode = Mode::Idle;
                Ok(())
            }
        }
    }

    /// Refuses to switch the outputs on while the phase currents read a current with the
    /// outputs off: the current loops would drive that offset into the motor.
    pub(super) fn check_current_sense(&self) -> Result<(), Refusal> {
        if self.calibration.sense_monitor.offset_detected(&self.config) {
            Err(Refusal::CurrentSenseOffset)
        } else {
            Ok(())
        }
    }

    /// Refuses a peak speed that is not finite or outside (0, max].
    pub(super) fn check_speed(&self, peak_speed_mps: f32) -> Result<(), Refusal> {
        if !peak_speed_mps.is_finite() {
            return Err(Refusal::NotFinite);
        }
        if !(peak_speed_mps > 0.0 && peak_speed_mps <= self.config.max_speed_mps) {
            return Err(Refusal::OutOfRange);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::calibration::store::LoadError;
    use crate::control::config::ControlConfig;
    use crate::motion::trajectory::Setpoint;
    use crate::safety::faults::ResetCause;

    #[test]
    fn the_hold_after_a_watchdog_reset_ends_on_clear_faults_not_the_braking_before_it() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        step.supply(true);
        step.boot(ResetCause::Watchdog);
        // Braking the measured velocity to zero: busy.
        step.mode = Mode::Stopping {
            setpoint: Setpoint {
                position_m: 0.01,
                velocity_mps: 0.2,
                acceleration_mps2: -625.0,
            },
            then: AfterStop::Off,
        };
        step.safe.brake = FaultedBrake::Zeroing(1);
        assert_eq!(step.command(Command::ClearFaults), Err(Refusal::Busy));
        // Held at rest, not homed: the hold does not end by itself, the clear ends it.
        step.safe.brake = FaultedBrake::None;
        step.mode = Mode::Stopping {
            setpoint: Setpoint::at_rest(0.01),
            then: AfterStop::Off,
        };
        assert_eq!(step.command(Command::ClearFaults), Ok(()));
        assert!(matches!(step.mode, Mode::Idle));
        assert!(step.faults.is_empty());
        // SS1's hold (homed) ends on its own force criterion: busy.
        step.sensing.zero_raw_m = Some(0.0);
        step.latch(Fault::Overspeed);
        step.mode = Mode::Stopping {
            setpoint: Setpoint::at_rest(0.01),
            then: AfterStop::Off,
        };
        assert_eq!(step.command(Command::ClearFaults), Err(Refusal::Busy));
    }

    #[test]
    fn without_a_stored_calibration_start_is_refused_but_home_and_calibrate_are_not() {
        for (loaded, status) in [
            (Err(LoadError::Missing), CalibrationStatus::Missing),
            (Err(LoadError::Flash), CalibrationStatus::Invalid),
        ] {
            let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
            step.load_calibration(loaded);
            assert_eq!(step.calibration_status(), status);
            assert_eq!(
                status.name(),
                ["calibration_missing", "calibration_invalid"][status as usize - 2]
            );
            assert_eq!(
                step.command(Command::Start {
                    peak_speed_mps: 2.0
                }),
                Err(Refusal::NotCalibrated)
            );
            assert_eq!(
                step.command(Command::Calibrate {
                    routine: Routine::CurrentSense
                }),
                Ok(())
            );
            let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
            step.load_calibration(loaded);
            assert_eq!(step.command(Command::Home), Ok(()));
            assert_eq!(step.take_calibration_to_save(), None);
        }
    }

    #[test]
    fn a_supply_loss_latches_once_and_is_cleared_only_once_the_supply_is_back() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        step.supply(true);
        assert!(step.faults.is_empty());
        step.supply(false);
        step.supply(false);
        assert!(step.faults.contains(Fault::SupplyLoss));
        assert_eq!(step.faults.iter().count(), 1);
        // Not homed: the brake's short circuit, the outputs' own (the faulted state).
        assert!(matches!(step.mode, Mode::Faulted));
        assert_eq!(
            step.command(Command::ClearFaults),
            Err(Refusal::CausePersists)
        );
        step.supply(true);
        assert_eq!(step.command(Command::ClearFaults), Ok(()));
        assert!(step.faults.is_empty());
    }

    #[test]
    fn set_parameter_validates_and_changes_only_what_it_names() {
        let mut step = ControlStep::new(ControlConfig::reference()).unwrap();
        let before = step.config().clone();
        for (parameter, value, refusal) in [
            (Parameter::PositionKp, f32::NAN, Refusal::NotFinite),
            (Parameter::PositionKp, f32::INFINITY, Refusal::NotFinite),
            (Parameter::PositionKp, 1.0e9, Refusal::OutOfRange),
            (Parameter::ParkPosition, -0.01, Refusal::OutOfRange),
            (Parameter::DeadPointGain, 1.5, Refusal::OutOfRange),
        ] {
            assert_eq!(
                step.command(Command::SetParameter { parameter, value }),
                Err(refusal)
            );
            assert_eq!(step.config(), &before, "a refused command changes nothing");
        }
        assert_eq!(
            step.command(Command::SetParameter {
                parameter: Parameter::HeartbeatTimeout,
                value: 1.5
            }),
            Ok(())
        );
        let mut expected = before;
        expected.heartbeat_timeout_s = 1.5;
        assert_eq!(step.config(), &expected);
    }
}
