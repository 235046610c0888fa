//! A calibration routine's cycle, after the rest of the step: what the routine measures, the
//! bookkeeping of what the routines found (and whether the machine may start on it), and
//! the frames of both sections' current loops for what the routine asks (off, forced
//! current vectors, position control along its sweep).

use super::publish::Previous;
use crate::control::calibration::record::{CalibrationRecord, CalibrationStatus};
#[cfg(feature = "bench")]
use crate::control::calibration::report::RoutineReport;
use crate::control::calibration::{
    Calibrated, CalibrationError, Forced, Measurements, Outcome, Routine,
};
use crate::control::config::ControlConfig;
use crate::physics::motor::Dq;
use crate::ports::PhaseCurrentCodes;
use crate::units::{DacCode, PerSection};

use super::{ControlStep, CycleOutputs};

/// The calibration's bookkeeping: what the routines loaded, whether the machine may start on
/// it, whether a result waits to be saved.
#[derive(Clone, Debug)]
pub(super) struct CalibrationState {
    /// What the calibration routines have loaded.
    pub calibrated: Calibrated,
    /// Whether the machine may `Start` on its calibration.
    pub status: CalibrationStatus,
    /// A routine has finished since the record was last taken for saving.
    pub unsaved: bool,
    /// The last routine started since boot, and how it stands (the bench build's: the
    /// release firmware reports no routine, so its 20 kHz path carries none of this).
    #[cfg(feature = "bench")]
    pub report: Option<RoutineReport>,
    /// The report changed since it was last taken for the link.
    #[cfg(feature = "bench")]
    pub report_changed: bool,
}

impl CalibrationState {
    pub(super) fn new() -> Self {
        CalibrationState {
            calibrated: Calibrated::default(),
            // The configuration as given is trusted (the simulator hands it the machine's
            // true values); a firmware that stores its calibration says otherwise at boot
            // (`ControlStep::load_calibration`).
            status: CalibrationStatus::Calibrated,
            unsaved: false,
            #[cfg(feature = "bench")]
            report: None,
            #[cfg(feature = "bench")]
            report_changed: false,
        }
    }

    /// A routine was accepted: reported running. Out of line (in flash): it runs once a
    /// routine, and the command handling it would be inlined into is in CCM SRAM.
    #[cfg(feature = "bench")]
    #[inline(never)]
    pub(super) fn start(&mut self, routine: Routine, config: &ControlConfig) {
        self.report = Some(RoutineReport::start(routine, config));
        self.report_changed = true;
    }

    /// A routine ended with `result`: reported. Out of line, as [`CalibrationState::start`].
    #[cfg(feature = "bench")]
    #[inline(never)]
    fn report_end(
        &mut self,
        routine: Routine,
        result: &Result<Outcome, CalibrationError>,
        config: &ControlConfig,
    ) {
        self.report = Some(RoutineReport::end(routine, result, config));
        self.report_changed = true;
    }

    /// The report, once after each change.
    #[cfg(feature = "bench")]
    pub(super) fn take_report(&mut self) -> Option<RoutineReport> {
        if !self.report_changed {
            return None;
        }
        self.report_changed = false;
        self.report
    }

    /// A routine ended with `result`, its outcome already loaded into `config` when it
    /// succeeded: the result recorded, a record to save, and — unless the machine was
    /// calibrated already — whether it now is.
    pub(super) fn finish(
        &mut self,
        routine: Routine,
        result: Result<Outcome, CalibrationError>,
        config: &ControlConfig,
    ) {
        // The commissioning loads nothing: no record to save.
        if result.is_ok() && routine != Routine::Commission {
            self.unsaved = true;
        }
        #[cfg(feature = "bench")]
        self.report_end(routine, &result, config);
        self.calibrated.record(routine, result);
        if self.status != CalibrationStatus::Calibrated {
            self.status = if CalibrationRecord::of(&self.calibrated, config).is_complete() {
                CalibrationStatus::Calibrated
            } else {
                CalibrationStatus::Incomplete
            };
        }
    }

