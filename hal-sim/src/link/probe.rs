//! The probe (cargo feature `probe`): the board's memory through a debug probe, with the
//! `probe-rs` library, as a [`MemAccessPort`] — so the RTT transport over it is
//! [`crate::link::rtt::RttChannels`] on [`NonHalting`], the very code the PIL's capture test
//! runs on the emulated chip's debug port. Thin on purpose: choose and open the probe, reach
//! the memory access port, move words; and flash a firmware image, reset, detach (`fpc-sim
//! link flash`, which does halt: refused while the machine moves unless `--force`).
//!
//! No `probe_rs::Session` for the link: a session halts the core on attach and on drop
//! (`docs/link.md`, "The link never halts the core"). The probe is attached to the
//! unspecified target, turned into probe-rs's ARM debug interface with the default sequence
//! (the debug port powered up; no vendor unlock, no DBGMCU write, no core attach), and only
//! MEM-AP 0's 32-bit reads and writes of RAM are issued. `--connect-under-reset` asserts the
//! reset line (it restarts the firmware, as asked). The control block is taken at the ELF's
//! `_SEGGER_RTT` when an ELF is given, otherwise searched for in the G474's SRAM.

use std::io;
use std::path::Path;

use probe_rs::architecture::arm::sequences::DefaultArmSequence;
use probe_rs::architecture::arm::{ArmDebugInterface, FullyQualifiedApAddress};
use probe_rs::probe::list::Lister;
use probe_rs::probe::{DebugProbeSelector, Probe};
use probe_rs::{Permissions, Session};

use super::debugport::{MemAccessPort, NonHalting};
use super::rtt::{Locate, RttChannels};

/// How to reach the board.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ProbeOptions {
    /// The chip, as probe-rs names it.
    pub chip: String,
    /// Which probe: `VID:PID` or `VID:PID:SERIAL` (hex ids, as `probe-rs list` shows them);
    /// `None`: the only one connected.
    pub probe: Option<String>,
    /// SWD clock, kHz (`None`: the probe's default).
    pub speed_khz: Option<u32>,
    /// Assert the reset line while connecting (a chip whose SWD pins were reconfigured, or
    /// that sleeps too deeply to answer); this restarts the firmware.
    pub connect_under_reset: bool,
}

fn other(e: impl std::fmt::Display) -> io::Error {
    io::Error::other(e.to_string())
}

/// `e` with its causes, on one line (probe-rs's top-level messages are vague: "An error with
/// the usage of the probe occurred" hides "the selected debug probe was not found").
fn chain(e: &dyn std::error::Error) -> String {
    let mut parts = vec![e.to_string()];
    let mut cause = e.source();
    while let Some(c) = cause {
        parts.push(c.to_string());
        cause = c.source();
    }
    parts
        .iter()
        .map(|p| p.split_whitespace().collect::<Vec<_>>().join(" "))
        .map(|p| p.trim_end_matches('.').to_string())
        .collect::<Vec<_>>()
        .join(": ")
}

/// Opens the probe `opts` names, at the speed asked.
fn open(opts: &ProbeOptions) -> Result<Probe, String> {
    let lister = Lister::new();
    let mut probe = match &opts.probe {
        Some(text) => {
            let selector: DebugProbeSelector = text.parse().map_err(|e| {
                format!(
                    "--probe {text}: not VID:PID or VID:PID:SERIAL ({})",
                    chain(&e)
                )
            })?;
            lister
                .open(selector)
                .map_err(|e| format!("cannot open the probe {text}: {}", chain(&e)))?
        }
        None => {
            let found = lister.list_all();
            match found.as_slice() {
                [] => {
                    return Err(
                        "no debug probe found (is it plugged in, with access rights?)".into(),
                    )
                }
                [one] => one
                    .open()
                    .map_err(|e| format!("cannot open the probe {one}: {}", chain(&e)))?,
                many => {
                    let list: Vec<String> = many.iter().map(|p| p.to_string()).collect();
                    return Err(format!(
                        "{} debug probes found; choose one with --probe VID:PID[:SERIAL]: {}",
                        many.len(),
                        list.join("; ")
                    ));
                }
            }
        }
    };
    if let Some(khz) = opts.speed_khz {
        probe
            .set_speed(khz)
            .map_err(|e| format!("--speed {khz}: {}", chain(&e)))?;
    }
    Ok(probe)
}

/// Opens the probe and attaches a debug session to the chip (halts the core: for flashing).
fn session(opts: &ProbeOptions) -> Result<Session, String> {
    let probe = open(opts)?;
    let chip = opts.chip.as_str();
    let attached = if opts.connect_under_reset {
        probe.attach_under_reset(chip, Permissions::default())
    } else {
        probe.attach(chip, Permissions::default())
    };
    attached.map_err(|e| format!("cannot attach to {chip} through the probe: {}", chain(&e)))
}

