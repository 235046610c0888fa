//! The debug access port a probe reaches over SWD, as the chip implements it: the SW-DP and
//! the AHB-AP of the Cortex-M4 (ARM IHI 0031, ADIv5.2: §B2 the DP registers, §C2 the MEM-AP
//! registers; RM0440 §47.3–47.5, DP IDCODE 0x2BA0_1477; the Cortex-M4 TRM §C1, AHB-AP IDR),
//! and the core's debug registers behind it (ARMv7-M ARM §C1.6: DHCSR, DEMCR).
//!
//! A probe's transfer is one DP or AP register access; the MEM-AP's DRW and BD0–BD3 turn
//! into accesses on the system bus while the core runs: SRAM and flash from the emulated
//! memory; the private peripheral bus (SCB, DWT, DBGMCU) as the core sees it; DHCSR from
//! the model here. Every access to the core's debug registers
//! is recorded ([`DebugPort::touches`]): a link that never halts the core touches none. A
//! write of DHCSR with DBGKEY, C_DEBUGEN and C_HALT halts the core (with DBGMCU's freezes,
//! [`super::halt`]) until a write clears C_HALT.
//!
//! What the model leaves out: JTAG, the transaction counter and pushed compare/verify modes,
//! WAIT responses (every access completes at once), the 8- and 16-bit packed transfers, C_STEP
//! (a write without C_HALT resumes the core; a step would halt it again), the
//! ROM tables, the FPB and the ITM (they read as zero).

use super::{Chip, Soc};

/// DP IDCODE of the STM32G474 (RM0440 §47.8.3): DPv1, designer ARM.
pub const DPIDR: u32 = 0x2BA0_1477;
/// AHB-AP identification of the Cortex-M4 (TRM §C1.3): a MEM-AP on AHB-Lite, revision 2.
pub const AHB_AP_IDR: u32 = 0x2477_0011;
/// AHB-AP BASE: the ROM table at 0xE00F_F000, present, ADIv5 format.
pub const AHB_AP_BASE: u32 = 0xE00F_F003;
/// DHCSR (ARMv7-M ARM §C1.6.2).
pub const DHCSR: u32 = 0xE000_EDF0;
/// DEMCR (ARMv7-M ARM §C1.6.5).
pub const DEMCR: u32 = 0xE000_EDFC;
/// Program flash, and its size (the part's 512 KiB).
const FLASH_BASE: u32 = 0x0800_0000;
const FLASH_BYTES: u32 = 0x8_0000;
/// The private peripheral bus and DBGMCU, as the core sees them ([`super::ppb`]).
const PPB_START: u32 = 0xE000_0000;
const PPB_END: u32 = 0xE00F_FFFF;

/// DHCSR's write key, bits 31:16.
const DBGKEY: u32 = 0xA05F;
const C_DEBUGEN: u32 = 1;
const C_HALT: u32 = 1 << 1;
const S_REGRDY: u32 = 1 << 16;
const S_HALT: u32 = 1 << 17;

pub mod ctrl {
    //! CTRL/STAT bits (ADIv5.2 §B2.2.2).
    /// ORUNDETECT: overrun detection on.
    pub const ORUNDETECT: u32 = 1;
    /// STICKYORUN: an overrun was detected.
    pub const STICKYORUN: u32 = 1 << 1;
    /// STICKYCMP: a pushed compare matched.
    pub const STICKYCMP: u32 = 1 << 4;
    /// STICKYERR: an AP transaction failed.
    pub const STICKYERR: u32 = 1 << 5;
    /// WDATAERR: a write's data was corrupt.
    pub const WDATAERR: u32 = 1 << 7;
    /// CDBGPWRUPREQ: debug power requested (the ACKs, bits 29 and 31, follow the REQs one
    /// bit up).
    pub const CDBGPWRUPREQ: u32 = 1 << 28;
    /// CSYSPWRUPREQ: system power requested.
    pub const CSYSPWRUPREQ: u32 = 1 << 30;
}