    /// The record to save, once after each routine that succeeded.
    pub(super) fn take_to_save(&mut self, config: &ControlConfig) -> Option<CalibrationRecord> {
        if !self.unsaved {
            return None;
        }
        self.unsaved = false;
        Some(CalibrationRecord::of(&self.calibrated, config))
    }
}

/// What a routine measures in this cycle: `now` is the cycle just published (its position,
/// velocity), `forces` each section's force from its q-current, N; the encoders' electrical
/// angles from the raw positions (`zero_raw_m`, `zero_slave_raw_m`: the frames' zeros, m;
/// 20-bit resolution within the period, 23 nm: far finer than any calibration needs), the gas
/// force from the last valid chamber pressures (`last_pa`).
#[allow(clippy::too_many_arguments)]
pub(super) fn measurements<'a>(
    c: &ControlConfig,
    now: &Previous,
    forces: PerSection<f32>,
    zero_raw_m: f32,
    zero_slave_raw_m: f32,
    last_pa: &[f32; 4],
    currents: &'a PerSection<PhaseCurrentCodes>,
) -> Measurements<'a> {
    let raw_m = now.position_m + zero_raw_m;
    let slave_raw_m = now.slave_position_m + zero_slave_raw_m;
    let angle_of = |x_m: f32, period_m: f32| crate::angle::turns(x_m / period_m);
    let [pa, pb, _, _] = *last_pa;
    let gas_force_n = if pa.is_finite() && pb.is_finite() {
        c.cylinder.gas_force_n(pa, pb)
    } else {
        0.0
    };
    Measurements {
        position_m: now.position_m,
        slave_position_m: now.slave_position_m,
        velocity_mps: now.velocity_mps,
        angle: PerSection {
            master: angle_of(raw_m, c.encoder_master.period_m),
            slave: angle_of(slave_raw_m, c.encoder_slave.period_m),
        },
        currents,
        force_n: forces,
        gas_force_n,
    }
}

/// Each section's frame for a routine's forced vectors: the forced angle and current, or
/// zero current in the section's own frame (`own`: its encoder angle with its offset) where
/// none is forced.
pub(super) fn forced_frames(
    forced: PerSection<Option<Forced>>,
    own: PerSection<u32>,
) -> PerSection<(u32, Dq<f32>)> {
    let frame =
        |f: Option<Forced>, own: u32| f.map_or((own, Dq::default()), |f| (f.angle, f.current));
    PerSection {
        master: frame(forced.master, own.master),
        slave: frame(forced.slave, own.slave),
    }
}

/// Each section's frame while a routine tracks a setpoint: its own angle (`own`), the
/// q-current of its share of the force (`shares`, N; `inv_kf`, A/N), and for the slave the
/// routine's injected d-current (`slave_d_a`, A).
pub(super) fn tracking_frames(
    own: PerSection<u32>,
    shares: PerSection<f32>,
    inv_kf: f32,
    slave_d_a: f32,
) -> PerSection<(u32, Dq<f32>)> {
    PerSection {
        master: (
            own.master,
            Dq {
                d: 0.0,
                q: shares.master * inv_kf,
            },
        ),
        slave: (
            own.slave,
            Dq {
                d: slave_d_a,
                q: shares.slave * inv_kf,
            },
        ),
    }
}

impl ControlStep {
    /// The outputs of a cycle that calibrates (or, in the bench build, runs a bench
    /// operation): the routine's duties, after the rest of the step, and the servo's command
    /// (a bench operation's torque, else the rotate stage's `servo`).
    #[cold]
    #[inline(never)]
    pub(super) fn calibrating_outputs(
        &mut self,
        currents: &PerSection<PhaseCurrentCodes>,
        sections: PerSection<bool>,
        servo: DacCode,
    ) -> CycleOutputs {
        let pwm = self.calibration_cycle(currents);
        #[cfg(feature = "bench")]
        let servo = self.bench_servo(servo);
        CycleOutputs {
            pwm,
            sections,
            servo,
        }
    }
}
