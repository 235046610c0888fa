//! The flash interface (RM0440 §5): what the firmware's calibration store and boot touch.
//!
//! - ACR (latency, caches), KEYR/CR lock sequence, SR flags (EOP, the error flags, BSY),
//!   ECCR (double-error detection: ECCD, the failing address, and the NMI it raises), and
//!   OPTR with its DBANK bit (dual-bank, 2 KiB pages, when 1; one bank of 4 KiB pages when 0).
//! - Programming: with PG set, two 32-bit writes to a double-word address program it; the
//!   flash can only clear bits, a double word already programmed may only be rewritten
//!   with zeros (else PROGERR), a misaligned or partial double word is PGAERR. Page erase:
//!   PER, PNB, BKER and STRT. Each takes the datasheet's time (82 µs per double word,
//!   22 ms per page erase, typical), with BSY set meanwhile and EOP (and the interrupt,
//!   with EOPIE) at the end.
//! - The calibration store's pages are emulated here (mapped as MMIO), so every read of them
//!   is checked against the ECC state: a double word left torn by a power cut reads as a
//!   double ECC error — ECCD set, the address latched, an NMI — as the hardware does.
//! - As RM0440's flash chapter states it (FLASH_KEYR, FLASH_SR, FLASH_CR; the program and
//!   erase sequences): a wrong KEYR sequence locks FLASH_CR until the next reset and is a
//!   bus error; a program or an erase started while an error flag of a previous operation
//!   is still set does not start and sets PGSERR; EOP is set only with EOPIE = 1 and OPERR
//!   only with ERRIE = 1; all zeros may be programmed over any double word (the way a torn
//!   one is repaired); a read of a bank while that bank is being programmed or erased
//!   stalls until the operation ends ([`Flash::stall_until`]).
//!
//! The manual's own text is not in this repository's references; what is modelled here was
//! written from RM0440 rev. 8 as the team read it, with the register fields of ST's SVD
//! (stm32-metapac 21: `flash_g4c3`), and is cited in each unit test.

use std::collections::BTreeSet;

use crate::time::UNITS_PER_US;

/// Base of the flash.
pub const FLASH_BASE: u32 = 0x0800_0000;
/// Size of the flash (STM32G474RE), bytes.
pub const FLASH_BYTES: u32 = 512 * 1024;
/// The calibration store's first byte (the last four 2 KiB pages of bank 2).
pub const STORE_BASE: u32 = 0x0807_E000;
/// The calibration store's size, bytes.
pub const STORE_BYTES: u32 = 8 * 1024;

/// Double-word programming time, µs (datasheet tPROG, typical).
const PROGRAM_US: u64 = 82;
/// Page erase time, µs (datasheet tERASE, typical).
const ERASE_US: u64 = 22_000;

/// SR bits.
mod sr {
    pub const EOP: u32 = 1 << 0;
    pub const OPERR: u32 = 1 << 1;
    pub const PROGERR: u32 = 1 << 3;
    pub const WRPERR: u32 = 1 << 4;
    pub const PGAERR: u32 = 1 << 5;
    pub const SIZERR: u32 = 1 << 6;
    pub const PGSERR: u32 = 1 << 7;
    pub const MISERR: u32 = 1 << 8;
    pub const FASTERR: u32 = 1 << 9;
    pub const BSY: u32 = 1 << 16;
    /// The flags of a previous operation that keep the next one from starting (PGSERR).
    pub const BLOCKING: u32 = PROGERR | WRPERR | PGAERR | SIZERR | PGSERR | MISERR | FASTERR;
    /// Bits cleared by writing 1.
    pub const W1C: u32 = 0xC3FB;
}

/// CR bits.
mod cr {
    pub const PG: u32 = 1 << 0;
    pub const PER: u32 = 1 << 1;
    pub const BKER: u32 = 1 << 11;
    pub const STRT: u32 = 1 << 16;
    pub const EOPIE: u32 = 1 << 24;
    pub const ERRIE: u32 = 1 << 25;
    pub const OPTLOCK: u32 = 1 << 30;
    pub const LOCK: u32 = 1 << 31;
}

