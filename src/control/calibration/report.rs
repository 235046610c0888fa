//! What the last routine did, as the host reads it over the link: the routine, whether it is
//! running, ended or was left before it ended, and what it found or why it failed. The
//! parameters a routine loads are read with the calibration record; this carries what no
//! record holds (the commissioning's findings, a failure's cause).

use super::{CalibrationError, Commissioning, Outcome, Routine};
#[cfg(feature = "bench")]
use crate::control::config::ControlConfig;

/// How the last routine stands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RoutineState {
    /// Accepted and running (the machine's mode is `calibrating`). A routine that is no longer
    /// running in this state was left before it ended: a fault latched, or `Stop`.
    Running,
    /// Ended with its outcome loaded; the commissioning's findings with it.
    Succeeded(Option<Commissioning>),
    /// Ended without a result, and why (nothing was loaded).
    Failed(CalibrationError),
}

/// The last routine started since boot, and how it stands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoutineReport {
    /// The routine.
    pub routine: Routine,
    /// Running, or how it ended.
    pub state: RoutineState,
    /// The configured electrical period (the N–N pitch expected), m.
    pub expected_pitch_m: f32,
    /// The pitch's tolerance, fraction of the period.
    pub pitch_tolerance: f32,
}

impl RoutineReport {
    /// `routine` has just been accepted.
    pub fn started(routine: Routine, expected_pitch_m: f32, pitch_tolerance: f32) -> Self {
        RoutineReport {
            routine,
            state: RoutineState::Running,
            expected_pitch_m,
            pitch_tolerance,
        }
    }

    /// `routine` has just been accepted, on the machine configured as `config`. Out of line
    /// (in flash): it runs once a routine, and the step's calibration code is in CCM SRAM.
    #[inline(never)]
    #[cfg(feature = "bench")]
    pub fn start(routine: Routine, config: &ControlConfig) -> Self {
        let c = &config.calibration;
        let period = config.motor.electrical_period_m;
        RoutineReport::started(routine, period, c.commission_pitch_tolerance)
    }

    /// `routine` has just ended with `result` ([`RoutineReport::start`]'s, then
    /// [`RoutineReport::ended`]). Out of line, as `start`.
    #[inline(never)]
    #[cfg(feature = "bench")]
    pub fn end(
        routine: Routine,
        result: &Result<Outcome, CalibrationError>,
        config: &ControlConfig,
    ) -> Self {
        RoutineReport::start(routine, config).ended(result)
    }

    /// The routine ended with `result`.
    pub fn ended(self, result: &Result<Outcome, CalibrationError>) -> Self {
        let state = match result {
            Ok(Outcome::Commission(found)) => RoutineState::Succeeded(Some(*found)),
            Ok(_) => RoutineState::Succeeded(None),
            Err(e) => RoutineState::Failed(*e),
        };
        RoutineReport { state, ..self }
    }
}
