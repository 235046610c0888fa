//! The probe (cargo feature `probe`): the board's memory through a debug probe, with the
//! `probe-rs` library, as a [`TargetMemory`] — so the RTT transport over it is
//! [`crate::link::rtt::RttChannels`], the very code the tests run on the simulated board's
//! RAM. Thin on purpose: choose and open the probe, attach, read and write memory; and flash
//! a firmware image, reset, detach (`fpc-sim link flash`).
//!
//! Attaching does not reset or halt the target (the firmware keeps controlling the
//! machine) unless `--connect-under-reset` asks for it. The control block is taken at the
//! ELF's `_SEGGER_RTT` when an ELF is given, otherwise searched for in the chip's RAM.

use std::io;
use std::path::Path;

use probe_rs::probe::list::Lister;
use probe_rs::probe::DebugProbeSelector;
use probe_rs::{MemoryInterface, Permissions, Session};

use super::memory::TargetMemory;
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

/// Opens the probe `opts` names and attaches to the chip.
fn session(opts: &ProbeOptions) -> Result<Session, String> {
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
    let chip = opts.chip.as_str();
    let attached = if opts.connect_under_reset {
        probe.attach_under_reset(chip, Permissions::default())
    } else {
        probe.attach(chip, Permissions::default())
    };
    attached.map_err(|e| format!("cannot attach to {chip} through the probe: {}", chain(&e)))
}

/// The board's memory through an attached probe (core 0's view).
pub struct ProbeMemory {
    session: Session,
}

impl TargetMemory for ProbeMemory {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> io::Result<()> {
        let mut core = self.session.core(0).map_err(other)?;
        core.read(address, buf).map_err(|e| other(chain(&e)))
    }

    fn write(&mut self, address: u64, bytes: &[u8]) -> io::Result<()> {
        let mut core = self.session.core(0).map_err(other)?;
        core.write(address, bytes).map_err(|e| other(chain(&e)))
    }

    /// One 32-bit access per word: the RTT offsets change while the firmware runs.
    fn read_words(&mut self, address: u64, words: &mut [u32]) -> io::Result<()> {
        let mut core = self.session.core(0).map_err(other)?;
        core.read_32(address, words).map_err(|e| other(chain(&e)))
    }

    fn write_word(&mut self, address: u64, word: u32) -> io::Result<()> {
        let mut core = self.session.core(0).map_err(other)?;
        core.write_word_32(address, word)
            .map_err(|e| other(chain(&e)))
    }
}

/// Attaches to the running board and to its RTT control block: at the address the ELF
/// `elf` names, if given, else found in the chip's RAM.
pub fn attach(opts: &ProbeOptions, elf: Option<&Path>) -> Result<RttChannels<ProbeMemory>, String> {
    let session = session(opts)?;
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
        None => Locate::Scan(
            session
                .target()
                .memory_map
                .iter()
                .filter_map(|region| match region {
                    probe_rs::config::MemoryRegion::Ram(r) => Some(r.range.clone()),
                    _ => None,
                })
                .collect(),
        ),
    };
    RttChannels::attach(ProbeMemory { session }, &locate)
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