/// OPTR.DBANK.
pub const OPTR_DBANK: u32 = 1 << 22;
/// OPTR as the factory programs it (RM0440 FLASH_OPTR reset value, DBANK = 1, BOR_LEV = 0).
pub const OPTR_FACTORY: u32 = 0xFFEF_F8AA;
/// OPTR.BOR_LEV (bits 10:8).
pub const OPTR_BOR_LEV: u32 = 7 << 8;
/// OPTR as `docs/bring-up.md`'s step 0 leaves it: the factory's with BOR_LEV = 2.
pub const OPTR_BRINGUP: u32 = (OPTR_FACTORY & !OPTR_BOR_LEV) | 2 << 8;

/// An operation in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Op {
    Program {
        at: u32,
        data: u64,
    },
    Erase {
        from: u32,
        len: u32,
    },
    /// A program whose effect is already applied (a torn one): it only takes its time.
    Settled {
        at: u32,
    },
}

/// Injected faults of the flash interface.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FlashFaults {
    /// Power is cut when this many program/erase steps have been *started* (the step that
    /// starts last is torn: half its double word programmed, or half its page erased, and
    /// the torn double words poisoned for ECC).
    pub cut_power_at_step: Option<u64>,
    /// The program step that makes this many steps since power-up ends with this SR error
    /// flag set, and does not program.
    pub error_on_program: Option<(u64, u32)>,
    /// The n-th page erase from now (1: the next) runs its time, then ends with OPERR (with
    /// ERRIE) and the page not erased.
    pub error_on_erase: Option<u64>,
    /// The n-th double-word program from now (1: the next) ends as if done (EOP) but leaves
    /// its double word half programmed and ECC-poisoned (a failing cell), the power on.
    pub tear_on_program: Option<u64>,
}

/// The flash interface.
#[derive(Clone, Debug)]
pub struct Flash {
    /// The store's bytes.
    pub store: Vec<u8>,
    /// Store double words (index) whose ECC is inconsistent: reading them is a double error.
    pub poisoned: BTreeSet<usize>,
    /// Store double words programmed since their last erase.
    programmed: Vec<bool>,
    /// ACR.
    pub acr: u32,
    cr: u32,
    sr: u32,
    eccr: u32,
    /// OPTR (DBANK is bit 22).
    pub optr: u32,
    key_step: u8,
    /// A wrong KEYR sequence locked FLASH_CR until the next reset.
    key_locked: bool,
    /// A register access the flash interface answered with a bus error (a wrong key), for
    /// the core to take as a precise data bus fault.
    pub bus_error: bool,
    /// The first word of a double word being programmed.
    half: Option<(u32, u32)>,
    op: Option<(Op, u64)>,
    /// The operation in progress fails at its end (an injected erase error).
    op_fails: bool,
    /// Steps started since power-up.
    pub steps: u64,
    /// Injected faults.
    pub faults: FlashFaults,
    /// The power was cut (by [`FlashFaults::cut_power_at_step`]).
    pub power_cut: bool,
    /// ACR values written by the CPU during program/erase (data-cache state), for the timing
    /// report.
    pub acr_during_ops: Vec<u32>,
    /// An NMI is requested (double ECC error).
    pub nmi: bool,
}

impl Flash {
    /// An erased store, factory option bytes.
    pub fn new() -> Self {
        Flash {
            store: vec![0xFF; STORE_BYTES as usize],
            poisoned: BTreeSet::new(),
            programmed: vec![false; STORE_BYTES as usize / 8],
            acr: 0x600,
            cr: cr::LOCK | cr::OPTLOCK,
            sr: 0,
            eccr: 0,
            optr: OPTR_FACTORY,
            key_step: 0,
            key_locked: false,
            bus_error: false,
            half: None,
            op: None,
            op_fails: false,
            steps: 0,
            faults: FlashFaults::default(),
            power_cut: false,
            acr_during_ops: Vec::new(),
            nmi: false,
        }
    }

    /// The store holding `image` (a flash image of the same size, e.g. `hal-sim`'s
    /// simulated flash after the firmware's store saved a record).
    pub fn load_image(&mut self, image: &[u8]) {
        let n = image.len().min(self.store.len());
        self.store[..n].copy_from_slice(&image[..n]);
        for (i, w) in self.store.chunks(8).enumerate() {
            self.programmed[i] = w.iter().any(|&b| b != 0xFF);
        }
    }

