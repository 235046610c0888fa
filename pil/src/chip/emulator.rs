//! The emulator: unicorn's Cortex-M4 with the memory map of the STM32G474RE (flash, the
//! calibration store's pages, SRAM, CCM SRAM, system memory, the peripherals and the
//! private peripheral bus), booted, reset and powered as the chip is, and read and written
//! as a debug probe does.

use super::bus::{extract, merge};
use super::rcc::{RCC_CSR_IWDGRSTF, RCC_CSR_SFTRSTF};
use super::*;

/// The chip: the core and the [`Soc`].
pub struct Chip {
    /// The unicorn engine, whose user data is the [`Soc`].
    pub uc: Unicorn<'static, Soc>,
    image: Image,
}

/// An error of the emulation itself (not of the firmware).
#[derive(Debug)]
pub struct ChipError(pub String);

impl std::fmt::Display for ChipError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ChipError {}

fn uc_err(what: &str) -> impl Fn(unicorn_engine::uc_error) -> ChipError + '_ {
    move |e| ChipError(format!("unicorn: {what}: {e:?}"))
}

/// Program flash below the calibration store: erased (0xFF), then `image`'s flash segments;
/// read and execute only (a stray write is a bus fault). The store's pages are the flash
/// model's ([`map_store`]).
fn map_program_flash(uc: &mut Unicorn<'static, Soc>, image: &Image) -> Result<(), ChipError> {
    uc.mem_map(
        u64::from(FLASH_BASE),
        u64::from(STORE_BASE - FLASH_BASE),
        Prot::READ | Prot::EXEC,
    )
    .map_err(uc_err("map flash"))?;
    let erased = vec![0xFF; (STORE_BASE - FLASH_BASE) as usize];
    uc.mem_write(u64::from(FLASH_BASE), &erased)
        .map_err(uc_err("erase flash"))?;
    for (addr, bytes) in &image.segments {
        if *addr >= FLASH_BASE && *addr < FLASH_BASE + FLASH_BYTES {
            uc.mem_write(u64::from(*addr), bytes)
                .map_err(uc_err("load"))?;
        }
    }
    Ok(())
}

/// The calibration store's pages, through the flash model: a read of a bank being
/// programmed or erased stalls the core until the operation ends, a read with a double ECC
/// error raises the NMI before the next instruction, and a write whose program step meets an
/// injected power cut leaves the chip unpowered.
fn map_store(uc: &mut Unicorn<'static, Soc>) -> Result<(), ChipError> {
    uc.mmio_map(
        u64::from(STORE_BASE),
        u64::from(STORE_BYTES),
        Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize| {
            let soc = uc.get_data_mut();
            soc.store_reads += 1;
            let at = STORE_BASE + off as u32;
            if let Some(end) = soc.flash.stall_until(at) {
                // The read waits for the operation in its bank, then reads what it left.
                soc.stall_until = Some(end);
                let v = soc.flash.read_after_op(at, size);
                let _ = uc.emu_stop();
                return u64::from(v);
            }
            let v = soc.flash.read_array(at, size);
            if soc.flash.nmi {
                soc.update_irqs();
                let _ = uc.emu_stop();
            }
            u64::from(v)
        }),
        Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize, value: u64| {
            let soc = uc.get_data_mut();
            let now = soc.time;
            soc.flash
                .write_array(STORE_BASE + off as u32, value as u32, size, now);
            if soc.flash.power_cut {
                soc.powered = false;
                soc.plant_next = soc.time + 50 * UNITS_PER_US;
                let _ = uc.emu_stop();
            }
        }),
    )
    .map_err(uc_err("map store"))?;
    Ok(())
}

