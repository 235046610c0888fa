//! The fault path: panic, HardFault, any unexpected interrupt and a failed boot check switch
//! the motor outputs off before anything else, then end in a reset.
//!
//! [`safe_outputs_off`] touches registers only (no driver, no lock, no allocation), so it is
//! callable from any context, including a fault inside the HAL. After it:
//! - panic: log the message over defmt, then `udf` → HardFault (a debugger running
//!   `probe-rs run` stops there and prints the backtrace);
//! - HardFault, and `DefaultHandler` (an interrupt enabled without a handler): outputs off
//!   again (it may be a fault of its own), log, then [`reset_after_log`];
//! - a boot check that fails ([`boot_fault`]): outputs off, log the [`BootCheck`], reset.
//!
//! Every path ends in a reset of its own, so a fault before the watchdog starts (clock or
//! ADC bring-up) cannot hang the board. Interrupts stay masked meanwhile, so nothing can
//! re-enable the outputs.
//!
//! The wait before that reset (1 ms by the cycle counter) reloads the IWDG all along: the
//! running window is ≈ 3 ms, so without it the watchdog would reset first and the next
//! boot would report a hung task (and brake as after one). The cause is also kept in an `.uninit` record
//! ([`FaultRecord`]), which RAM keeps across a reset, and logged by the next boot
//! ([`take_kept_cause`]): the defmt line of the fault itself is lost if no host reads it
//! within that millisecond.
//!
//! NMI: a double ECC error on a flash read (FLASH_ECCR.ECCD), what a power cut during a
//! program or an erase can leave. If the failing double word is in the calibration store,
//! that double word alone is programmed to zero before the reset (RM0440 allows programming
//! all zeros over any double word, programmed or not, and writes a matching ECC): the next
//! boot reads zeros there, which the storage crate's CRCs reject, so the item it was part of
//! is skipped and the previous record loads — instead of reading the same word again and
//! resetting for ever. Only if that program fails is the store erased (its pages only).
//!
//! Whether the next boot brakes is decided from the machine's state at the fault, not from
//! its kind: the handlers note whether a bridge's outputs were enabled (TIM1 or TIM8
//! BDTR.MOE) before switching them off. A flash ECC error met while the outputs were off
//! (at boot, at a standstill) reboots without braking; one met while they were on (a save's
//! read-back with the piston moving) brakes as after a hung task.
//!
//! `panic-probe` is not linked: it has no hook to run before its own logging.

use core::panic::PanicInfo;

use cortex_m::peripheral::SCB;
use cortex_m_rt::{exception, ExceptionFrame};
use embassy_stm32::pac;
use fpc::units::DacCode;

use super::clocks::SYSCLK_HZ;
use super::store_flash;
use super::watchdog::reload_watchdog;

/// A boot-time read-back that did not match: the board refuses to run. Stable numbers (they
/// are logged); each line tells the operator what to do.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum BootCheck {
    /// PWR_CR5 bit 8 (R1MODE) did not read back 0: the core is not in boost mode and must
    /// not run at 170 MHz. Check the PAC/embassy version against `docs/upstream-pwr-cr5-r1mode.md`.
    BoostMode = 1,
    /// An ADC's JSQR (injected sequence and trigger) did not read back as written: the
    /// injected queue was not disabled first, or the ADC was converting. Firmware bug.
    AdcJsqr = 2,
    /// An ADC's CFGR (regular trigger, JQDIS, overrun mode) did not read back as written.
    AdcCfgr = 3,
    /// ADC12_CCR (dual mode, DMA mode, clock prescaler) did not read back as written.
    Adc12Ccr = 4,
    /// FLASH_OPTR.DBANK is 0 (one bank of 4 KiB pages): the firmware is built for dual-bank
    /// mode (2 KiB pages), and the calibration store's erases would hit other pages. Set
    /// DBANK = 1 in the option bytes (STM32CubeProgrammer, "User Configuration").
    FlashBankLayout = 5,
    /// FLASH_OPTR.BOR_LEV is below 2 (≈ 2.2 V): with the factory's level 0 (≈ 1.7 V) the core
    /// runs on while VDD sags far below where the flash and the analog front end are
    /// specified. Set BOR_LEV = 2 or more in the option bytes (`docs/bring-up.md`, step 0).
    BrownOutLevel = 6,
}

/// Safe torque off: both bridges' gates low (TIM1/TIM8 MOE = 0 with OSSI = 1 forces every
/// output to its idle level, low), servo torque command to zero.
pub fn safe_outputs_off() {
    super::safe_pwm_off();
    pac::DAC1.dhr12r(0).write(|w| w.set_dhr(DacCode::MID.0));
}

/// A boot check failed: outputs off, log which, reset.
pub fn boot_fault(check: BootCheck) -> ! {
    cortex_m::interrupt::disable();
    safe_outputs_off();
    defmt::error!("boot check failed: {} ({=u8})", check, check as u8);
    reset_after_log()
}