/// A DP or AP register, as a probe addresses it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DapRegister {
    /// A DP register.
    Dp {
        /// A[3:2], as 0x0, 0x4, 0x8, 0xC.
        address: u8,
        /// The bank, where the probe names one.
        bank: Option<u8>,
    },
    /// A register of the AP that SELECT names: the low byte of its address.
    Ap(u8),
}

/// How a transfer failed, as the wire answers it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DapFault {
    /// FAULT: a sticky error is set (the access was not done).
    Fault,
}

/// An access of the probe to the core's debug registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Touch {
    /// When, emulated time units.
    pub at: u64,
    /// The register's address.
    pub address: u32,
    /// The value written; `None`: a read.
    pub written: Option<u32>,
}

/// The debug port's state.
#[derive(Clone, Debug, Default)]
pub struct DebugPort {
    select: u32,
    ctrl_stat: u32,
    csw: u32,
    tar: u32,
    /// DHCSR's control bits (C_*) as the debugger set them.
    dhcsr: u32,
    /// DEMCR as the debugger set it.
    pub demcr: u32,
    /// Every access to DHCSR or DEMCR, in order.
    pub touches: Vec<Touch>,
    /// DP and AP transfers served.
    pub transfers: u64,
    /// The transfer count when the probe halted the core, while it is halted.
    halted_at: Option<u64>,
}

/// CSW's writable bits: Size, AddrInc, Mode, Prot and DbgSwEnable.
const CSW_WRITABLE: u32 = 0xFF00_0F37;
/// CSW.DeviceEn, read as one: the AHB-AP always reaches the bus.
const CSW_DEVICE_EN: u32 = 1 << 6;

impl Chip {
    /// Serves one read of a DP or AP register.
    pub fn dap_read(&mut self, reg: DapRegister) -> Result<u32, DapFault> {
        self.soc().dap.transfers += 1;
        match reg {
            DapRegister::Dp { address, bank } => Ok(self.soc_ref().dap.dp_read(address, bank)),
            DapRegister::Ap(address) => {
                self.soc_ref().dap.ap_ready()?;
                if self.soc_ref().dap.select >> 24 != 0 {
                    // No AP but AP 0: an absent AP reads as zero.
                    return Ok(0);
                }
                match address {
                    0x00 => Ok(self.soc_ref().dap.csw | CSW_DEVICE_EN),
                    0x04 => Ok(self.soc_ref().dap.tar),
                    0x0C => {
                        let (addr, size) = (self.soc_ref().dap.tar, self.soc_ref().dap.size()?);
                        let v = self.bus_read(addr);
                        self.soc().dap.after_drw(v.is_ok(), size);
                        v
                    }
                    0x10..=0x1C => {
                        let addr = (self.soc_ref().dap.tar & !0xF) | u32::from(address & 0xC);
                        let v = self.bus_read(addr);
                        self.soc().dap.after_drw(v.is_ok(), 0);
                        v
                    }
                    0xF4 => Ok(0),
                    0xF8 => Ok(AHB_AP_BASE),
                    0xFC => Ok(AHB_AP_IDR),
                    _ => Ok(0),
                }
            }
        }
    }

    /// Serves one write of a DP or AP register.
    pub fn dap_write(&mut self, reg: DapRegister, value: u32) -> Result<(), DapFault> {
        self.soc().dap.transfers += 1;
        match reg {
            DapRegister::Dp { address, bank } => {
                self.soc().dap.dp_write(address, bank, value);
                Ok(())
            }
            DapRegister::Ap(address) => {
                self.soc_ref().dap.ap_ready()?;
                if self.soc_ref().dap.select >> 24 != 0 {
                    return Ok(());
                }
                match address {
                    0x00 => self.soc().dap.csw = value & CSW_WRITABLE,
                    0x04 => self.soc().dap.tar = value,
                    0x0C => {
                        let (addr, size) = (self.soc_ref().dap.tar, self.soc_ref().dap.size()?);
                        let done = self.bus_write(addr, size, value);
                        self.soc().dap.after_drw(done.is_ok(), size);
                        done?;
                    }
                    0x10..=0x1C => {
                        let addr = (self.soc_ref().dap.tar & !0xF) | u32::from(address & 0xC);
                        let done = self.bus_write(addr, 4, value);
                        self.soc().dap.after_drw(done.is_ok(), 0);
                        done?;
                    }
                    _ => {}
                }
                Ok(())
            }
        }
    }