/// SRAM1 + SRAM2 and CCM SRAM (read, write, execute); system memory read only, with the
/// flash size register (RM0440 §47.2: 512 KiB).
fn map_ram_and_system_memory(uc: &mut Unicorn<'static, Soc>) -> Result<(), ChipError> {
    for (b, size) in [RAM, CCM] {
        uc.mem_map(u64::from(b), u64::from(size), Prot::ALL)
            .map_err(uc_err("map ram"))?;
    }
    uc.mem_map(
        u64::from(SYSMEM.0),
        u64::from(SYSMEM.1),
        Prot::READ | Prot::EXEC,
    )
    .map_err(uc_err("map system memory"))?;
    // The flash size register (RM0440 §47.2): 512 KiB.
    uc.mem_write(0x1FFF_75E0, &512u16.to_le_bytes())
        .map_err(uc_err("flash size"))?;
    Ok(())
}

/// The peripherals (APB1, APB2, AHB1, AHB2) through [`Soc::periph_read`] and
/// [`Soc::periph_write`], word by word: a byte or half-word write merges into the word.
fn map_peripherals(uc: &mut Unicorn<'static, Soc>) -> Result<(), ChipError> {
    uc.mmio_map(
        u64::from(PERIPH.0),
        u64::from(PERIPH.1),
        Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize| {
            let addr = PERIPH.0 + off as u32;
            let soc = uc.get_data_mut();
            soc.peripheral_access(addr);
            let word = soc.periph_read(addr & !3);
            u64::from(extract(word, addr, size))
        }),
        Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize, value: u64| {
            let addr = PERIPH.0 + off as u32;
            let soc = uc.get_data_mut();
            soc.peripheral_access(addr);
            let word = addr & !3;
            let merged = if size == 4 {
                value as u32
            } else {
                let old = soc.periph_read(word);
                merge(old, addr, size, value as u32)
            };
            // Flag registers written with a byte/half-word access still clear only what
            // they write: the models take the whole word.
            soc.periph_write(word, merged);
            cpu::after_write(uc);
        }),
    )
    .map_err(uc_err("map peripherals"))?;
    Ok(())
}

/// The private peripheral bus (NVIC, SCB, SysTick, DWT, DBGMCU) through [`Soc::ppb_read`]
/// and [`Soc::ppb_write`], a narrow write with its byte lanes' mask.
fn map_ppb(uc: &mut Unicorn<'static, Soc>) -> Result<(), ChipError> {
    uc.mmio_map(
        u64::from(PPB.0),
        u64::from(PPB.1),
        Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize| {
            let addr = PPB.0 + off as u32;
            let word = uc.get_data_mut().ppb_read(addr & !3);
            u64::from(extract(word, addr, size))
        }),
        Some(|uc: &mut Unicorn<Soc>, off: u64, size: usize, value: u64| {
            let addr = PPB.0 + off as u32;
            let shift = (addr & 3) * 8;
            let mask = if size >= 4 {
                !0
            } else {
                ((1u32 << (8 * size)) - 1) << shift
            };
            let v = (value as u32) << shift;
            uc.get_data_mut().ppb_write(addr, v, mask);
            cpu::after_write(uc);
        }),
    )
    .map_err(uc_err("map ppb"))?;
    Ok(())
}

/// The addresses the chip watches for: the `b .` a hung task is sent to, `main`, and
/// `fpc::tasks::control_cycle` (0 where the image has none).
fn place_spin_and_symbols(uc: &mut Unicorn<'static, Soc>, image: &Image) -> Result<(), ChipError> {
    // A `b .` in erased flash below the store, where a hung task is sent.
    let spin = STORE_BASE - 0x10;
    uc.mem_write(u64::from(spin), &[0xFE, 0xE7])
        .map_err(uc_err("spin"))?;
    uc.get_data_mut().spin_address = spin;
    uc.get_data_mut().main_address = image.symbol("main").unwrap_or(0) & !1;
    // The function itself (legacy mangling, any hash), not a long-branch thunk to it.
    uc.get_data_mut().control_cycle_address = image
        .symbols
        .iter()
        .find(|(n, _)| n.starts_with("_ZN3fpc5tasks13control_cycle17h"))
        .map_or(0, |(_, a)| *a & !1);
    Ok(())
}

