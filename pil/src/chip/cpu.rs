//! The core's side of the chip: what unicorn 2 does not do for an M-profile CPU, done here
//! as the ARMv7-M architecture manual describes it.
//!
//! Measured on unicorn 2.1 (and visible in its source): there is no NVIC (its
//! `armv7m_nvic_*` functions are empty), `do_v7m_exception_exit` returns at once, WFE
//! raises an "invalid instruction" (EXCP_YIELD) with the PC past it, WFI halts the
//! emulation, SEV executes as a NOP, UDF is an invalid instruction with the PC on it. A
//! branch to an EXC_RETURN value in handler mode does raise EXCP_EXCEPTION_EXIT (8), which
//! reaches the interrupt hook. IPSR, CONTROL, PRIMASK, BASEPRI and the FP registers can be
//! read and written, and writing IPSR and then PC makes the translator see handler mode.
//! CONTROL.FPCA is set by the core when FP instructions run.
//!
//! So the chip does: exception entry (push the basic or, with FPCA, the extended frame with
//! 8-byte alignment, EXC_RETURN in LR, IPSR, vector fetch), exception return (pop, restore
//! xPSR, FPCA, the event register), tail-chaining (a pending exception that can be taken
//! on return is taken before thread code runs), WFE with its event register (set by SEV,
//! by exception return and by an interrupt pending), and HardFault entry for UDF and bus
//! errors (HFSR.FORCED, CFSR as the architecture sets it).
//!
//! Interrupts are taken between translated blocks: a block is at most a few instructions,
//! and a pending interrupt is checked before each block (with the masks as the core has
//! them), so the latency is at most one block, as QEMU's own M-profile does.

use std::collections::HashMap;

use unicorn_engine::{HookType, MemType, RegisterARM, Unicorn};

use super::flash::{FLASH_BASE, FLASH_BYTES};
use super::nvic::{self, HARD_FAULT};
use super::timing::{self, Block};
use super::{irqn, Chip, ChipError, Soc};

/// Why an emulation slice stopped early.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    /// A fault to take as HardFault: (CFSR bits, BFAR if valid).
    Fault(u32, Option<u32>),
}

/// The decoded translated blocks, by start address (with their size: a branch into the
/// middle of a block starts another one).
pub struct BlockCache {
    /// Flash blocks, indexed by half-word.
    flash: Vec<Option<(u32, Block)>>,
    other: HashMap<u32, (u32, Block)>,
}

impl BlockCache {
    /// Empty.
    pub fn new() -> Self {
        BlockCache {
            flash: vec![None; (FLASH_BYTES / 2) as usize],
            other: HashMap::new(),
        }
    }

    fn get(&self, addr: u32, size: u32) -> Option<Block> {
        let e = if (FLASH_BASE..FLASH_BASE + FLASH_BYTES).contains(&addr) {
            self.flash[((addr - FLASH_BASE) / 2) as usize]
        } else {
            self.other.get(&addr).copied()
        };
        e.filter(|(s, _)| *s == size).map(|(_, b)| b)
    }

    fn put(&mut self, addr: u32, size: u32, b: Block) {
        if (FLASH_BASE..FLASH_BASE + FLASH_BYTES).contains(&addr) {
            self.flash[((addr - FLASH_BASE) / 2) as usize] = Some((size, b));
        } else {
            self.other.insert(addr, (size, b));
        }
    }

    /// Forgets the blocks outside program flash (RAM code is copied at each boot).
    pub fn forget_ram(&mut self) {
        self.other.clear();
    }
}

impl Default for BlockCache {
    fn default() -> Self {
        BlockCache::new()
    }
}

/// The registers of the basic frame, in stacking order.
const FRAME: [RegisterARM; 7] = [
    RegisterARM::R0,
    RegisterARM::R1,
    RegisterARM::R2,
    RegisterARM::R3,
    RegisterARM::R12,
    RegisterARM::LR,
    RegisterARM::PC,
];

