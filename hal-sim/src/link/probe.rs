//! The probe (cargo feature `probe`): the board's memory through a debug probe, with the
//! `probe-rs` library, as a [`TargetMemory`] — so the RTT transport over it is
//! [`crate::link::rtt::RttChannels`], the very code the tests run on the simulated board's
//! RAM. Thin on purpose: choose and open the probe, reach the memory, read and write it; and
//! flash a firmware image, reset, detach (`fpc-sim link flash`).
//!
//! The link never halts the core. It reaches memory through the debug port's memory access
//! port (AHB-AP 0) alone ([`attach_memory`]), with no `probe_rs::Session`: a session halts
//! every core on attach and again when dropped, to clear the breakpoint unit, and writes
//! DEMCR = 0 on detach. Nothing here reads or writes the core's debug registers (DHCSR,
//! DEMCR, the FPB, the DWT): the firmware keeps controlling the machine, and a halt — which
//! freezes TIM1/TIM8 with their outputs off and stops the machine on resume — can only come
//! from a debugger. Flashing does halt and reset, and is refused by the command line while
//! the machine is energised (`--force` overrides). The control block is taken at the ELF's
//! `_SEGGER_RTT` when an ELF is given, otherwise searched for in the chip's RAM.

use std::io;
use std::path::Path;

use probe_rs::architecture::arm::sequences::DefaultArmSequence;
use probe_rs::architecture::arm::{ArmDebugInterface, FullyQualifiedApAddress};
use probe_rs::probe::list::Lister;
use probe_rs::probe::{DebugProbeSelector, Probe};
use probe_rs::Permissions;

use super::memory::TargetMemory;
use super::rtt::{Locate, RttChannels};

/// The memory access port the link uses: AP 0 of the default debug port, the Cortex-M4's
/// AHB-AP (system bus view: SRAM, peripherals).
pub const MEMORY_AP: FullyQualifiedApAddress = FullyQualifiedApAddress::v1_with_default_dp(0);

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
pub fn chain(e: &dyn std::error::Error) -> String {
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

/// Opens the probe `opts` names, at its SWD clock (not yet connected to the chip).
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

/// The board's memory through the debug port's memory access port ([`MEMORY_AP`]): reads
/// and writes on the system bus while the core runs, nothing else.
pub struct ProbeMemory {
    interface: Box<dyn ArmDebugInterface>,
}

impl ProbeMemory {
    fn memory(
        &mut self,
    ) -> io::Result<Box<dyn probe_rs::architecture::arm::memory::ArmMemoryInterface + '_>> {
        self.interface
            .memory_interface(&MEMORY_AP)
            .map_err(|e| other(chain(&e)))
    }
}

impl TargetMemory for ProbeMemory {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
        self.memory()?
            .read_8(address, buf)
            .map_err(|e| other(chain(&e)))
    }

    fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
        self.memory()?
            .write_8(address, bytes)
            .map_err(|e| other(chain(&e)))
    }

    /// One 32-bit access per word: the RTT offsets change while the firmware runs.
    fn read_words(&mut self, address: u64, words: &mut [u32]) -> io::Result<()> {
        self.memory()?
            .read_32(address, words)
            .map_err(|e| other(chain(&e)))
    }

    fn write_word(&mut self, address: u64, word: u32) -> io::Result<()> {
        self.memory()?
            .write_word_32(address, word)
            .map_err(|e| other(chain(&e)))
    }
}

