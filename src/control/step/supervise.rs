//! The supervise stage: limits and faults, and the one place that moves the machine to its
//! safe state (SS1 while the position can be trusted, STO when it cannot).

use super::modes::{AfterStop, Mode};
use super::sense::Sensed;
use super::ControlStep;
use crate::real::max_f32;
use crate::safety::faults::Fault;
use crate::safety::supervisor::Observation;

impl ControlStep {
    /// The supervise stage: the machine's limits checked against this cycle's measurements
    /// (a fault latched and its reaction started, a lost section dropped), and the host's
    /// heartbeat timed (host lost: park).
    pub(super) fn supervise(&mut self, s: &Sensed) {
        let dt = self.config.sample_time_s;
        let homed = self.zero_raw_m.is_some();
        let driving = !matches!(self.mode, Mode::Idle | Mode::Faulted);
        // The rotation times the ports only while compressing; in a stop it only holds (or,
        // after a reset, coasts down), whatever the linear motion does.
        let running = matches!(self.mode, Mode::Running(_));
        let rotation_error_rad = if running {
            self.theta_reference_rad - self.servo.angle_rad()
        } else {
            0.0
        };
        // Only looked at once the error is large (never in normal running: the step stays
        // cheap).
        let rotation_stalled = rotation_error_rad.abs()
            > self.config.supervisor.rotation_stall_error_rad
            && self.rotation_stalled();
        let observation = Observation {
            dt_s: dt,
            homed,
            driving: driving && !matches!(self.mode, Mode::Homing(_)),
            position_m: s.position_m,
            slave_position_m: s.slave_raw_m - self.zero_slave_raw_m,
            velocity_mps: s.derivatives.velocity_mps,
            reference_m: self.reference_m().unwrap_or(s.position_m),
            peak_phase_a: max_f32(
                self.currents.master.state().peak_phase_a,
                self.currents.slave.state().peak_phase_a,
            ),
            commanded_n: [self.shares.master, self.shares.slave],
            delivered_n: [s.force_master_n, s.force_slave_n],
            rotation_error_rad,
            rotation_stalled,
        };
        let verdict = self.supervisor.check(&self.config.supervisor, &observation);
        if let Some(section) = verdict.lost_section {
            self.drop_section(section);
        }
        if let Some(fault) = verdict.fault {
            if fault == Fault::Overcurrent {
                // Drop the section with the excessive current; the other one stops the piston.
                let m = self.currents.master.state().peak_phase_a;
                let s = self.currents.slave.state().peak_phase_a;
                self.drop_section(if m >= s { 0 } else { 1 });
            }
            if fault == Fault::EncoderMismatch {
                self.encoder_mismatch(&s.master, &s.slave);
            } else {
                self.latch(fault);
            }
        }

        if let Some(elapsed) = self.heartbeat_s.as_mut() {
            *elapsed += dt;
            if *elapsed >= self.config.heartbeat_timeout_s {
                // Host lost: park (a controlled stop first), not a fault. Disarmed until the
                // host is back.
                self.heartbeat_s = None;
                if matches!(
                    self.mode,
                    Mode::Moving { .. } | Mode::Holding(_) | Mode::Running(_)
                ) {
                    self.begin_stop(AfterStop::Park);
                }
            }
        }
    }

    /// Latches `fault` and starts its reaction: SS1 while the position can be trusted,
    /// STO when it cannot (see [`Fault::position_trusted`]).
    pub(super) fn latch(&mut self, fault: Fault) {
        self.latch_as(fault, fault.position_trusted());
    }

    /// The one place that moves the machine to its safe state: latches `fault`; with the
    /// position trusted (and known: homed) a controlled stop on the braking envelope that
    /// ends with the outputs off (SS1), otherwise the outputs off at once (STO) — also when
    /// the fault was already latched with the position still trusted then.
    #[cold]
    #[inline(never)]
    pub(super) fn latch_as(&mut self, fault: Fault, position_trusted: bool) {
        let new = self.faults.latch(fault);
        if !(position_trusted && self.zero_raw_m.is_some()) {
            self.mode = Mode::Faulted;
        } else if new {
            self.begin_stop(AfterStop::Off);
        }
    }

    /// Takes a section out of the allocation (lost, or switched off after an overcurrent).
    pub(super) fn drop_section(&mut self, index: usize) {
        let cap = &mut self.config.allocation.capability;
        if index == 0 {
            cap.master = 0.0;
        } else {
            cap.slave = 0.0;
        }
    }

    /// Whether the rotation turns at less than a quarter of its reference's speed.
    #[cold]
    #[inline(never)]
    pub(super) fn rotation_stalled(&self) -> bool {
        self.servo.velocity_rad_s().abs() < 0.25 * self.theta_reference_speed_rad_s.abs()
    }
}
