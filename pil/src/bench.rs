//! The bring-up's bench operations on the emulated board, as the rig's engineer runs them
//! (`docs/bring-up.md` §2 and §9.3): the ELF boots on the reference machine with its bridges
//! on a low-voltage bench supply (the DC link at [`BENCH_BUS_V`], power-good low since
//! boot), the piston at mid-travel, and the host — `fpc-sim link send bench …`'s and
//! `… stop`'s own code over the RTT channels in the emulated chip's RAM — sends the
//! operations; between them the test reads what the chip drives: the output stages, the
//! compare registers, the DAC.

use std::time::Duration;

use fpc::control::command::{BenchOp, Command};
use fpc::units::{DacCode, PerSection, PhaseDuties};
use hal_sim::link::session::{outcome_text, send_command};
use hal_sim::run::RunOptions;

use crate::board::Board;
use crate::chip::timers::reg;
use crate::chip::{ChipOptions, DeadlineFigures};
use crate::commission::Attached;
use crate::elf::Image;
use crate::session::Session;

/// The bench supply's voltage on the DC link, V (`docs/bring-up.md` §2).
pub const BENCH_BUS_V: f64 = 12.0;

/// What the chip drives now.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Driven {
    /// Each bridge switching, as its timer's output stage decides it (MOE, OSSI, CCxE,
    /// CCxNE, polarity, mode: [`crate::chip::output_stage::bridge`]).
    pub switching: PerSection<bool>,
    /// The compare values CCR1..3 of TIM1 (master) and TIM8 (slave).
    pub compare: PerSection<[u32; 3]>,
    /// The duties the plant applies (from the update events).
    pub duties: PerSection<PhaseDuties>,
    /// DAC1 channel 1's code (the servo's torque command).
    pub dac: DacCode,
    /// The servo encoder's count (TIM4).
    pub quadrature: u16,
}

/// The emulated board on the bench, the host attached.
pub struct Bench {
    s: Session,
    block: hal_sim::link::rtt::ControlBlock,
}

impl Bench {
    /// Boots `image` on the reference machine with the DC link at [`BENCH_BUS_V`] (no
    /// calibration record in the store) and runs it 0.1 s.
    pub fn boot(image: &Image) -> Result<Bench, String> {
        let mut opts = RunOptions::reference();
        opts.model.motor.bus_voltage_v = BENCH_BUS_V;
        let start_m = 0.5 * opts.model.piston.travel_m;
        let world = hal_sim::run::world(&opts.model, opts.seed, 0, start_m);
        let mut s = Session::new(image.clone(), Board::new(world), ChipOptions::default())?;
        s.chip.soc().recording = true;
        s.run_until(0.1)?;
        let block = s.rtt().ok_or("the firmware set no RTT control block up")?;
        // From here the host's link code alone reads the channels.
        s.host_detached = true;
        Ok(Bench { s, block })
    }

    /// Runs `command` as `fpc-sim link send` does: `op` for `seconds` (the bench
    /// operation's lines, or its error), or, with `op` `None`, `stop` (its line).
    pub fn send(
        &mut self,
        op: Option<BenchOp>,
        seconds: f32,
    ) -> Result<Result<Vec<String>, String>, String> {
        let mut host = Attached {
            s: &mut self.s,
            block: self.block.clone(),
            stopped: None,
        };
        let timeout = Duration::from_secs(5);
        let mut earlier = Vec::new();
        let done = match op {
            Some(op) => {
                hal_sim::link::bench::run(&mut host, op, seconds, timeout, |l| earlier.push(l))
            }
            None => send_command(&mut host, &Command::Stop, timeout, |l| earlier.push(l))
                .map(|o| vec![outcome_text(&o)]),
        };
        if let Some(e) = host.stopped.take() {
            return Err(e);
        }
        Ok(done.map(|lines| earlier.into_iter().chain(lines).collect()))
    }

    /// Runs the board `seconds` more, the session reading the up channels meanwhile (the
    /// status from the telemetry, the log).
    pub fn run_for(&mut self, seconds: f64) -> Result<(), String> {
        let t = self.s.chip.time_s() + seconds;
        self.s.host_detached = false;
        let run = self.s.run_until(t);
        self.s.host_detached = true;
        run
    }

    /// What the chip drives now.
    pub fn driven(&self) -> Driven {
        let soc = self.s.chip.soc_ref();
        let compare =
            |timer| [0, 1, 2].map(|ch| soc.timer_register(timer, reg::CCR1 + 4 * ch as u32));
        let w = &soc.board.world;
        Driven {
            switching: w.sections_on,
            compare: PerSection {
                master: compare(0),
                slave: compare(1),
            },
            duties: w.duties_in_force,
            dac: DacCode(soc.dac_code()),
            quadrature: soc.board.quadrature(),
        }
    }

    /// The control period's deadline since boot ([`crate::chip::deadline`]).
    pub fn deadline(&self) -> DeadlineFigures {
        DeadlineFigures::of(&self.s.chip.soc_ref().samples)
    }

    /// The session (the status the telemetry last reported, the log).
    pub fn session(&self) -> &Session {
        &self.s
    }
}