/// The board's memory access port 0 through the probe's ARM debug interface: word reads and
/// writes while the core runs, no debug session.
pub struct ProbeMemAp {
    interface: Box<dyn ArmDebugInterface + 'static>,
    ap: FullyQualifiedApAddress,
}

impl ProbeMemAp {
    /// Opens the probe, connects to the debug port (no core attach, no halt).
    pub fn open(opts: &ProbeOptions) -> Result<ProbeMemAp, String> {
        let mut probe = open(opts)?;
        let connected = if opts.connect_under_reset {
            probe.attach_to_unspecified_under_reset()
        } else {
            probe.attach_to_unspecified()
        };
        connected.map_err(|e| format!("cannot connect to {}: {}", opts.chip, chain(&e)))?;
        let interface = probe
            .try_into_arm_debug_interface(DefaultArmSequence::create())
            .map_err(|(_, e)| format!("{}: no ARM debug port: {}", opts.chip, chain(&e)))?;
        Ok(ProbeMemAp {
            interface,
            ap: FullyQualifiedApAddress::v1_with_default_dp(0),
        })
    }
}

impl MemAccessPort for ProbeMemAp {
    fn attach(&mut self) -> io::Result<()> {
        // Connected by `open`: the memory access port is selected on first use.
        Ok(())
    }

    fn read_words(&mut self, address: u32, words: &mut [u32]) -> io::Result<()> {
        let mut m = self
            .interface
            .memory_interface(&self.ap)
            .map_err(|e| other(chain(&e)))?;
        m.read_32(u64::from(address), words)
            .map_err(|e| other(chain(&e)))
    }

    fn write_words(&mut self, address: u32, words: &[u32]) -> io::Result<()> {
        let mut m = self
            .interface
            .memory_interface(&self.ap)
            .map_err(|e| other(chain(&e)))?;
        m.write_32(u64::from(address), words)
            .and_then(|()| m.flush())
            .map_err(|e| other(chain(&e)))
    }

    fn detach(&mut self) -> io::Result<()> {
        // The interface is closed (the debug port released) when dropped.
        Ok(())
    }
}

/// The STM32G474's SRAM1 + SRAM2, where the firmware's RTT control block is searched for
/// without an ELF.
const G474_RAM: std::ops::Range<u64> = 0x2000_0000..0x2002_0000;

/// Attaches to the running board's RTT control block through the memory access port: at the
/// address the ELF `elf` names, if given, else found in the chip's RAM. Never halts the core.
pub fn attach(
    opts: &ProbeOptions,
    elf: Option<&Path>,
) -> Result<RttChannels<NonHalting<ProbeMemAp>>, String> {
    let locate = match elf {
        Some(path) => {
            let bytes = std::fs::read(path)
                .map_err(|e| format!("cannot read {}: {e}", crate::output::show(path)))?;
            match probe_rs::rtt::find_rtt_control_block_in_raw_file(&bytes) {
                Ok(Some(address)) => Locate::At(address),
                _ => {
                    return Err(format!(
                        "{}: no `_SEGGER_RTT` symbol (is it the fpc firmware's ELF?)",
                        crate::output::show(path)
                    ))
                }
            }
        }
        None => Locate::Scan(vec![G474_RAM]),
    };
    let memory = NonHalting::attach(ProbeMemAp::open(opts)?).map_err(|e| e.to_string())?;
    RttChannels::attach(memory, &locate)
        .map_err(|e| format!("{e} (on {}: is the fpc firmware running?)", opts.chip))
}

/// Writes the firmware `elf` to the board's flash, resets the core and detaches, leaving
/// the firmware running. Returns what was done, as one line.
pub fn flash(opts: &ProbeOptions, elf: &Path) -> Result<String, String> {
    let mut session = session(opts)?;
    let format =
        probe_rs::flashing::image_format("elf").ok_or("this probe-rs has no ELF loader")?;
    let mut options = probe_rs::flashing::DownloadOptions::default();
    options.verify = true;
    probe_rs::flashing::download_file_with_options(
        &mut session,
        elf,
        format.create_loader(None),
        options,
    )
    .map_err(|e| format!("cannot flash {}: {}", crate::output::show(elf), chain(&e)))?;
    session
        .core(0)
        .and_then(|mut core| core.reset())
        .map_err(|e| format!("flashed, but the reset failed: {}", chain(&e)))?;
    // Dropping the session detaches the probe without halting the core.
    drop(session);
    Ok(format!(
        "flashed and verified {} on {}; reset, detached: the firmware runs",
        crate::output::show(elf),
        opts.chip
    ))
}