    /// After a reset: the registers to their reset values, the array as it stands.
    pub fn reset(&mut self) {
        self.acr = 0x600;
        self.cr = cr::LOCK | cr::OPTLOCK;
        self.sr = 0;
        self.eccr = 0;
        self.key_step = 0;
        self.key_locked = false;
        self.bus_error = false;
        self.half = None;
        self.op = None;
        self.op_fails = false;
        self.nmi = false;
    }

    fn dual_bank(&self) -> bool {
        self.optr & OPTR_DBANK != 0
    }

    /// The interrupt line (EOP with EOPIE, an error with ERRIE).
    pub fn irq(&self) -> bool {
        (self.sr & sr::EOP != 0 && self.cr & cr::EOPIE != 0)
            || (self.sr & (sr::OPERR | 0xF8) != 0 && self.cr & cr::ERRIE != 0)
    }

    /// When the operation in progress ends.
    pub fn next_event(&self) -> Option<u64> {
        self.op.map(|(_, at)| at)
    }

    /// Ends the operation in progress (its time has come).
    pub fn finish(&mut self) {
        let Some((op, _)) = self.op.take() else {
            return;
        };
        self.sr &= !sr::BSY;
        if std::mem::take(&mut self.op_fails) {
            // Unsuccessful: OPERR, only with ERRIE (FLASH_SR.OPERR); no EOP, nothing erased.
            if self.cr & cr::ERRIE != 0 {
                self.sr |= sr::OPERR;
            }
            return;
        }
        match op {
            Op::Program { at, data } => {
                if let Some(i) = store_index(at) {
                    let bytes = data.to_le_bytes();
                    for (k, b) in bytes.iter().enumerate() {
                        self.store[i * 8 + k] &= b;
                    }
                    self.programmed[i] = true;
                    self.poisoned.remove(&i);
                }
            }
            Op::Erase { from, len } => {
                for a in (from..from + len).step_by(8) {
                    if let Some(i) = store_index(a) {
                        self.store[i * 8..i * 8 + 8].fill(0xFF);
                        self.programmed[i] = false;
                        self.poisoned.remove(&i);
                    }
                }
            }
            Op::Settled { .. } => {}
        }
        // EOP is set only with the end-of-operation interrupt enabled (FLASH_SR.EOP).
        if self.cr & cr::EOPIE != 0 {
            self.sr |= sr::EOP;
        }
    }

    /// Starts a step, or tears it if the power is cut now. Returns false if it was torn.
    fn start(&mut self, op: Op, now: u64, duration_us: u64) -> bool {
        self.steps += 1;
        if self.faults.cut_power_at_step == Some(self.steps) {
            self.tear(op);
            self.power_cut = true;
            return false;
        }
        self.sr |= sr::BSY;
        self.op = Some((op, now + duration_us * UNITS_PER_US));
        self.acr_during_ops.push(self.acr);
        true
    }

    /// What an interrupted operation leaves: half the bits, and ECC that no longer matches.
    fn tear(&mut self, op: Op) {
        match op {
            Op::Program { at, data } => {
                if let Some(i) = store_index(at) {
                    let bytes = data.to_le_bytes();
                    for (k, b) in bytes.iter().enumerate().take(4) {
                        self.store[i * 8 + k] &= b;
                    }
                    self.poisoned.insert(i);
                }
            }
            Op::Settled { .. } => {}
            Op::Erase { from, len } => {
                for a in (from..from + len / 2).step_by(8) {
                    if let Some(i) = store_index(a) {
                        self.store[i * 8..i * 8 + 8].fill(0xFF);
                        self.programmed[i] = false;
                    }
                }
                // The word where the erase stopped is neither erased nor intact.
                if let Some(i) = store_index(from + len / 2) {
                    self.poisoned.insert(i);
                }
            }
        }
    }

    /// A CPU read of a register at offset `off`.
    pub fn read_reg(&self, off: u32) -> u32 {
        match off {
            0x00 => self.acr,
            0x10 => self.sr,
            0x14 => self.cr,
            0x18 => self.eccr,
            0x20 => self.optr,
            // PCROP/WRP option registers: factory values (no protection).
            0x24 | 0x44 => 0xFFFF_FFFF,
            0x28 | 0x48 => 0,
            0x2C | 0x30 | 0x4C | 0x50 => 0x00FF_0000 | 0xFF,
            _ => 0,
        }
    }