/// Waits 1 ms (170,000 core clocks at 170 MHz; ≈ 10 ms at the 16 MHz boot clock) so an
/// attached host can read the last log, reloading the IWDG all the while so this reset, not
/// the watchdog's, ends the fault; then resets the MCU. Short on purpose: the outputs are
/// off and a piston at speed coasts until the next boot brakes it (measured in the
/// emulator, `fpc-pil fault fault-path`: with a 10 ms wait it reached the head), and the
/// cause survives the reset in [`FaultRecord`] anyway.
///
/// Timed by the core's cycle counter (DWT CYCCNT), not `cortex_m::asm::delay`: that is a
/// loop of at least one cycle per iteration, 3–5 on the M4 (a taken branch refills the
/// pipeline, and flash wait states add more), so `delay(170_000)` took 3–5 ms — longer
/// than the watchdog's 3 ms running window, which then reset first (the next boot
/// reporting a hung task), whatever the reload before it.
fn reset_after_log() -> ! {
    reload_watchdog();
    // SAFETY: the fault path owns the core: nothing else runs (interrupts masked, or a fault
    // handler that never returns); enabling the cycle counter has no other effect.
    let mut core = unsafe { cortex_m::Peripherals::steal() };
    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();
    let start = cortex_m::peripheral::DWT::cycle_count();
    while cortex_m::peripheral::DWT::cycle_count().wrapping_sub(start) < SYSCLK_HZ / 1000 {
        reload_watchdog();
    }
    SCB::sys_reset()
}

impl KeptCause {
    /// Whether the machine may have been moving when it happened: the next boot then brakes
    /// as after a watchdog reset. A flash ECC error says so itself (the outputs' state at
    /// the NMI); the other causes are taken as met while running (the safe side).
    pub fn while_running(&self) -> bool {
        match self {
            KeptCause::FlashEcc { outputs_on, .. } => *outputs_on,
            _ => true,
        }
    }
}

/// Whether either bridge's outputs are enabled now (TIM1 or TIM8 BDTR.MOE): read first thing
/// by the fault handlers, before [`safe_outputs_off`].
fn outputs_enabled() -> bool {
    pac::TIM1.bdtr().read().moe() || pac::TIM8.bdtr().read().moe()
}

/// Why the previous run ended, kept across the reset (RAM is not cleared by a reset, and
/// `.uninit` is not zeroed at boot).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum KeptCause {
    /// A panic at this source line (file and line as the panic reported them).
    Panic {
        /// Source file.
        file: &'static str,
        /// Line.
        line: u32,
    },
    /// A HardFault with the stacked PC.
    HardFault {
        /// Faulting instruction's address.
        pc: u32,
    },
    /// A double ECC error at this flash address.
    FlashEcc {
        /// The failing double word.
        address: u32,
        /// What was done to the calibration store about it.
        repair: StoreRepair,
        /// A bridge's outputs were enabled at the NMI (the piston may have been moving).
        outputs_on: bool,
    },
    /// An NMI that was not a flash ECC error.
    Nmi,
    /// An interrupt without a handler.
    Unexpected {
        /// Its IRQ number.
        irqn: i16,
    },
}

/// What the NMI handler did to the calibration store about a double ECC error.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum StoreRepair {
    /// The failing double word is outside the store: nothing to repair (program flash).
    NotInStore,
    /// The failing double word was programmed to zero: the previous record loads.
    Zeroed,
    /// Programming it to zero failed: the store was erased (calibration missing).
    Erased,
}

/// The record's layout: magic, kind, two words of detail.
#[repr(C)]
struct FaultRecord {
    magic: u32,
    kind: u32,
    a: u32,
    b: u32,
}

const RECORD_MAGIC: u32 = 0xFA17_5AFE;

#[link_section = ".uninit.FAULT_RECORD"]
static mut FAULT_RECORD: core::mem::MaybeUninit<FaultRecord> = core::mem::MaybeUninit::uninit();

fn keep(kind: u32, a: u32, b: u32) {
    // SAFETY: called with interrupts masked on the fault path only; the record is plain
    // words written with volatile stores to a static nothing else holds a reference to.
    unsafe {
        core::ptr::addr_of_mut!(FAULT_RECORD)
            .cast::<FaultRecord>()
            .write_volatile(FaultRecord {
                magic: RECORD_MAGIC ^ kind,
                kind,
                a,
                b,
            });
    }
}

