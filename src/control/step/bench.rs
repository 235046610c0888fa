//! The bring-up's bench operations (the bench build's; `docs/bring-up.md` §2 and §9): a
//! fixed duty on one phase of one section, a torque to the servo drive. Each runs for its
//! time, then the machine is idle; `Stop` or any fault ends it sooner, and a fixed duty ends
//! the cycle the DC link comes up. Neither enables the outputs as the machine's modes do:
//! the parts absent since boot stay a state, not faults — the fixed duty runs with the DC
//! link off, on the bench supply, and nothing measures where the mover is. Out of line and
//! in flash: no cycle of the machine's own modes runs this code.

use super::commands::check_bench;
use super::modes::{BenchRun, Mode};
use super::ControlStep;
use crate::control::command::{BenchOp, Refusal, BENCH_SERVO_TURN_RAD};
use crate::ports::PhaseCurrentCodes;
use crate::units::{DacCode, Duty, PerSection, PhaseDuties};

impl ControlStep {
    /// A bench command: checked ([`check_bench`]), then the operation starts (the outputs not
    /// energised: the parts absent since boot stay a state). Out of line, in flash: it runs
    /// once per command, and the command handling it would be inlined into is in CCM SRAM.
    #[cold]
    #[inline(never)]
    pub(super) fn bench_command(&mut self, op: BenchOp, seconds: f32) -> Result<(), Refusal> {
        let (op, cycles) = check_bench(&self.view(), op, seconds)?;
        self.supervision.bench_since_boot = true;
        self.plan.mode = Mode::Bench(BenchRun {
            op,
            servo_from_rad: self.rotary.servo.angle_rad(),
            cycles_left: cycles,
        });
        Ok(())
    }

    /// A bench operation's cycle: the fixed duty's duties, or the outputs off (the servo
    /// torque). At its end — its time, the DC link up under a fixed duty, the shaft turned
    /// [`BENCH_SERVO_TURN_RAD`] under a servo torque — the machine is idle, the outputs off.
    #[cold]
    #[inline(never)]
    pub(super) fn bench_cycle(
        &mut self,
        codes: &PerSection<PhaseCurrentCodes>,
    ) -> Option<PerSection<PhaseDuties>> {
        let Mode::Bench(run) = &mut self.plan.mode else {
            return None;
        };
        run.cycles_left = run.cycles_left.saturating_sub(1);
        let (fixed, ended) = match run.op {
            BenchOp::FixedDuty {
                section,
                phase,
                duty,
            } => (Some((section, phase, duty)), self.supervision.supply_good),
            BenchOp::ServoTorque { .. } => {
                let turned = self.rotary.servo.angle_rad() - run.servo_from_rad;
                (None, turned.abs() >= BENCH_SERVO_TURN_RAD)
            }
        };
        if ended || run.cycles_left == 0 {
            self.plan.mode = Mode::Idle;
            self.publish.mode = self.plan.mode_kind();
        } else if let Some((section, phase, duty)) = fixed {
            self.drive.reset();
            let mut duties = PerSection {
                master: [Duty::HALF; 3],
                slave: [Duty::HALF; 3],
            };
            if let Some(d) = duties.get_mut(section).get_mut(usize::from(phase)) {
                *d = Duty::from_fraction(duty);
            }
            return Some(duties);
        }
        self.publish.previous.outputs_off();
        self.drive.outputs_off(codes, false)
    }

    /// The servo's command: a bench operation's torque, else `servo` (the rotate stage's).
    #[cold]
    #[inline(never)]
    pub(super) fn bench_servo(&mut self, servo: DacCode) -> DacCode {
        match self.plan.mode {
            Mode::Bench(BenchRun {
                op: BenchOp::ServoTorque { torque_nm },
                ..
            }) => self.rotary.servo.command(torque_nm),
            _ => servo,
        }
    }
}