    /// A CPU write of a register.
    pub fn write_reg(&mut self, off: u32, value: u32, now: u64) {
        match off {
            0x00 => {
                self.acr = value & 0x0007_1F0F;
                if self.op.is_some() {
                    self.acr_during_ops.push(self.acr);
                }
            }
            0x08 => {
                if self.key_locked {
                    self.bus_error = true;
                    return;
                }
                self.key_step = match (self.key_step, value) {
                    (0, 0x4567_0123) => 1,
                    (1, 0xCDEF_89AB) => {
                        self.cr &= !cr::LOCK;
                        0
                    }
                    _ => {
                        // A wrong sequence locks FLASH_CR until the next reset and is a bus
                        // error (FLASH_KEYR).
                        self.cr |= cr::LOCK;
                        self.key_locked = true;
                        self.bus_error = true;
                        0
                    }
                };
            }
            0x10 => self.sr &= !(value & sr::W1C),
            0x14 => {
                if self.cr & cr::LOCK != 0 {
                    return;
                }
                self.cr = value & !cr::STRT;
                if value & cr::STRT != 0 && value & cr::PER != 0 {
                    self.start_erase(value, now);
                }
            }
            0x18 => {
                // ECCC/ECCD are cleared by writing 1.
                self.eccr &= !(value & 0xC000_0000);
                self.eccr = (self.eccr & 0xC000_0000) | (value & 0x0100_0000);
            }
            _ => {}
        }
    }

    fn start_erase(&mut self, cr_value: u32, now: u64) {
        if self.sr & (sr::BSY | sr::BLOCKING) != 0 {
            self.sr |= sr::PGSERR;
            return;
        }
        let pnb = (cr_value >> 3) & 0x7F;
        let (from, len) = if self.dual_bank() {
            let bank = if cr_value & cr::BKER != 0 {
                0x4_0000
            } else {
                0
            };
            (FLASH_BASE + bank + pnb * 2048, 2048)
        } else {
            // One bank of 4 KiB pages: BKER is not looked at (RM0440 FLASH_CR).
            (FLASH_BASE + pnb * 4096, 4096)
        };
        let fails = countdown(&mut self.faults.error_on_erase);
        if self.start(Op::Erase { from, len }, now, ERASE_US) && fails {
            self.op_fails = true;
        }
    }

    /// A CPU write into the flash array (programming), `at` the byte address.
    pub fn write_array(&mut self, at: u32, value: u32, size: usize, now: u64) {
        if self.cr & cr::PG == 0 || self.cr & cr::LOCK != 0 {
            self.sr |= sr::PGSERR;
            return;
        }
        if size != 4 || !at.is_multiple_of(4) {
            self.sr |= sr::PGAERR | sr::SIZERR;
            self.half = None;
            return;
        }
        match self.half.take() {
            None if at.is_multiple_of(8) => self.half = Some((at, value)),
            Some((first, low)) if at == first + 4 => {
                let data = u64::from(low) | u64::from(value) << 32;
                self.program(first, data, now);
            }
            _ => self.sr |= sr::PGAERR,
        }
    }

    fn program(&mut self, at: u32, data: u64, now: u64) {
        if self.sr & (sr::BSY | sr::BLOCKING) != 0 {
            // Busy, or the flags of a previous operation not cleared: PGSERR, no program.
            self.sr |= sr::PGSERR;
            return;
        }
        if let Some((step, flag)) = self.faults.error_on_program {
            if self.steps + 1 != step {
                return self.program_checked(at, data, now);
            }
            self.faults.error_on_program = None;
            self.steps += 1;
            // The operation ends at once with the error flag (as a write-protected or
            // sequence-error program does).
            self.sr |= flag;
            return;
        }
        self.program_checked(at, data, now)
    }

    fn program_checked(&mut self, at: u32, data: u64, now: u64) {
        match store_index(at) {
            Some(i) => {
                let old = self.store[i * 8..i * 8 + 8].iter().all(|&b| b == 0xFF);
                let erased = old && !self.programmed[i];
                if !erased && data != 0 {
                    // A double word not erased may only be written with zeros.
                    self.steps += 1;
                    self.sr |= sr::PROGERR;
                    return;
                }
                if countdown(&mut self.faults.tear_on_program) {
                    let started = self.start(Op::Program { at, data }, now, PROGRAM_US);
                    if started {
                        // Ends as done, but only half its bits landed and the ECC is wrong.
                        self.op = self.op.map(|(_, end)| (Op::Settled { at }, end));
                        self.tear(Op::Program { at, data });
                    }
                    return;
                }
                self.start(Op::Program { at, data }, now, PROGRAM_US);
            }
            // Outside the emulated store: the program area is never written.
            None => self.sr |= sr::WRPERR,
        }
    }