/// The cause the previous run kept, if it ended on the fault path; the record is cleared.
/// Call once at boot, before anything can fault.
pub fn take_kept_cause() -> Option<KeptCause> {
    // SAFETY: the record is read as plain words (any bit pattern is a valid u32) before any
    // fault path can write it, then cleared; nothing else refers to it.
    let r = unsafe {
        let p = core::ptr::addr_of_mut!(FAULT_RECORD).cast::<FaultRecord>();
        let r = p.read_volatile();
        p.write_volatile(FaultRecord {
            magic: 0,
            kind: 0,
            a: 0,
            b: 0,
        });
        r
    };
    if r.magic != RECORD_MAGIC ^ r.kind {
        return None;
    }
    match r.kind {
        1 => {
            // The file name is a string in this image's flash: accept it only if it is.
            let (ptr, len) = (r.a, (r.b >> 20) as usize);
            let flash = 0x0800_0000..0x0808_0000u32;
            let file = if flash.contains(&ptr) && flash.contains(&(ptr + len as u32)) {
                // SAFETY: the range lies in flash, which holds this image's constants; the
                // bytes are checked to be UTF-8 below.
                let bytes = unsafe { core::slice::from_raw_parts(ptr as *const u8, len) };
                core::str::from_utf8(bytes).unwrap_or("?")
            } else {
                "?"
            };
            Some(KeptCause::Panic {
                file,
                line: r.b & 0xF_FFFF,
            })
        }
        2 => Some(KeptCause::HardFault { pc: r.a }),
        3 => Some(KeptCause::FlashEcc {
            address: r.a,
            repair: match r.b & 3 {
                1 => StoreRepair::Zeroed,
                2 => StoreRepair::Erased,
                _ => StoreRepair::NotInStore,
            },
            outputs_on: r.b & 4 != 0,
        }),
        4 => Some(KeptCause::Nmi),
        5 => Some(KeptCause::Unexpected { irqn: r.a as i16 }),
        _ => None,
    }
}

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    safe_outputs_off();
    // Location and static message only: formatting the message's arguments would link all
    // of core::fmt (float formatting alone is ~17 KiB of flash).
    let message = info.message().as_str().unwrap_or("(formatted message)");
    match info.location() {
        Some(l) => {
            let file = l.file();
            keep(
                1,
                file.as_ptr() as u32,
                (file.len().min(0xFFF) as u32) << 20 | l.line().min(0xF_FFFF),
            );
            defmt::error!("panic at {=str}:{=u32}: {=str}", file, l.line(), message)
        }
        None => {
            keep(1, 0, 0);
            defmt::error!("panic: {=str}", message)
        }
    }
    cortex_m::asm::udf()
}

// SAFETY: cortex-m-rt requires the HardFault handler to be an `unsafe fn`; this one only
// writes peripheral registers through the PAC, reads the stacked frame it is given and
// requests a system reset.
#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    safe_outputs_off();
    // A panic already kept its cause (its `udf` lands here): keep that one.
    // SAFETY: plain words of the record, read while nothing else runs.
    let kept_panic = unsafe {
        let r = core::ptr::addr_of!(FAULT_RECORD)
            .cast::<FaultRecord>()
            .read_volatile();
        r.kind == 1 && r.magic == RECORD_MAGIC ^ 1
    };
    if !kept_panic {
        keep(2, frame.pc(), 0);
    }
    defmt::error!("HardFault at pc {=u32:#010x}", frame.pc());
    reset_after_log()
}

/// FLASH_ECCR bits (RM0440, FLASH_ECCR): ECCD, BK_ECC, ADDR_ECC.
const ECCR_ECCD: u32 = 1 << 31;
const ECCR_BK_ECC: u32 = 1 << 21;
const ECCR_ADDR: u32 = 0x7_FFF8;

// SAFETY: cortex-m-rt requires exception handlers that take no frame to be plain or unsafe
// fns; this one reads and writes flash-interface registers through the PAC, programs the
// failing double word of the calibration store to zero (or erases the store), and resets.
#[exception]
unsafe fn NonMaskableInt() {
    cortex_m::interrupt::disable();
    let outputs_on = outputs_enabled();
    safe_outputs_off();
    let eccr = pac::FLASH.eccr().read().0;
    if eccr & ECCR_ECCD == 0 {
        keep(4, 0, 0);
        defmt::error!("NMI (not a flash ECC error)");
        reset_after_log()
    }
    let bank = if eccr & ECCR_BK_ECC != 0 { 0x4_0000 } else { 0 };
    let offset = bank + (eccr & ECCR_ADDR);
    let address = 0x0800_0000 + offset;
    // ECCD is cleared by writing 1 (the other bits written back unchanged).
    pac::FLASH.eccr().write_value(pac::flash::regs::Eccr(eccr));
    let repair = if !super::CALIBRATION_STORE.contains(&offset) {
        StoreRepair::NotInStore
    } else if store_flash::zero_double_word(address) {
        StoreRepair::Zeroed
    } else {
        store_flash::erase_calibration_store();
        StoreRepair::Erased
    };
    let code = match repair {
        StoreRepair::NotInStore => 0,
        StoreRepair::Zeroed => 1,
        StoreRepair::Erased => 2,
    };
    keep(3, address, code | u32::from(outputs_on) << 2);
    defmt::error!(
        "flash double ECC error at {=u32:#010x}: {}, outputs {=str}",
        address,
        repair,
        if outputs_on { "on" } else { "off" }
    );
    reset_after_log()
}

// SAFETY: cortex-m-rt requires `DefaultHandler` to be an `unsafe fn`. It runs for any
// exception or interrupt without a handler of its own (an interrupt enabled by mistake);
// it only writes peripheral registers, logs and requests a system reset.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    cortex_m::interrupt::disable();
    safe_outputs_off();
    keep(5, irqn as u32, 0);
    defmt::error!("unexpected exception or interrupt {=i16}", irqn);
    reset_after_log()
}
