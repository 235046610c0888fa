//! The emulated board's debug port, as a host reaches it: [`EmulatedDap`] is the memory
//! access port (hal-sim's [`MemAccessPort`]) on the emulated chip — the bus as a debugger's
//! memory view sees it, the halting-debug registers counted (`chip::debug`) — so the host
//! link's own transport ([`hal_sim::link::debugport::NonHalting`]) runs on it unchanged.
//!
//! [`probe_rs_session_attach`] and [`probe_rs_session_detach`] replay what probe-rs 0.32's
//! `Session` does to an STM32G4 when it is created and dropped, read from its source
//! (`probe-rs/src/session.rs`: `Session::new` → `debug_device_unlock` → core attach →
//! `clear_all_hw_breakpoints` → `halted_access` (halt, clear the comparators, `run`);
//! `Drop` → the same, then `debug_core_stop`; `vendor/st/sequences/stm32_armv7.rs`: the
//! DBGMCU_CR set on attach and restored on detach, DHCSR and DEMCR left alone;
//! `architecture/arm/core/armv7m.rs`: `halt` writes DHCSR with C_HALT | C_DEBUGEN, `run`
//! single-steps, then clears C_HALT). They are the witness that the emulator catches a
//! transport that halts: the same capture through them stops the machine.

use std::io;

use hal_sim::link::debugport::MemAccessPort;

use crate::chip::debug::{addr, C_DEBUGEN, C_HALT, C_MASKINTS, C_STEP, DBGKEY};
use crate::chip::Chip;

/// The emulated chip behind its debug port.
pub struct EmulatedDap {
    /// The chip (stepped by whoever drives the scenario).
    pub chip: Chip,
    /// Words moved through the port.
    pub words: u64,
}

impl EmulatedDap {
    /// The debug port of `chip`.
    pub fn new(chip: Chip) -> Self {
        EmulatedDap { chip, words: 0 }
    }
}

fn err(e: crate::chip::ChipError) -> io::Error {
    io::Error::other(e.0)
}

impl MemAccessPort for EmulatedDap {
    fn attach(&mut self) -> io::Result<()> {
        Ok(())
    }

    fn read_words(&mut self, address: u32, words: &mut [u32]) -> io::Result<()> {
        for (i, w) in words.iter_mut().enumerate() {
            *w = self.chip.dap_read(address + 4 * i as u32).map_err(err)?;
            self.words += 1;
        }
        Ok(())
    }

    fn write_words(&mut self, address: u32, words: &[u32]) -> io::Result<()> {
        for (i, w) in words.iter().enumerate() {
            self.chip
                .dap_write(address + 4 * i as u32, *w)
                .map_err(err)?;
            self.words += 1;
        }
        Ok(())
    }

    fn detach(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// One round trip to the probe: the target runs on (period by period) for `round_trip_s`
/// while the host waits for the answer.
fn round_trip(dap: &mut EmulatedDap, round_trip_s: f64) -> Result<(), String> {
    let until = dap.chip.time_s() + round_trip_s;
    while dap.chip.time_s() < until {
        dap.chip.run_period().map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// The DBGMCU_CR bits probe-rs's STM32 sequence sets on attach (DBG_SLEEP, DBG_STOP,
/// DBG_STANDBY), and the value it saved.
const DBGMCU_CR: u32 = addr::DBGMCU + 4;

/// What probe-rs 0.32's `Session::new` does to a running STM32G4 through the debug port,
/// each read that needs its answer a round trip of `round_trip_s` (the core runs, or stays
/// halted, meanwhile). Returns the DBGMCU_CR value saved for the detach.
pub fn probe_rs_session_attach(dap: &mut EmulatedDap, round_trip_s: f64) -> Result<u32, String> {
    let io = |e: io::Error| e.to_string();
    // debug_device_unlock (Stm32Armv7): DBGMCU_CR |= DBG_SLEEP | DBG_STOP | DBG_STANDBY.
    let mut cr = [0u32];
    dap.read_words(DBGMCU_CR, &mut cr).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.write_words(DBGMCU_CR, &[cr[0] | 0b111]).map_err(io)?;
    // debug_core_start: C_DEBUGEN unless already set; Armv7m::new reads DHCSR, clears DFSR.
    let mut dhcsr = [0u32];
    dap.read_words(addr::DHCSR, &mut dhcsr).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    if dhcsr[0] & C_DEBUGEN == 0 {
        dap.write_words(addr::DHCSR, &[DBGKEY | C_DEBUGEN])
            .map_err(io)?;
    }
    dap.write_words(addr::DFSR, &[0x1F]).map_err(io)?;
    clear_breakpoints_halted(dap, round_trip_s)?;
    Ok(cr[0])
}

/// What dropping probe-rs 0.32's `Session` does: the breakpoints cleared again (halt, run),
/// then `debug_core_stop` (the STM32 sequence restores DBGMCU_CR; DHCSR and DEMCR stay).
pub fn probe_rs_session_detach(
    dap: &mut EmulatedDap,
    round_trip_s: f64,
    saved_cr: u32,
) -> Result<(), String> {
    clear_breakpoints_halted(dap, round_trip_s)?;
    dap.write_words(DBGMCU_CR, &[saved_cr])
        .map_err(|e| e.to_string())
}

/// `Session::clear_all_hw_breakpoints` → `halted_access`: halt the running core, wait for
/// S_HALT, read the PC, clear the comparators, then `run` (a single step, then C_HALT
/// cleared).
fn clear_breakpoints_halted(dap: &mut EmulatedDap, round_trip_s: f64) -> Result<(), String> {
    let io = |e: io::Error| e.to_string();
    let mut w = [0u32];
    // core_halted(): status() reads DHCSR.
    dap.read_words(addr::DHCSR, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.write_words(addr::DHCSR, &[DBGKEY | C_HALT | C_DEBUGEN])
        .map_err(io)?;
    // wait_for_core_halted: DHCSR (S_HALT), DFSR read and cleared.
    dap.read_words(addr::DHCSR, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.write_words(addr::DFSR, &[0x1F]).map_err(io)?;
    // read the PC: DCRSR = 15, S_REGRDY polled, DCRDR read.
    dap.write_words(addr::DCRSR, &[15]).map_err(io)?;
    dap.read_words(addr::DHCSR, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.read_words(addr::DCRDR, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    // FP_CTRL read (the comparators' count), each comparator written 0, the unit disabled.
    dap.read_words(addr::FP_CTRL, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.write_words(addr::FP_CTRL + 8, &[0; 6]).map_err(io)?;
    dap.write_words(addr::FP_CTRL, &[2]).map_err(io)?;
    // run(): step() first (C_STEP with C_MASKINTS, S_HALT awaited, PC read), then C_HALT
    // cleared. The step is modelled as the core staying halted (one instruction).
    dap.write_words(
        addr::DHCSR,
        &[DBGKEY | C_DEBUGEN | C_HALT | C_STEP | C_MASKINTS],
    )
    .map_err(io)?;
    dap.read_words(addr::DHCSR, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.write_words(addr::DCRSR, &[15]).map_err(io)?;
    dap.read_words(addr::DCRDR, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.read_words(addr::DHCSR, &mut w).map_err(io)?;
    round_trip(dap, round_trip_s)?;
    dap.write_words(addr::DHCSR, &[DBGKEY | C_DEBUGEN])
        .map_err(io)?;
    Ok(())
}