    /// A CPU read of the store at byte address `at`: the bytes, or a double ECC error
    /// (ECCD set, the address latched, NMI) on a poisoned double word.
    pub fn read_array(&mut self, at: u32, size: usize) -> u32 {
        let Some(i) = store_index(at) else {
            return 0xFFFF_FFFF;
        };
        if self.poisoned.contains(&i) {
            if self.eccr & (1 << 31) == 0 {
                let bank_offset = if self.dual_bank() {
                    (at - FLASH_BASE) % 0x4_0000
                } else {
                    at - FLASH_BASE
                };
                let bank2 = self.dual_bank() && at - FLASH_BASE >= 0x4_0000;
                self.eccr = (self.eccr & 0x0100_0000)
                    | (1 << 31)
                    | (u32::from(bank2) << 21)
                    | (bank_offset & 0x7_FFF8);
            }
            self.nmi = true;
        }
        let off = (at - STORE_BASE) as usize;
        let mut v = 0u32;
        for k in 0..size.min(4) {
            v |= u32::from(self.store.get(off + k).copied().unwrap_or(0xFF)) << (8 * k);
        }
        v
    }

    /// What a read of `at` returns once the operation in progress has ended: erased bytes
    /// where it erases, the programmed bits where it programs, else the array as it is.
    pub fn read_after_op(&mut self, at: u32, size: usize) -> u32 {
        let v = self.read_array(at, size);
        match self.op.map(|(op, _)| op) {
            Some(Op::Erase { from, len }) if (from..from + len).contains(&at) => {
                if size >= 4 {
                    u32::MAX
                } else {
                    (1 << (8 * size)) - 1
                }
            }
            Some(Op::Program { at: dw, data }) if at & !7 == dw => {
                let shift = 8 * (at - dw);
                v & (data >> shift) as u32
            }
            _ => v,
        }
    }

    /// Whether a program or an erase is in progress.
    pub fn busy(&self) -> bool {
        self.sr & sr::BSY != 0
    }

    /// A read of `at` while an operation runs in the same bank stalls until it ends: that
    /// instant (read-while-write only works across banks; in single-bank mode every
    /// operation stalls every read).
    pub fn stall_until(&self, at: u32) -> Option<u64> {
        let (op, end) = self.op?;
        let bank = |a: u32| {
            if self.dual_bank() {
                (a.wrapping_sub(FLASH_BASE) >= 0x4_0000) as u8
            } else {
                0
            }
        };
        let op_at = match op {
            Op::Program { at, .. } => at,
            Op::Erase { from, .. } => from,
            Op::Settled { at } => at,
        };
        (bank(op_at) == bank(at)).then_some(end)
    }
}

impl Default for Flash {
    fn default() -> Self {
        Flash::new()
    }
}

/// Counts an armed fault down by one step: true (and disarmed) when it reaches its step.
fn countdown(n: &mut Option<u64>) -> bool {
    match *n {
        Some(1) => {
            *n = None;
            true
        }
        Some(k) => {
            *n = Some(k.saturating_sub(1));
            false
        }
        None => false,
    }
}

/// Index of the store double word holding byte address `at`, if in the store.
fn store_index(at: u32) -> Option<usize> {
    (STORE_BASE..STORE_BASE + STORE_BYTES)
        .contains(&at)
        .then(|| ((at - STORE_BASE) / 8) as usize)
}