    /// A read of the word holding `addr` on the system bus (its bytes in their lanes).
    fn bus_read(&mut self, addr: u32) -> Result<u32, DapFault> {
        let word = addr & !3;
        match word {
            DHCSR => {
                self.touch(word, None);
                let soc = self.soc_ref();
                let halted = if soc.halt.is_some() { S_HALT } else { 0 };
                Ok(soc.dap.dhcsr | halted | S_REGRDY)
            }
            DEMCR => {
                self.touch(word, None);
                Ok(self.soc().ppb_read(word))
            }
            PPB_START..=PPB_END => Ok(self.soc().ppb_read(word)),
            0xE010_0000..=u32::MAX => Err(DapFault::Fault),
            _ => {
                // The boot alias: flash at 0 (BOOT0 low, nBOOT1 set: RM0440 §2.6).
                let at = if word < FLASH_BYTES {
                    FLASH_BASE + word
                } else {
                    word
                };
                let mut b = [0u8; 4];
                self.read_mem(at, &mut b).map_err(|_| DapFault::Fault)?;
                Ok(u32::from_le_bytes(b))
            }
        }
    }

    /// A write of `size` bytes at `addr` on the system bus, taken from its byte lanes.
    fn bus_write(&mut self, addr: u32, size: u32, value: u32) -> Result<(), DapFault> {
        let word = addr & !3;
        let lane = addr & 3;
        let mask = match size {
            4 => u32::MAX,
            s => ((1u32 << (8 * s)) - 1) << (8 * lane),
        };
        match word {
            DHCSR => {
                self.touch(word, Some(value));
                if size == 4 && value >> 16 == DBGKEY {
                    self.dhcsr_write(value & 0xFFFF);
                }
                Ok(())
            }
            DEMCR => {
                self.touch(word, Some(value));
                self.soc().ppb_write(word, value, mask);
                Ok(())
            }
            PPB_START..=PPB_END => {
                self.soc().ppb_write(word, value, mask);
                Ok(())
            }
            0xE010_0000..=u32::MAX => Err(DapFault::Fault),
            _ => {
                let bytes = value.to_le_bytes();
                let from = lane as usize;
                let to = from + size as usize;
                let part = bytes.get(from..to).ok_or(DapFault::Fault)?;
                self.write_mem(addr, part).map_err(|_| DapFault::Fault)
            }
        }
    }

    fn touch(&mut self, address: u32, written: Option<u32>) {
        let at = self.soc_ref().time;
        self.soc().dap.touches.push(Touch {
            at,
            address,
            written,
        });
    }

    /// DHCSR's control bits written: C_HALT with C_DEBUGEN halts the core, clearing it
    /// resumes it.
    fn dhcsr_write(&mut self, c: u32) {
        let soc = self.soc();
        let before = soc.dap.dhcsr;
        soc.dap.dhcsr = c & 0x2F;
        let halt = c & C_DEBUGEN != 0 && c & C_HALT != 0;
        if halt && before & C_HALT == 0 && soc.halt.is_none() {
            soc.halt_for(OPEN_HALT);
            soc.dap.halted_at = Some(soc.dap.transfers);
        } else if !halt {
            if let Some(at) = soc.dap.halted_at.take() {
                // The halt lasted the transfers the probe made in it.
                soc.resume_after((soc.dap.transfers - at) * TRANSFER_UNITS);
            }
        }
    }
}

/// A halt a debugger holds until it resumes the core: an hour of emulated time.
const OPEN_HALT: u64 = 3_600 * crate::time::UNITS_PER_S;

