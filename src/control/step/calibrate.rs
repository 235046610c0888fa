//! A calibration routine's cycle, after the rest of the step: the routine says what the
//! outputs do (off, forced current vectors, position control along its sweep).

use super::modes::Mode;
use super::{ControlStep, CycleInputs};
use crate::control::calibration::record::{CalibrationRecord, CalibrationStatus};
use crate::control::calibration::{Calibrated, Demand, Measurements, Outcome, SenseMonitor};
use crate::drive::allocation::allocate;
use crate::motion::trajectory::Setpoint;
use crate::physics::motor::Dq;
use crate::sensing::differentiator::Derivatives;
use crate::units::{PerSection, PhaseDuties, Section};

/// The calibration's bookkeeping: what the routines loaded, whether the machine may start on
/// it, whether a result waits to be saved, and the current-sense monitor.
#[derive(Clone, Debug)]
pub(super) struct CalibrationState {
    /// What the calibration routines have loaded.
    pub calibrated: Calibrated,
    /// Whether the machine may `Start` on its calibration.
    pub status: CalibrationStatus,
    /// A routine has finished since the record was last taken for saving.
    pub unsaved: bool,
    /// The phase currents while the outputs are off (current-sense offset detection).
    pub sense_monitor: SenseMonitor,
}

impl CalibrationState {
    pub(super) fn new() -> Self {
        CalibrationState {
            calibrated: Calibrated::default(),
            // The configuration as given is trusted (the simulator hands it the machine's
            // true values); a firmware that stores its calibration says otherwise at boot
            // ([`ControlStep::load_calibration`]).
            status: CalibrationStatus::Calibrated,
            unsaved: false,
            sense_monitor: SenseMonitor::new(),
        }
    }
}

impl ControlStep {
    /// One cycle of a calibration routine, after the rest of the step (supervision, status):
    /// the routine says what to do with the outputs (off, forced current vectors, or
    /// position control along its sweep); when it is done its parameters are loaded and the
    /// machine holds (homed) or goes idle. It reads what it needs from the status this step
    /// has just written, so the normal step carries nothing for it; the rotation is not
    /// driven meanwhile.
    #[cold]
    #[inline(never)]
    pub(super) fn calibration_cycle(
        &mut self,
        inputs: &CycleInputs,
    ) -> Option<PerSection<PhaseDuties>> {
        let s = self.status;
        // The encoders' electrical angles from the raw positions (20-bit resolution within
        // the period, 23 nm: far finer than any calibration needs).
        let raw_m = s.position_m + self.sensing.zero_raw_m.unwrap_or(0.0);
        let slave_raw_m = s.slave_position_m + self.sensing.zero_slave_raw_m;
        let angle_of = |x_m: f32, period_m: f32| crate::angle::turns(x_m / period_m);
        let [pa, pb, _, _] = self.sensing.pressures.last_pa;
        let gas_force_n = if pa.is_finite() && pb.is_finite() {
            self.config.cylinder.gas_force_n(pa, pb)
        } else {
            0.0
        };
        let position_m = s.position_m;
        let Mode::Calibrating(calibration) = &mut self.mode else {
            return None;
        };
        let routine = calibration.routine();
        let measured = Measurements {
            position_m,
            slave_position_m: s.slave_position_m,
            velocity_mps: s.velocity_mps,
            angle: PerSection {
                master: angle_of(raw_m, self.config.encoder_master.period_m),
                slave: angle_of(slave_raw_m, self.config.encoder_slave.period_m),
            },
            currents: &inputs.currents,
            force_n: PerSection {
                master: s.force_master_n,
                slave: s.force_slave_n,
            },
            gas_force_n,
        };
        let mut demand = calibration.step(&self.config, &measured);
        if let Demand::Done(result) = demand {
            if let Ok(outcome) = &result {
                outcome.apply(&mut self.config);
                if let Outcome::EncoderMap(_) = outcome {
                    // The slave's gate passes the map's step from the next cycle on.
                    let slave =
                        crate::control::calibration::encoder_map::slave_encoder(&self.config);
                    self.sensing
                        .encoders
                        .slave
                        .set_glitch_gate(slave.glitch_gate_periods);
                }
                self.calibration.unsaved = true;
            }
            self.calibration.calibrated.record(routine, result);
            if self.calibration.status != CalibrationStatus::Calibrated {
                self.calibration.status =
                    if CalibrationRecord::of(&self.calibration.calibrated, &self.config)
                        .is_complete()
                    {
                        CalibrationStatus::Calibrated
                    } else {
                        CalibrationStatus::Incomplete
                    };
            }
            let hold = Setpoint::at_rest(position_m);
            (self.mode, demand) = if self.sensing.zero_raw_m.is_some() {
                let track = Demand::Track {
                    setpoint: hold,
                    master_only: false,
                    slave_d_a: 0.0,
                };
                (Mode::Holding(hold), track)
            } else {
                (Mode::Idle, Demand::Off)
            };
            self.status.mode = self.mode_kind();
        }
        self.shares = PerSection::default();
        let inv_kf = 1.0 / self.config.motor.force_constant_n_per_a;
        let o = self.config.angle_offset;
        let own_frame = PerSection {
            master: measured.angle.master.wrapping_add(o.master),
            slave: measured.angle.slave.wrapping_add(o.slave),
        };
        // Each section's angle (forced, or its encoder's with its offset) and d/q reference.
        let frames = match demand {
            Demand::Forced(forced) => {
                let frame = |f: Option<crate::control::calibration::Forced>, own: u32| {
                    f.map_or((own, Dq::default()), |f| (f.angle, f.current))
                };
                PerSection {
                    master: frame(forced.master, own_frame.master),
                    slave: frame(forced.slave, own_frame.slave),
                }
            }
            Demand::Track {
                setpoint,
                master_only,
                slave_d_a,
            } => {
                // The position loop as in any mode (the next cycle's supervision checks the
                // following error against this setpoint).
                self.setpoint = Some(setpoint);
                let limit = self.config.force_limit_n;
                let derivatives = Derivatives {
                    velocity_mps: s.velocity_mps,
                    acceleration_mps2: s.acceleration_mps2,
                };
                let model = self.model_forces(&setpoint, gas_force_n);
                let force =
                    self.position_loop(&setpoint, position_m, &derivatives, &model, 0.0, limit);
                let mut allocation = self.config.allocation;
                if master_only {
                    allocation.capability.slave = 0.0;
                }
                self.shares = allocate(&allocation, force, position_m);
                self.status.reference_m = setpoint.position_m;
                self.status.force_command_n = force;
                self.status.limits.force = force.abs() >= limit;
                PerSection {
                    master: (
                        own_frame.master,
                        Dq {
                            d: 0.0,
                            q: self.shares.master * inv_kf,
                        },
                    ),
                    slave: (
                        own_frame.slave,
                        Dq {
                            d: slave_d_a,
                            q: self.shares.slave * inv_kf,
                        },
                    ),
                }
            }
            Demand::Off | Demand::Done(_) => {
                self.currents.master.reset();
                self.currents.slave.reset();
                return None;
            }
        };
        let mut out = PerSection::<PhaseDuties>::default();
        for section in Section::ALL {
            let (angle, reference) = *frames.get(section);
            let amps = self
                .config
                .current_sense
                .get(section)
                .amps(inputs.currents.get(section));
            *out.get_mut(section) =
                self.currents
                    .get_mut(section)
                    .step(amps, angle, reference, s.velocity_mps);
        }
        self.status.limits.voltage = self.currents.master.state().voltage_limited
            || self.currents.slave.state().voltage_limited;
        Some(out)
    }
}