/// SR error flags an injected program error may raise, by name.
pub fn error_flag(name: &str) -> Option<u32> {
    Some(match name {
        "progerr" => sr::PROGERR,
        "wrperr" => sr::WRPERR,
        "pgaerr" => sr::PGAERR,
        "sizerr" => sr::SIZERR,
        "pgserr" => sr::PGSERR,
        "operr" => sr::OPERR,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unlocked() -> Flash {
        let mut f = Flash::new();
        f.write_reg(0x08, 0x4567_0123, 0);
        f.write_reg(0x08, 0xCDEF_89AB, 0);
        f
    }

    #[test]
    fn a_double_word_programs_once_and_takes_its_time() {
        let mut f = unlocked();
        f.write_reg(0x14, cr::PG, 0);
        f.write_array(STORE_BASE, 0x1122_3344, 4, 0);
        f.write_array(STORE_BASE + 4, 0x5566_7788, 4, 0);
        assert!(f.busy());
        assert_eq!(f.next_event(), Some(82 * UNITS_PER_US));
        f.finish();
        assert_eq!(f.read_array(STORE_BASE + 4, 4), 0x5566_7788);
        // Again, not zeros: PROGERR, nothing started.
        f.write_array(STORE_BASE, 1, 4, 0);
        f.write_array(STORE_BASE + 4, 1, 4, 0);
        assert_eq!(f.read_reg(0x10) & sr::PROGERR, sr::PROGERR);
        assert!(!f.busy());
    }

    #[test]
    fn the_erase_page_depends_on_dbank() {
        let mut f = unlocked();
        // Bank 2, page 124: the store's first page in dual-bank mode.
        f.write_reg(0x14, cr::PER | cr::BKER | (124 << 3) | cr::STRT, 0);
        assert_eq!(
            f.op.map(|(o, _)| o),
            Some(Op::Erase {
                from: STORE_BASE,
                len: 2048
            })
        );
        let mut g = unlocked();
        g.optr &= !OPTR_DBANK;
        g.write_reg(0x14, cr::PER | cr::BKER | (124 << 3) | cr::STRT, 0);
        assert_eq!(
            g.op.map(|(o, _)| o),
            Some(Op::Erase {
                from: 0x0807_C000,
                len: 4096
            })
        );
    }

    #[test]
    fn a_torn_program_reads_as_a_double_ecc_error() {
        let mut f = unlocked();
        f.faults.cut_power_at_step = Some(1);
        f.write_reg(0x14, cr::PG, 0);
        f.write_array(STORE_BASE + 16, 0, 4, 0);
        f.write_array(STORE_BASE + 20, 0, 4, 0);
        assert!(f.power_cut);
        f.reset();
        f.read_array(STORE_BASE + 16, 4);
        assert!(f.nmi);
        let eccr = f.read_reg(0x18);
        assert_eq!(eccr >> 31, 1);
        assert_eq!(eccr & 0x7_FFF8, 0x3_E010);
        assert_eq!(eccr >> 21 & 1, 1, "bank 2");
    }

    /// RM0440, FLASH_KEYR and "Unlocking the Flash memory": "Any wrong sequence will lock up
    /// the FLASH_CR register until the next system reset. In the case of a wrong key
    /// sequence, a bus error is detected and a Hard Fault interrupt is generated."
    #[test]
    fn a_wrong_key_sequence_locks_until_reset_and_is_a_bus_error() {
        let mut f = Flash::new();
        f.write_reg(0x08, 0xCDEF_89AB, 0);
        assert!(std::mem::take(&mut f.bus_error));
        // The right sequence now changes nothing: still locked, still a bus error.
        f.write_reg(0x08, 0x4567_0123, 0);
        f.write_reg(0x08, 0xCDEF_89AB, 0);
        assert!(f.bus_error);
        assert_ne!(f.read_reg(0x14) & cr::LOCK, 0);
        f.reset();
        f.write_reg(0x08, 0x4567_0123, 0);
        f.write_reg(0x08, 0xCDEF_89AB, 0);
        assert_eq!(f.read_reg(0x14) & cr::LOCK, 0);
        assert!(!f.bus_error);
    }

    /// RM0440, FLASH_SR.PGSERR: "Set also by hardware when PROGERR, SIZERR, PGAERR, WRPERR,
    /// MISSERR or FASTERR is set due to a previous programming error"; the program and erase
    /// sequences begin by checking and clearing those flags.
    #[test]
    fn a_program_or_erase_over_stale_error_flags_does_not_start() {
        let mut f = unlocked();
        f.sr |= sr::PROGERR;
        f.write_reg(0x14, cr::PG, 0);
        f.write_array(STORE_BASE, 0, 4, 0);
        f.write_array(STORE_BASE + 4, 0, 4, 0);
        assert!(!f.busy());
        assert_ne!(f.read_reg(0x10) & sr::PGSERR, 0);
        f.write_reg(0x14, cr::PER | cr::BKER | (124 << 3) | cr::STRT, 0);
        assert!(!f.busy(), "the erase started over PGSERR");
        // Cleared (write 1), the same program starts.
        f.write_reg(0x10, sr::W1C, 0);
        f.write_reg(0x14, cr::PG, 0);
        f.write_array(STORE_BASE, 0, 4, 0);
        f.write_array(STORE_BASE + 4, 0, 4, 0);
        assert!(f.busy());
    }

    /// RM0440, FLASH_SR.EOP: "This bit is set only if the end of operation interrupts are
    /// enabled (EOPIE = 1)"; FLASH_SR.OPERR: set when an operation completes unsuccessfully,
    /// "only if error interrupts are enabled (ERRIE = 1)".
    #[test]
    fn eop_and_operr_are_set_only_with_their_interrupts_enabled() {
        let mut f = unlocked();
        f.write_reg(0x14, cr::PG, 0);
        f.write_array(STORE_BASE, 0, 4, 0);
        f.write_array(STORE_BASE + 4, 0, 4, 0);
        f.finish();
        assert_eq!(f.read_reg(0x10) & sr::EOP, 0, "EOP without EOPIE");
        f.write_reg(0x14, cr::PG | cr::EOPIE, 0);
        f.write_array(STORE_BASE + 8, 0, 4, 0);
        f.write_array(STORE_BASE + 12, 0, 4, 0);
        f.finish();
        assert_ne!(f.read_reg(0x10) & sr::EOP, 0);
        for errie in [0, cr::ERRIE] {
            let mut g = unlocked();
            g.faults.error_on_erase = Some(1);
            g.write_reg(0x14, errie | cr::PER | cr::BKER | (124 << 3) | cr::STRT, 0);
            g.finish();
            assert_eq!(g.read_reg(0x10) & sr::OPERR != 0, errie != 0);
            assert_eq!(g.read_reg(0x10) & sr::EOP, 0);
            assert_eq!(g.store[0], 0xFF, "nothing was erased, nothing was there");
        }
    }

    /// RM0440, programming: a double word not erased may be programmed again only with all
    /// zeros (else PROGERR); the zeros' ECC is written with them, so a torn double word
    /// programmed to zero reads without an ECC error.
    #[test]
    fn zeros_programmed_over_a_torn_double_word_read_without_an_ecc_error() {
        let mut f = unlocked();
        f.faults.tear_on_program = Some(1);
        f.write_reg(0x14, cr::PG, 0);
        f.write_array(STORE_BASE + 16, 0x1234_5678, 4, 0);
        f.write_array(STORE_BASE + 20, 0x9ABC_DEF0, 4, 0);
        assert!(
            f.busy() && !f.power_cut,
            "a torn program still takes its time"
        );
        f.finish();
        f.read_array(STORE_BASE + 16, 4);
        assert!(std::mem::take(&mut f.nmi));
        f.write_reg(0x18, 1 << 31, 0);
        f.write_array(STORE_BASE + 16, 0, 4, 0);
        f.write_array(STORE_BASE + 20, 0, 4, 0);
        f.finish();
        assert_eq!(f.read_array(STORE_BASE + 16, 4), 0);
        assert!(!f.nmi);
    }

    /// RM0440, read-while-write: in dual-bank mode one bank is read while the other is
    /// programmed or erased; a read of the bank being erased waits for the erase's end.
    #[test]
    fn a_read_of_the_bank_being_erased_stalls_until_the_erase_ends() {
        let mut f = unlocked();
        f.store[8] = 0;
        f.programmed[1] = true;
        f.write_reg(0x14, cr::PER | cr::BKER | (124 << 3) | cr::STRT, 1000);
        let end = 1000 + ERASE_US * UNITS_PER_US;
        assert_eq!(f.stall_until(STORE_BASE + 8), Some(end));
        assert_eq!(f.read_after_op(STORE_BASE + 8, 4), u32::MAX);
        // Bank 1 (the program) reads on.
        assert_eq!(f.stall_until(FLASH_BASE + 0x100), None);
        // One bank (DBANK = 0): every read waits.
        f.optr &= !OPTR_DBANK;
        assert_eq!(f.stall_until(FLASH_BASE + 0x100), Some(end));
    }
}
