//! The supervise stage: limits and faults detected, and the one place that dispatches a
//! latched fault to its reaction ([`ControlStep::react`]: one `match` on
//! [`Reaction`]); the reactions themselves are in `safe_state.rs`.

use super::modes::{AfterStop, Mode};
use super::sense::Sensed;
use super::ControlStep;
use crate::real::max_f32;
use crate::safety::faults::{Fault, Reaction};
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
            // Two encoders that disagree: the readings may show which one is wrong (it is
            // taken out, SS1 on the other); the fault's kind alone cannot.
            let reaction = match fault {
                Fault::EncoderMismatch => self.encoder_mismatch(&s.master, &s.slave),
                _ => fault.reaction(),
            };
            self.react(fault, reaction);
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

    /// Latches `fault` and starts the reaction it asks for ([`Fault::reaction`]).
    pub(super) fn latch(&mut self, fault: Fault) {
        self.react(fault, fault.reaction());
    }

    /// The one dispatch from a fault to the safe state: latches `fault` and carries out
    /// `reaction` (`safe_state.rs`). Each reaction starts SS1 (a controlled stop ending with
    /// the outputs off; STO while not homed) or STO, the section or braking steps around it.
    #[cold]
    #[inline(never)]
    pub(super) fn react(&mut self, fault: Fault, reaction: Reaction) {
        match reaction {
            Reaction::Ss1 | Reaction::Sto => {
                self.enter_safe_state(fault, reaction.position_trusted());
            }
            Reaction::DropSection => {
                self.drop_hotter_section();
                self.enter_safe_state(fault, true);
            }
            Reaction::BrakeWithoutPosition => {
                self.enter_safe_state(fault, false);
                self.brake_without_position();
            }
            Reaction::BrakeAfterReset => {
                self.enter_safe_state(fault, true);
                self.await_velocity_then_brake();
            }
        }
    }

    /// Whether the rotation turns at less than a quarter of its reference's speed.
    #[cold]
    #[inline(never)]
    pub(super) fn rotation_stalled(&self) -> bool {
        self.servo.velocity_rad_s().abs() < 0.25 * self.theta_reference_speed_rad_s.abs()
    }
}