/// Connects `probe` to the chip's debug port and its memory access port, without a
/// `probe_rs::Session` (which would halt the core): the debug port's own power-up and the
/// access port's registers, nothing in the core. `under_reset` holds the reset line while
/// connecting and releases it after (the firmware restarts).
pub fn attach_memory(mut probe: Probe, under_reset: bool) -> Result<ProbeMemory, String> {
    let connected = if under_reset {
        probe.attach_to_unspecified_under_reset()
    } else {
        probe.attach_to_unspecified()
    };
    connected.map_err(|e| format!("cannot connect to the debug port: {}", chain(&e)))?;
    let mut interface = probe
        .try_into_arm_debug_interface(DefaultArmSequence::create())
        .map_err(|(_, e)| format!("the probe has no ARM debug interface: {}", chain(&e)))?;
    // The first access powers the debug port up and checks the access port is a MEM-AP.
    interface
        .memory_interface(&MEMORY_AP)
        .map_err(|e| format!("cannot reach the memory access port: {}", chain(&e)))?;
    if under_reset {
        let mut probe = interface.close();
        probe
            .target_reset_deassert()
            .map_err(|e| format!("cannot release the reset line: {}", chain(&e)))?;
        interface = probe
            .try_into_arm_debug_interface(DefaultArmSequence::create())
            .map_err(|(_, e)| format!("the probe has no ARM debug interface: {}", chain(&e)))?;
    }
    Ok(ProbeMemory { interface })
}

/// Where the RTT control block is: at the `_SEGGER_RTT` of `elf` (the ELF's bytes and its
/// name, for messages), else anywhere in the RAM of `chip` (probe-rs's memory map of it).
pub fn locate(chip: &str, elf: Option<(&[u8], &Path)>) -> Result<Locate, String> {
    if let Some((bytes, path)) = elf {
        return match probe_rs::rtt::find_rtt_control_block_in_raw_file(bytes) {
            Ok(Some(address)) => Ok(Locate::At(address)),
            _ => Err(format!(
                "{}: no `_SEGGER_RTT` symbol (is it the fpc firmware's ELF?)",
                crate::output::show(path)
            )),
        };
    }
    let target = probe_rs::config::Registry::from_builtin_families()
        .get_target_by_name(chip)
        .map_err(|e| format!("--chip {chip}: {}", chain(&e)))?;
    Ok(Locate::Scan(
        target
            .memory_map
            .iter()
            .filter_map(|region| match region {
                probe_rs::config::MemoryRegion::Ram(r) => Some(r.range.clone()),
                _ => None,
            })
            .collect(),
    ))
}

/// The RTT channels of the fpc firmware in `memory`, found as `locate` says.
pub fn rtt(
    memory: ProbeMemory,
    locate: &Locate,
    chip: &str,
) -> Result<RttChannels<ProbeMemory>, String> {
    RttChannels::attach(memory, locate)
        .map_err(|e| format!("{e} (on {chip}: is the fpc firmware running?)"))
}

/// Attaches to the running board, without halting it, and to its RTT control block: at the
/// address the ELF `elf` names, if given, else found in the chip's RAM.
pub fn attach(opts: &ProbeOptions, elf: Option<&Path>) -> Result<RttChannels<ProbeMemory>, String> {
    let bytes = match elf {
        Some(path) => Some(
            std::fs::read(path)
                .map_err(|e| format!("cannot read {}: {e}", crate::output::show(path)))?,
        ),
        None => None,
    };
    let locate = locate(&opts.chip, bytes.as_deref().zip(elf))?;
    let memory = attach_memory(open(opts)?, opts.connect_under_reset)?;
    rtt(memory, &locate, &opts.chip)
}

/// Writes the firmware `elf` to the board's flash, resets the core and detaches, leaving
/// the firmware running. Returns what was done, as one line.
pub fn flash(opts: &ProbeOptions, elf: &Path) -> Result<String, String> {
    let probe = open(opts)?;
    let chip = opts.chip.as_str();
    let attached = if opts.connect_under_reset {
        probe.attach_under_reset(chip, Permissions::default())
    } else {
        probe.attach(chip, Permissions::default())
    };
    let mut session = attached
        .map_err(|e| format!("cannot attach to {chip} through the probe: {}", chain(&e)))?;
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
    // Dropping the session halts the core to clear its breakpoints, resumes it and detaches.
    drop(session);
    Ok(format!(
        "flashed and verified {} on {}; reset, detached: the firmware runs",
        crate::output::show(elf),
        opts.chip
    ))
}