/// S0–S15, stacked in the extended frame.
const FP_FRAME: [RegisterARM; 16] = [
    RegisterARM::S0,
    RegisterARM::S1,
    RegisterARM::S2,
    RegisterARM::S3,
    RegisterARM::S4,
    RegisterARM::S5,
    RegisterARM::S6,
    RegisterARM::S7,
    RegisterARM::S8,
    RegisterARM::S9,
    RegisterARM::S10,
    RegisterARM::S11,
    RegisterARM::S12,
    RegisterARM::S13,
    RegisterARM::S14,
    RegisterARM::S15,
];

/// CONTROL.FPCA.
const FPCA: u64 = 4;

/// xPSR's T bit (EPSR).
const EPSR_T: u64 = 1 << 24;
/// xPSR's IT bits (ICI/IT, EPSR): 26:25 and 15:10.
const EPSR_IT: u32 = 0x0600_FC00;

fn err(what: &'static str) -> impl Fn(unicorn_engine::uc_error) -> ChipError {
    move |e| ChipError(format!("unicorn: {what}: {e:?}"))
}

fn reg(uc: &Unicorn<Soc>, r: RegisterARM) -> u32 {
    uc.reg_read(r).unwrap_or(0) as u32
}

/// The masks as the core has them now.
fn masks(uc: &Unicorn<Soc>) -> (bool, u8) {
    (
        reg(uc, RegisterARM::PRIMASK) & 1 != 0,
        reg(uc, RegisterARM::BASEPRI) as u8,
    )
}

/// The exception to take now, if any.
fn takeable_now(uc: &Unicorn<Soc>) -> Option<usize> {
    let (primask, basepri) = masks(uc);
    let soc = uc.get_data();
    soc.nvic
        .takeable(soc.nvic.execution_priority(primask, basepri))
}

/// Exception entry (ARMv7-M B1.5.6, PushStack and ExceptionTaken).
pub fn enter(uc: &mut Unicorn<Soc>, exc: usize) -> Result<(), ChipError> {
    let control = uc.reg_read(RegisterARM::CONTROL).map_err(err("control"))?;
    let in_handler = uc.get_data().ipsr != 0;
    if !in_handler && control & 2 != 0 {
        return Err(ChipError(
            "thread mode on the process stack (CONTROL.SPSEL): not modelled".into(),
        ));
    }
    let fpca = control & FPCA != 0;
    let sp = reg(uc, RegisterARM::SP);
    let size = if fpca { 0x68 } else { 0x20 };
    let mut frame = sp.wrapping_sub(size);
    let realign = frame & 4 != 0;
    if realign {
        frame -= 4;
    }
    let mut words = Vec::with_capacity(26);
    for r in FRAME {
        words.push(reg(uc, r));
    }
    let xpsr = reg(uc, RegisterARM::XPSR) | (u32::from(realign) << 9);
    words.push(xpsr);
    if fpca {
        for r in FP_FRAME {
            words.push(reg(uc, r));
        }
        words.push(reg(uc, RegisterARM::FPSCR));
        words.push(0);
    }
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    if !stack_writable(uc, frame, bytes.len() as u32)
        || uc.mem_write(u64::from(frame), &bytes).is_err()
    {
        // A bus error on stacking (BFSR.STKERR): its HardFault stacks below the same stack
        // pointer and fails again, a fault on HardFault entry: lockup.
        lockup(uc);
        return Ok(());
    }
    let mut exc_return: u32 = if in_handler { 0xFFFF_FFF1 } else { 0xFFFF_FFF9 };
    if fpca {
        exc_return &= !0x10;
    }
    // VTOR resets to 0, where the boot memory (main flash with BOOT0 low, SYSCFG_MEMRMP
    // at reset) is aliased.
    let vtor = match uc.get_data().nvic.vtor {
        v if v < FLASH_BYTES => FLASH_BASE + v,
        v => v,
    };
    let mut v = [0u8; 4];
    uc.mem_read(u64::from(vtor) + 4 * exc as u64, &mut v)
        .map_err(err("vector"))?;
    let vector = u32::from_le_bytes(v);
    uc.reg_write(RegisterARM::SP, u64::from(frame))
        .map_err(err("sp"))?;
    uc.reg_write(RegisterARM::LR, u64::from(exc_return))
        .map_err(err("lr"))?;
    uc.reg_write(RegisterARM::CONTROL, control & !FPCA)
        .map_err(err("control"))?;
    uc.reg_write(RegisterARM::IPSR, exc as u64)
        .map_err(err("ipsr"))?;
    // ExceptionTaken clears the IT state (ITSTATE is in the stacked xPSR): without this the
    // handler's first instructions ran under the interrupted IT block's condition (an
    // interrupt between two translated blocks of an IT block skipped the handler's PUSH and
    // its return popped a wrong PC).
    uc.reg_write(RegisterARM::EPSR, EPSR_T)
        .map_err(err("epsr"))?;
    uc.reg_write(RegisterARM::PC, u64::from(vector | 1))
        .map_err(err("pc"))?;
    let soc = uc.get_data_mut();
    soc.nvic.pending[exc] = false;
    soc.nvic.active[exc] = true;
    soc.ipsr = exc;
    soc.sleeping = false;
    soc.period.exceptions += 1;
    if !in_handler {
        soc.path_open = true;
        soc.path_entered();
    }
    soc.exception_entered(fpca, (FLASH_BASE..FLASH_BASE + FLASH_BYTES).contains(&vtor));
    if exc == nvic::irq(irqn::UART5) {
        soc.milestone(super::Milestone::ControlTask);
        // The control step of this plant cycle starts (it takes the commands posted so far).
        let cycle = soc.board.world.cycle();
        let watched = soc.watch_word;
        let value = watched.map_or(0, |a| {
            let mut w = [0u8; 4];
            let _ = uc.mem_read(u64::from(a), &mut w);
            u32::from_le_bytes(w)
        });
        uc.get_data_mut().control_entry = Some((cycle, value));
    }
    Ok(())
}