/// One SWD transfer at a 4 MHz clock: 8 request bits, turnaround, 3 ACK bits, 33 data and
/// parity bits, turnaround and idle — 50 bit times, 12.5 µs. A lower bound of what a probe
/// takes (its USB round trips come on top): the time a core halted by the probe stays
/// halted while the transfers run is at least this per transfer.
const TRANSFER_UNITS: u64 = 25 * crate::time::UNITS_PER_US / 2;

impl DebugPort {
    fn dp_read(&self, address: u8, bank: Option<u8>) -> u32 {
        match (address, bank.unwrap_or((self.select & 0xF) as u8)) {
            (0x0, _) => DPIDR,
            (0x4, 0) => {
                let req = self.ctrl_stat & (ctrl::CDBGPWRUPREQ | ctrl::CSYSPWRUPREQ);
                // The power domains answer at once: each ACK follows its REQ.
                self.ctrl_stat | (req << 1)
            }
            // RESEND and RDBUFF: the last AP read's value is returned by the transfer
            // itself here (the probe's DAP layer resolves the posted reads).
            _ => 0,
        }
    }

    fn dp_write(&mut self, address: u8, bank: Option<u8>, value: u32) {
        match (address, bank.unwrap_or((self.select & 0xF) as u8)) {
            (0x0, _) => {
                // ABORT: STKCMPCLR, STKERRCLR, WDERRCLR, ORUNERRCLR clear their flags.
                let clear = [
                    (1 << 1, ctrl::STICKYCMP),
                    (1 << 2, ctrl::STICKYERR),
                    (1 << 3, ctrl::WDATAERR),
                    (1 << 4, ctrl::STICKYORUN),
                ];
                for (bit, flag) in clear {
                    if value & bit != 0 {
                        self.ctrl_stat &= !flag;
                    }
                }
            }
            (0x4, 0) => {
                let sticky = ctrl::STICKYCMP | ctrl::STICKYERR | ctrl::WDATAERR | ctrl::STICKYORUN;
                let writable = ctrl::CDBGPWRUPREQ | ctrl::CSYSPWRUPREQ | ctrl::ORUNDETECT;
                self.ctrl_stat = (self.ctrl_stat & sticky) | (value & writable);
            }
            (0x8, _) => self.select = value,
            _ => {}
        }
    }

    /// An AP access needs the debug domain powered and no sticky error.
    fn ap_ready(&self) -> Result<(), DapFault> {
        let powered = self.ctrl_stat & ctrl::CDBGPWRUPREQ != 0;
        if !powered || self.ctrl_stat & ctrl::STICKYERR != 0 {
            return Err(DapFault::Fault);
        }
        Ok(())
    }

    /// CSW.Size in bytes (8, 16, 32 bits).
    fn size(&self) -> Result<u32, DapFault> {
        match self.csw & 7 {
            0 => Ok(1),
            1 => Ok(2),
            2 => Ok(4),
            _ => Err(DapFault::Fault),
        }
    }

    /// After a DRW (`inc` bytes, 0 for BDn): an error is sticky; with AddrInc = single, TAR
    /// moves on within its 1 KiB block (ADIv5.2 §C2.2.2).
    fn after_drw(&mut self, ok: bool, inc: u32) {
        if !ok {
            self.ctrl_stat |= ctrl::STICKYERR;
            return;
        }
        if inc != 0 && self.csw >> 4 & 3 == 1 {
            self.tar = (self.tar & !0x3FF) | (self.tar.wrapping_add(inc) & 0x3FF);
        }
    }
}

impl Soc {
    /// The debugger resumes the core `units` from now, its halt cut short: the watchdog's
    /// countdown, which was pushed back by the halt's planned length, is pulled forward by
    /// what is left of it.
    pub fn resume_after(&mut self, units: u64) {
        let end = self.time + units;
        if let Some(h) = self.halt.as_mut() {
            if end < h.until {
                let left = h.until - end;
                h.until = end;
                if h.iwdg_frozen {
                    self.iwdg.advance(left);
                }
            }
        }
    }
}
