//! The motor's commissioning on the emulated board, as the rig's engineer runs it: the release
//! ELF boots on the reference machine wired as [`Wiring`] says, the piston resting at
//! mid-travel, and the host — `fpc-sim link send calibrate ROUTINE`'s own code
//! ([`hal_sim::link::report::calibrate`]) over the RTT channels in the emulated chip's RAM —
//! runs `current-sense`, then `commission`, and prints what the board reported.

use std::io;
use std::time::Duration;

use fpc::control::calibration::Routine;
use hal_sim::board::wiring::Wiring;
use hal_sim::link::rtt::ControlBlock;
use hal_sim::link::Channels;
use hal_sim::run::RunOptions;

use crate::board::Board;
use crate::chip::{ChipOptions, DeadlineFigures};
use crate::elf::Image;
use crate::session::Session;

/// What the host printed, and how the board kept its deadline meanwhile.
#[derive(Clone, Debug)]
pub struct Commissioned {
    /// The lines of `calibrate current-sense`, then of `calibrate commission`.
    pub lines: Vec<String>,
    /// The host's error after them, if a routine was refused or failed.
    pub error: Option<String>,
    /// Emulated time at the end, s.
    pub end_s: f64,
    /// The control period's deadline over the whole run ([`crate::chip::deadline`]).
    pub deadline: DeadlineFigures,
}

/// The host's channels on the emulated chip: read and written in its RAM, the chip run while
/// the host waits.
pub(crate) struct Attached<'a> {
    pub(crate) s: &'a mut Session,
    pub(crate) block: ControlBlock,
    /// The emulation's error, once it stopped.
    pub(crate) stopped: Option<String>,
}

impl Attached<'_> {
    pub(crate) fn check(&self) -> io::Result<()> {
        match &self.stopped {
            Some(e) => Err(io::Error::other(e.clone())),
            None => Ok(()),
        }
    }
}

impl Channels for Attached<'_> {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> io::Result<usize> {
        self.check()?;
        self.block.read_up(&mut self.s.chip, channel, buf)
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> io::Result<usize> {
        self.check()?;
        self.block.write_down(&mut self.s.chip, channel, bytes)
    }

    fn pause(&mut self, d: Duration) {
        if self.stopped.is_none() {
            let t = self.s.chip.time_s() + d.as_secs_f64();
            if let Err(e) = self.s.run_until(t) {
                self.stopped = Some(e);
            }
        }
    }
}

/// Boots `image` on the reference machine wired as `wiring` (no calibration record in the
/// store: the routines run on the firmware's own configuration) and commissions it.
pub fn commission(image: &Image, wiring: Wiring) -> Result<Commissioned, String> {
    let opts = RunOptions::reference();
    let start_m = 0.5 * opts.model.piston.travel_m;
    let mut world = hal_sim::run::world(&opts.model, opts.seed, 0, start_m);
    world.set_wiring(wiring);
    let mut s = Session::new(image.clone(), Board::new(world), ChipOptions::default())?;
    s.chip.soc().recording = true;
    // Booted, and the channels up (the session asks for telemetry at every boot).
    s.run_until(0.1)?;
    let block = s.rtt().ok_or("the firmware set no RTT control block up")?;
    // From here the host's link code alone reads the channels.
    s.host_detached = true;
    let mut host = Attached {
        s: &mut s,
        block,
        stopped: None,
    };
    let timeout = Duration::from_secs(5);
    let mut lines = Vec::new();
    let mut error = None;
    for routine in [Routine::CurrentSense, Routine::Commission] {
        let done = hal_sim::link::report::calibrate(&mut host, routine, timeout, |l| lines.push(l));
        match done {
            Ok(l) => lines.extend(l),
            Err((l, e)) => {
                lines.extend(l);
                error = Some(e);
                break;
            }
        }
    }
    if let Some(e) = host.stopped.take() {
        return Err(e);
    }
    let soc = s.chip.soc_ref();
    Ok(Commissioned {
        lines,
        error,
        end_s: s.chip.time_s(),
        deadline: DeadlineFigures::of(&soc.samples),
    })
}