/// Exception return (ARMv7-M B1.5.8, ExceptionReturn and PopStack); `exc_return` the value
/// branched to.
fn exit(uc: &mut Unicorn<Soc>, exc_return: u32) -> Result<(), ChipError> {
    if exc_return & 4 != 0 {
        return Err(ChipError(
            "return to the process stack: not modelled".into(),
        ));
    }
    let fp = exc_return & 0x10 == 0;
    let sp = reg(uc, RegisterARM::SP);
    let words = if fp { 26 } else { 8 };
    let mut bytes = vec![0u8; 4 * words];
    uc.mem_read(u64::from(sp), &mut bytes)
        .map_err(err("unstacking"))?;
    let w: Vec<u32> = bytes
        .chunks(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    for (r, &v) in FRAME.iter().zip(&w).take(6) {
        uc.reg_write(*r, u64::from(v)).map_err(err("pop"))?;
    }
    let xpsr = w[7];
    if fp {
        for (r, &v) in FP_FRAME.iter().zip(&w[8..24]) {
            uc.reg_write(*r, u64::from(v)).map_err(err("pop s"))?;
        }
        uc.reg_write(RegisterARM::FPSCR, u64::from(w[24]))
            .map_err(err("fpscr"))?;
    }
    let new_sp = sp + 4 * words as u32 + if xpsr & (1 << 9) != 0 { 4 } else { 0 };
    uc.reg_write(RegisterARM::SP, u64::from(new_sp))
        .map_err(err("sp"))?;
    let control = uc.reg_read(RegisterARM::CONTROL).map_err(err("control"))?;
    let control = if fp { control | FPCA } else { control & !FPCA };
    uc.reg_write(RegisterARM::CONTROL, control)
        .map_err(err("control"))?;
    uc.reg_write(RegisterARM::XPSR_NZCVQG, u64::from(xpsr & !(1 << 9)))
        .map_err(err("xpsr"))?;
    // The interrupted IT block's state comes back with the xPSR (ARMv7-M B1.5.8).
    uc.reg_write(RegisterARM::EPSR, u64::from(xpsr & EPSR_IT) | EPSR_T)
        .map_err(err("epsr"))?;
    uc.reg_write(RegisterARM::PC, u64::from(w[6] | 1))
        .map_err(err("pc"))?;
    let soc = uc.get_data_mut();
    let returning = soc.ipsr;
    soc.nvic.active[returning] = false;
    if returning == nvic::irq(irqn::UART5) {
        soc.control_returned();
    }
    soc.ipsr = (xpsr & 0x1FF) as usize;
    soc.event = true;
    soc.exception_returned(fp);
    if soc.ipsr == 0 {
        soc.path_open = false;
    }
    // Level-sensitive lines still high pend their interrupt again.
    soc.update_irqs();
    Ok(())
}

/// After a peripheral write: stop at once for a reset; a pending interrupt is seen by the
/// next block's check.
pub fn after_write(uc: &mut Unicorn<Soc>) {
    let soc = uc.get_data_mut();
    if soc.reset_pending.is_some() || !soc.powered || soc.stop.is_some() {
        let _ = uc.emu_stop();
        return;
    }
    // A write can bring the next peripheral event forward (a counter started: TIM1's first
    // peak 25 µs after CEN, before the 50 µs plant step the run was aimed at). The run then
    // stops at that event, not past it: otherwise the event is handled late, when the counter
    // has already turned (the boot's check of TIM1's first update read DIR = up).
    soc.deadline = soc.deadline.min(soc.next_event());
}

/// Whether the pending exception of highest priority could pre-empt what runs now,
/// ignoring PRIMASK and BASEPRI (cheap: no register read).
fn could_preempt(soc: &Soc) -> bool {
    soc.nvic.any_pending() && soc.nvic.takeable(soc.nvic.active_priority()).is_some()
}

/// Installs the block, interrupt, invalid-instruction and bad-access hooks.
pub fn install_hooks(uc: &mut Unicorn<'static, Soc>) -> Result<(), ChipError> {
    uc.add_block_hook(1, 0, |uc, addr, size| {
        let addr = addr as u32;
        let block = match uc.get_data().blocks.get(addr, size) {
            Some(b) => b,
            None => {
                let mut bytes = vec![0u8; size as usize];
                let _ = uc.mem_read(u64::from(addr), &mut bytes);
                let b = timing::block(&bytes);
                uc.get_data_mut().blocks.put(addr, size, b);
                b
            }
        };
        let soc = uc.get_data_mut();
        if addr == soc.main_address {
            soc.milestone(super::Milestone::Main);
        }
        if addr == soc.control_cycle_address && addr != 0 {
            soc.milestone(super::Milestone::ControlCycle);
        }
        soc.fetched(addr, size);
        soc.execute(addr, size, &block);
        if soc.flash.busy() && (super::FLASH_BASE..super::STORE_BASE).contains(&addr) {
            if let Some(end) = soc.flash.stall_until(addr) {
                // Fetching from the bank being programmed or erased: stalled until it ends.
                soc.stall_until = Some(end);
                let _ = uc.emu_stop();
                return;
            }
        }
        if block.sev {
            soc.event = true;
        }
        let mut stop = soc.time >= soc.deadline;
        if (soc.hang_pending || soc.bus_fault_pending) && soc.ipsr == nvic::irq(irqn::UART5) {
            stop = true;
        }
        if !stop && could_preempt(uc.get_data()) && takeable_now(uc).is_some() {
            stop = true;
        }
        if stop {
            let _ = uc.emu_stop();
        }
    })
    .map_err(err("block hook"))?;
    uc.add_intr_hook(|uc, intno| {
        let pc = reg(uc, RegisterARM::PC);
        match intno {
            // EXCP_EXCEPTION_EXIT: PC holds the EXC_RETURN value (bit 0 cleared).
            8 if pc >= 0xFFFF_FF00 => {
                if let Err(e) = exit(uc, pc | 1) {
                    uc.get_data_mut().error = Some(e.0);
                    let _ = uc.emu_stop();
                    return;
                }
                if could_preempt(uc.get_data()) {
                    let _ = uc.emu_stop();
                }
            }
            _ => {
                // SVC, BKPT and the like: not used by the firmware; taken as a fault.
                uc.get_data_mut().stop = Some(Stop::Fault(1 << 16, None));
                let _ = uc.emu_stop();
            }
        }
    })
    .map_err(err("intr hook"))?;
    uc.add_insn_invalid_hook(|uc| {
        let pc = reg(uc, RegisterARM::PC);
        let mut hw = [0u8; 2];
        let at_pc = uc
            .mem_read(u64::from(pc), &mut hw)
            .map(|_| u16::from_le_bytes(hw))
            .unwrap_or(0);
        let udf = at_pc >> 8 == 0xDE || at_pc & 0xFFF0 == 0xF7F0;
        let before = uc
            .mem_read(u64::from(pc.wrapping_sub(2)), &mut hw)
            .map(|_| u16::from_le_bytes(hw))
            .unwrap_or(0);
        let soc = uc.get_data_mut();
        if !udf && before == 0xBF20 {
            // WFE: sleep unless the event register is set.
            if soc.event {
                soc.event = false;
            } else {
                soc.sleeping = true;
                let _ = uc.emu_stop();
            }
            return true;
        }
        // UDF or an undefined encoding: UsageFault UNDEFINSTR, escalated to HardFault.
        soc.stop = Some(Stop::Fault(1 << 16, None));
        let _ = uc.emu_stop();
        true
    })
    .map_err(err("invalid hook"))?;
    uc.add_mem_hook(
        HookType::MEM_UNMAPPED | HookType::MEM_PROT,
        1,
        0,
        |uc, kind, addr, _size, _value| {
            // A bus error: precise for data accesses (BFARVALID), instruction fetch otherwise.
            let cfsr = match kind {
                MemType::FETCH_UNMAPPED | MemType::FETCH_PROT => 1 << 8,
                _ => (1 << 9) | (1 << 15),
            };
            uc.get_data_mut().stop = Some(Stop::Fault(cfsr, Some(addr as u32)));
            false
        },
    )
    .map_err(err("mem hook"))?;
    Ok(())
}

/// Takes a HardFault for a fault the core raised (escalated: HFSR.FORCED).
fn fault(uc: &mut Unicorn<Soc>, cfsr: u32, bfar: Option<u32>) -> Result<(), ChipError> {
    let soc = uc.get_data_mut();
    if soc.nvic.active[HARD_FAULT] || soc.nvic.active[nvic::NMI] {
        // A fault in the HardFault or NMI handler: lockup (ARMv7-M B1.5.15).
        lockup(uc);
        return Ok(());
    }
    soc.nvic.cfsr |= cfsr;
    soc.nvic.hfsr |= 1 << 30;
    if let Some(a) = bfar {
        soc.nvic.bfar = a;
    }
    soc.faults_taken += 1;
    enter(uc, HARD_FAULT)
}

/// Whether the `len` bytes at `at` are RAM the core can stack into (SRAM or CCM SRAM).
fn stack_writable(uc: &Unicorn<Soc>, at: u32, len: u32) -> bool {
    let _ = uc;
    [super::RAM, super::CCM]
        .iter()
        .any(|&(b, n)| at >= b && at.wrapping_add(len) <= b + n)
}

/// The core locks up: it stops executing until a reset; with SYSCFG_CFGR2.CLL its LOCKUP
/// output is a system break on both bridge timers (their outputs off at once).
fn lockup(uc: &mut Unicorn<Soc>) {
    let soc = uc.get_data_mut();
    soc.locked_up = true;
    soc.lockups.push(crate::time::seconds(soc.time));
    if soc.comps.cfgr2 & 1 != 0 {
        soc.system_break();
    }
    let _ = uc.emu_stop();
}

/// The run loop: see [`Chip::run_period`].
pub fn run_until_plant_step(chip: &mut Chip) -> Result<(), ChipError> {
    {
        let soc = chip.uc.get_data_mut();
        if soc.held {
            soc.held = false;
            soc.release = true;
        }
    }
    loop {
        {
            let soc = chip.uc.get_data_mut();
            if let Some(e) = soc.error.take() {
                return Err(ChipError(e));
            }
            if !soc.powered {
                // No supply: nothing runs; the plant goes on with the outputs low.
                if soc.release {
                    soc.release = false;
                    soc.plant_next += 50 * crate::time::UNITS_PER_US;
                    soc.board.outputs_off();
                    soc.step_plant_unpowered();
                }
                soc.time = soc.time.max(soc.plant_next);
                soc.held = true;
                return Ok(());
            }
            soc.process_events();
        }
        flush_dma(chip)?;
        let soc = chip.uc.get_data_mut();
        if let Some(kind) = soc.reset_pending.take() {
            chip.reset(kind)?;
            continue;
        }
        soc.plant_stepped = false;
        if soc.held {
            return Ok(());
        }
        if soc.hang_pending && soc.ipsr == nvic::irq(irqn::UART5) {
            soc.hang_pending = false;
            let spin = soc.spin_address;
            chip.uc
                .reg_write(RegisterARM::PC, u64::from(spin | 1))
                .map_err(err("pc"))?;
        }
        let soc = chip.uc.get_data_mut();
        if soc.bus_fault_pending && soc.ipsr == nvic::irq(irqn::UART5) {
            // A precise bus error on a data access of the control executor (as a peripheral
            // that stops answering would give).
            soc.bus_fault_pending = false;
            fault(&mut chip.uc, (1 << 9) | (1 << 15), Some(0x4000_F000))?;
            continue;
        }
        if soc.halted() {
            // Halted by a debugger: no instruction runs; the peripherals not frozen go on.
            let until = soc.halt.map_or(soc.time, |h| h.until);
            soc.time = soc.next_event().min(until).max(soc.time);
            continue;
        }
        if soc.locked_up {
            // Nothing runs but the peripherals (the watchdog among them).
            soc.time = soc.time.max(soc.next_event());
            continue;
        }
        if let Some(end) = soc.stall_until {
            // Stalled on the flash: time runs on through the peripherals' events.
            if soc.time < end {
                soc.time = soc.next_event().min(end).max(soc.time);
                continue;
            }
            soc.stall_until = None;
        }
        if let Some(exc) = takeable_now(&chip.uc) {
            enter(&mut chip.uc, exc)?;
            continue;
        }
        let soc = chip.uc.get_data_mut();
        if soc.sleeping {
            if could_preempt(soc) {
                soc.sleeping = false;
                continue;
            }
            // Asleep: time jumps to the next peripheral event.
            soc.time = soc.time.max(soc.next_event());
            continue;
        }
        soc.deadline = soc.next_event();
        soc.stop = None;
        let pc = reg(&chip.uc, RegisterARM::PC);
        let result = chip.uc.emu_start(u64::from(pc | 1), 0, 0, 0);
        let stop = chip.uc.get_data_mut().stop.take();
        match (result, stop) {
            (_, Some(Stop::Fault(cfsr, bfar))) => fault(&mut chip.uc, cfsr, bfar)?,
            (Ok(()), None) => {}
            (Err(e), None) => {
                let soc = chip.uc.get_data();
                if !soc.powered || soc.reset_pending.is_some() {
                    continue;
                }
                return Err(ChipError(format!(
                    "unicorn stopped at pc {:#010x}: {e:?}",
                    reg(&chip.uc, RegisterARM::PC)
                )));
            }
        }
    }
}

/// The DMA's writes into RAM, made between blocks (the CPU sees them as it would after the
/// transfer).
fn flush_dma(chip: &mut Chip) -> Result<(), ChipError> {
    let writes = std::mem::take(&mut chip.uc.get_data_mut().board.dma_writes);
    for (at, word, bytes) in writes {
        let b = word.to_le_bytes();
        chip.uc
            .mem_write(u64::from(at), &b[..(bytes as usize).min(4)])
            .map_err(err("dma"))?;
    }
    Ok(())
}