impl Chip {
    /// A powered chip with `image` in its flash and `board` around it, held in reset (call
    /// [`Chip::power_on`]).
    pub fn new(image: Image, board: Board, options: ChipOptions) -> Result<Chip, ChipError> {
        let soc = Soc::new(&options, board);
        let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB | Mode::MCLASS, soc)
            .map_err(uc_err("new"))?;
        uc.ctl_set_cpu_model(unicorn_engine::ArmCpuModel::CORTEX_M4 as i32)
            .map_err(uc_err("cpu model"))?;
        map_program_flash(&mut uc, &image)?;
        map_store(&mut uc)?;
        map_ram_and_system_memory(&mut uc)?;
        map_peripherals(&mut uc)?;
        map_ppb(&mut uc)?;
        place_spin_and_symbols(&mut uc, &image)?;
        // A data read of program flash pays its wait states (instruction fetches are
        // counted per block, `load`).
        uc.add_mem_hook(
            unicorn_engine::HookType::MEM_READ,
            u64::from(FLASH_BASE),
            u64::from(STORE_BASE - 1),
            |uc, _kind, addr, size, _value| {
                uc.get_data_mut().flash_read(addr as u32, size as u32);
                true
            },
        )
        .map_err(uc_err("flash read hook"))?;
        cpu::install_hooks(&mut uc)?;
        Ok(Chip { uc, image })
    }

    /// The firmware image.
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// The peripherals' state.
    pub fn soc(&mut self) -> &mut Soc {
        self.uc.get_data_mut()
    }

    /// The peripherals' state (read only).
    pub fn soc_ref(&self) -> &Soc {
        self.uc.get_data()
    }

    /// Emulated time, s.
    pub fn time_s(&self) -> f64 {
        crate::time::seconds(self.uc.get_data().time)
    }

    /// Brings the core out of reset as the hardware does: MSP and PC from the vector table
    /// at 0x0800_0000 (BOOT0 low: flash aliased at 0), registers cleared.
    pub fn boot(&mut self) -> Result<(), ChipError> {
        let mut v = [0u8; 8];
        self.uc
            .mem_read(u64::from(FLASH_BASE), &mut v)
            .map_err(uc_err("vectors"))?;
        let sp = u32::from_le_bytes([v[0], v[1], v[2], v[3]]);
        let pc = u32::from_le_bytes([v[4], v[5], v[6], v[7]]);
        for r in [
            RegisterARM::R0,
            RegisterARM::R1,
            RegisterARM::R2,
            RegisterARM::R3,
            RegisterARM::R4,
            RegisterARM::R5,
            RegisterARM::R6,
            RegisterARM::R7,
            RegisterARM::R8,
            RegisterARM::R9,
            RegisterARM::R10,
            RegisterARM::R11,
            RegisterARM::R12,
        ] {
            self.uc.reg_write(r, 0).map_err(uc_err("reg"))?;
        }
        self.uc
            .reg_write(RegisterARM::PRIMASK, 0)
            .map_err(uc_err("primask"))?;
        self.uc
            .reg_write(RegisterARM::BASEPRI, 0)
            .map_err(uc_err("basepri"))?;
        self.uc
            .reg_write(RegisterARM::CONTROL, 0)
            .map_err(uc_err("control"))?;
        self.uc
            .reg_write(RegisterARM::IPSR, 0)
            .map_err(uc_err("ipsr"))?;
        self.uc
            .reg_write(RegisterARM::MSP, u64::from(sp))
            .map_err(uc_err("msp"))?;
        self.uc
            .reg_write(RegisterARM::SP, u64::from(sp))
            .map_err(uc_err("sp"))?;
        self.uc
            .reg_write(RegisterARM::LR, 0xFFFF_FFFF)
            .map_err(uc_err("lr"))?;
        self.uc
            .reg_write(RegisterARM::PC, u64::from(pc | 1))
            .map_err(uc_err("pc"))?;
        let soc = self.uc.get_data_mut();
        soc.ipsr = 0;
        soc.sleeping = false;
        soc.event = false;
        Ok(())
    }

    /// A system reset of `kind`: the peripherals to their reset values (RAM and flash kept),
    /// the reset flags set, and the core started from the reset vector.
    pub fn reset(&mut self, kind: ResetKind) -> Result<(), ChipError> {
        let soc = self.uc.get_data_mut();
        let at_s = crate::time::seconds(soc.time);
        soc.reset_peripherals();
        soc.csr_flags |= RCC_CSR_PINRSTF
            | match kind {
                ResetKind::PowerOn => RCC_CSR_BORRSTF,
                ResetKind::Watchdog => RCC_CSR_IWDGRSTF,
                ResetKind::Software => RCC_CSR_SFTRSTF,
            };
        soc.resets.push(ResetRecord { at_s, kind });
        soc.milestones.push((at_s, Milestone::Reset));
        soc.board.outputs_off();
        self.boot()
    }

    /// Cuts the supply: the core stops, the outputs go low, the plant runs on; the
    /// flash keeps what the cut left. [`Chip::power_on`] brings it back.
    pub fn power_off(&mut self) {
        let soc = self.uc.get_data_mut();
        soc.powered = false;
        soc.plant_next = soc.time + 50 * UNITS_PER_US;
        soc.board.outputs_off();
    }

    /// Power returns: RAM is lost (filled with a pattern, as SRAM powers up undefined), a
    /// power-on reset.
    pub fn power_on(&mut self) -> Result<(), ChipError> {
        let junk: Vec<u8> = (0..RAM.1)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        self.uc
            .mem_write(u64::from(RAM.0), &junk)
            .map_err(uc_err("ram"))?;
        // CCM SRAM too; as UDF instructions, so that code run from it before the firmware
        // copies its image there faults at once.
        self.uc
            .mem_write(u64::from(CCM.0), &vec![0xDE; CCM.1 as usize])
            .map_err(uc_err("ccm"))?;
        let soc = self.uc.get_data_mut();
        soc.powered = true;
        // The cut that tore a flash step is over: the next program is a program.
        soc.flash.power_cut = false;
        soc.csr_flags = 0;
        self.reset(ResetKind::PowerOn)
    }

    /// Runs the chip until the plant has advanced one PWM period (or one 50 µs step while
    /// the PWM is stopped).
    pub fn run_period(&mut self) -> Result<(), ChipError> {
        cpu::run_until_plant_step(self)
    }

    /// Reads target memory (as a debug probe does, without stopping anything).
    pub fn read_mem(&self, addr: u32, buf: &mut [u8]) -> Result<(), ChipError> {
        if (STORE_BASE..STORE_BASE + STORE_BYTES).contains(&addr) {
            let soc = self.uc.get_data();
            let off = (addr - STORE_BASE) as usize;
            for (i, b) in buf.iter_mut().enumerate() {
                *b = soc.flash.store.get(off + i).copied().unwrap_or(0xFF);
            }
            return Ok(());
        }
        self.uc
            .mem_read(u64::from(addr), buf)
            .map_err(uc_err("read"))
    }

    /// Writes target memory (as a debug probe does).
    pub fn write_mem(&mut self, addr: u32, bytes: &[u8]) -> Result<(), ChipError> {
        self.uc
            .mem_write(u64::from(addr), bytes)
            .map_err(uc_err("write"))
    }

    /// The program counter.
    pub fn pc(&self) -> u32 {
        self.uc.reg_read(RegisterARM::PC).unwrap_or(0) as u32
    }
}

/// The chip's memory as a debug probe sees it (reads and writes while the core runs), for
/// `hal-sim`'s RTT reader.
impl hal_sim::link::memory::TargetMemory for Chip {
    fn read(&mut self, address: u64, buf: &mut [u8]) -> std::io::Result<()> {
        let a = u32::try_from(address).map_err(std::io::Error::other)?;
        self.read_mem(a, buf)
            .map_err(|e| std::io::Error::other(e.0))
    }

    fn write(&mut self, address: u64, bytes: &[u8]) -> std::io::Result<()> {
        let a = u32::try_from(address).map_err(std::io::Error::other)?;
        self.write_mem(a, bytes)
            .map_err(|e| std::io::Error::other(e.0))
    }
}
