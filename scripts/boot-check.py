#!/usr/bin/env python3
"""Boot check: runs the real firmware ELF from its reset vector in a Cortex-M4 emulator
(unicorn) against a small register model of the STM32G474, logs every peripheral write,
and checks the boot-time register values and their order.

    scripts/boot-check.py [ELF]              run and check (default: the `cargo fw` ELF)
    scripts/boot-check.py --self-test [ELF]  also alter each asserted write in turn and
                                             show that its check then fails
    scripts/boot-check.py --log [ELF]        print the whole write log

The model: reads return what was last written (or the reset value), except the status bits
the model owns (RCC ready bits mirror their enable bits, RCC_CFGR.SWS mirrors SW, ADCAL
self-clears, ADEN sets ADRDY, ADDIS clears ADEN, TIMx.SR.UIF and the centre-aligned DIR
bit once a counter runs, IWDG_SR busy bits read 0). Writing a peripheral's reset bit in
RCC_xxxRSTR restores that peripheral's reset values (this is what undoes a PWR_CR5 write
made before `embassy_stm32::init`). TIM1's counter enable starts TIM8 only if TIM8 is in
trigger mode on ITR0, as the hardware would. No interrupt is ever taken: the run ends when
the thread-mode executor first sleeps (WFE/WFI), i.e. once main has spawned every task and
each has run up to its first wait. A system reset request, a fault (UDF, an unmapped
access) or the step limit end the run early and fail the check.

Flash outside the program reads as erased (0xFF), as on a new board, so the calibration
store (the last four pages of bank 2) is empty: the boot must read it, log
`calibration_missing` with "Start refused until calibrated" (the defmt frames on RTT
up-channel 0 are decoded with the ELF's .defmt table) and neither unlock nor program nor
erase the flash. The self-test also boots with the store pages all zeros (no valid item):
that must be logged as `calibration_invalid`, not pass as an empty store.

The ELF is run a second time as a host that attached in "block if full" mode on a full
defmt channel and never reads: logging must not wait, the boot must still reach the idle
executor.

Exit status 0 only if every check passes (and, with --self-test, every mutation is caught).
"""

import argparse
import struct
import sys
from dataclasses import dataclass, replace

from elftools.elf.elffile import ELFFile
import json

from unicorn import (Uc, UcError, UC_ARCH_ARM, UC_MODE_MCLASS, UC_MODE_THUMB, UC_HOOK_CODE,
                     UC_HOOK_MEM_READ)
from unicorn.arm_const import (
    UC_ARM_REG_PC,
    UC_ARM_REG_SP,
    UC_ARM_REG_IPSR,
    UC_ARM_REG_LR,
    UC_CPU_ARM_CORTEX_M4,
)

DEFAULT_ELF = "target/thumbv7em-none-eabihf/release/fpc"
STEP_LIMIT = 20_000_000

# ---- memory map -------------------------------------------------------------------------
FLASH = (0x0800_0000, 512 * 1024)
RAM = (0x2000_0000, 128 * 1024)
CCM = (0x1000_0000, 32 * 1024)
SYSMEM = (0x1FFF_0000, 0x1_0000)  # system memory, UID, flash size: reads 0
# The calibration store: the last four 2 KiB pages of bank 2, cut from memory.x
# (src/board/mod.rs, CALIBRATION_STORE).
STORE = (0x0807_E000, 4 * 2048)
PERIPH = (0x4000_0000, 0x2000_0000)  # APB1/APB2/AHB1/AHB2 up to 0x5FFF_FFFF
PPB = (0xE000_0000, 0x10_0000)

# ---- peripheral addresses (RM0440) ------------------------------------------------------
TIM2, TIM4, TIM1, TIM8 = 0x4000_0000, 0x4000_0800, 0x4001_2C00, 0x4001_3400
IWDG = 0x4000_3000
PWR = 0x4000_7000
DMA1, DMAMUX1 = 0x4002_0000, 0x4002_0800
RCC = 0x4002_1000
FLASH_R = 0x4002_2000
GPIOA, GPIOB, GPIOC = 0x4800_0000, 0x4800_0400, 0x4800_0800
ADC1, ADC2, ADC12 = 0x5000_0000, 0x5000_0100, 0x5000_0300
DAC1 = 0x5000_0800
NVIC_ISER = 0xE000_E100
SCB_AIRCR = 0xE000_ED0C
DWT_CYCCNT = 0xE000_1004
SCB_CPUID = 0xE000_ED00
DBGMCU = 0xE004_2000

PERIPHERALS = [  # name, base, size
    ("TIM2", TIM2, 0x400), ("TIM4", TIM4, 0x400), ("IWDG", IWDG, 0x400), ("PWR", PWR, 0x400),
    ("SYSCFG", 0x4001_0000, 0x400), ("EXTI", 0x4001_0400, 0x400),
    ("TIM1", TIM1, 0x400), ("TIM8", TIM8, 0x400), ("DMA1", DMA1, 0x400),
    ("DMA2", 0x4002_0400, 0x400), ("DMAMUX1", DMAMUX1, 0x400), ("RCC", RCC, 0x400),
    ("FLASH", FLASH_R, 0x400), ("GPIOA", GPIOA, 0x400), ("GPIOB", GPIOB, 0x400),
    ("GPIOC", GPIOC, 0x400), ("GPIOD", 0x4800_0C00, 0x400), ("GPIOE", 0x4800_1000, 0x400),
    ("GPIOF", 0x4800_1400, 0x400), ("GPIOG", 0x4800_1800, 0x400),
    ("ADC1", ADC1, 0x100), ("ADC2", ADC2, 0x100), ("ADC12", ADC12, 0x100),
    ("DAC1", DAC1, 0x400), ("NVIC", 0xE000_E100, 0x400), ("NVIC_STIR", 0xE000_EF00, 4), ("SysTick", 0xE000_E010, 0x10),
    ("SCB", 0xE000_ED00, 0x100), ("DWT", 0xE000_1000, 0x1000), ("DBGMCU", DBGMCU, 0x100),
]


def peripheral_of(addr):
    for name, base, size in PERIPHERALS:
        if base <= addr < base + size:
            return name, addr - base
    return "?", addr


RESET_VALUES = {
    RCC + 0x00: 0x0000_0500,  # CR: HSION, HSIRDY
    RCC + 0x08: 0x0000_0005,  # CFGR: SW = SWS = HSI16
    RCC + 0x0C: 0x0000_1000,  # PLLCFGR
    RCC + 0x94: 0x0C00_0000,  # CSR: PINRSTF, BORRSTF (power-on)
    PWR + 0x00: 0x0000_0200,  # CR1: VOS range 1
    PWR + 0x08: 0x0000_8000,  # CR3
    PWR + 0x80: 0x0000_0100,  # CR5: R1MODE = 1 (range-1 normal mode)
    FLASH_R + 0x00: 0x0000_0600,
    # OPTR as bring-up step 0 leaves it: the factory's (DBANK = 1) with BOR_LEV = 2 (the boot
    # checks both).
    FLASH_R + 0x20: 0xFFEF_FAAA,
    GPIOA + 0x00: 0xABFF_FFFF,
    GPIOB + 0x00: 0xFFFF_FEBF,
    ADC1 + 0x08: 0x2000_0000,  # CR: DEEPPWD
    ADC2 + 0x08: 0x2000_0000,
    ADC1 + 0x0C: 0x8000_0000,  # CFGR: JQDIS
    ADC2 + 0x0C: 0x8000_0000,
    IWDG + 0x08: 0x0000_0FFF,
    SCB_CPUID: 0x410F_C241,
}
for _gpio in (GPIOC, 0x4800_0C00, 0x4800_1000, 0x4800_1400, 0x4800_1800):
    RESET_VALUES[_gpio] = 0xFFFF_FFFF
for _tim in (TIM1, TIM8, TIM4):
    RESET_VALUES[_tim + 0x2C] = 0xFFFF
RESET_VALUES[TIM2 + 0x2C] = 0xFFFF_FFFF

# RCC reset registers: (register offset, bit) -> peripheral (base, size)
RESET_BITS = {
    (0x28, 0): (DMA1, 0x400), (0x28, 2): (DMAMUX1, 0x400),
    (0x2C, 13): (ADC1, 0x400), (0x2C, 16): (DAC1, 0x400),
    (0x38, 0): (TIM2, 0x400), (0x38, 2): (TIM4, 0x400), (0x38, 28): (PWR, 0x400),
    (0x40, 11): (TIM1, 0x400), (0x40, 13): (TIM8, 0x400),
}


@dataclass(frozen=True)
class Write:
    seq: int
    pc: int
    addr: int  # word address
    value: int  # the whole word after the write (reads-back value)
    raw: int  # the value as the CPU wrote it (for KR-style write-only registers)


class Stop(Exception):
    pass


class Model:
    """Register file of the modelled peripherals; every write lands in `log`."""

    def __init__(self, inject=None):
        self.inject = inject
        self.regs = dict(RESET_VALUES)
        self.log = []
        self.iwdg_unlocked = False
        self.stop_reason = None
        self.cycles = 0  # DWT_CYCCNT

    def get(self, addr):
        return self.regs.get(addr, 0)

    def reset_block(self, base, size):
        for a in [a for a in self.regs if base <= a < base + size]:
            del self.regs[a]
        for a, v in RESET_VALUES.items():
            if base <= a < base + size:
                self.regs[a] = v

    # -- reads ---------------------------------------------------------------------------
    def read(self, addr, size):
        word = addr & ~3
        value = self.get(word)
        # Timers: once the counter runs, the first update comes at the peak (counting down).
        if word in (TIM1 + 0x10, TIM8 + 0x10, TIM4 + 0x10, TIM2 + 0x10):
            base = word - 0x10
            cr1 = self.get(base)
            if cr1 & 1:
                value |= 1
                self.regs[word] = value
                if (cr1 >> 5) & 3:
                    self.regs[base] = cr1 | 0x10
        if word == IWDG + 0x0C:
            value = 0
        # DWT's cycle counter runs: each read sees 64 cycles more (a short polling loop's
        # worth), so the fault path's 1 ms wait before its reset ends as on the chip.
        if word == DWT_CYCCNT:
            self.cycles = (self.cycles + 64) & 0xFFFF_FFFF
            value = self.cycles
        shift = (addr & 3) * 8
        return (value >> shift) & ((1 << (8 * size)) - 1)

    # -- writes --------------------------------------------------------------------------
    def write(self, pc, addr, size, data):
        word = addr & ~3
        shift = (addr & 3) * 8
        mask = ((1 << (8 * size)) - 1) << shift
        old = self.get(word)
        raw = (data << shift) & mask
        new = (old & ~mask) | raw
        new = self.side_effects(word, old, new, raw)
        self.regs[word] = new
        self.log.append(Write(len(self.log), pc, word, new, raw))
        if self.stop_reason:
            raise Stop(self.stop_reason)

    def side_effects(self, word, old, new, raw):
        # Injected hardware misbehaviour (--self-test): the firmware's own checks must catch it.
        if self.inject == "pwr-cr5-ignored" and word == PWR + 0x80:
            return (new & ~0x100) | (old & 0x100)
        if self.inject == "adc1-jsqr-dropped" and word == ADC1 + 0x4C:
            return old
        if word == RCC + 0x00:  # CR: ready bits follow their enables
            new &= ~((1 << 10) | (1 << 17) | (1 << 25))
            new |= ((new >> 8) & 1) << 10 | ((new >> 16) & 1) << 17 | ((new >> 24) & 1) << 25
        elif word == RCC + 0x08:  # CFGR: SWS follows SW
            new = (new & ~0xC) | ((new & 3) << 2)
        elif word in (RCC + 0x90, RCC + 0x94, RCC + 0x98):  # BDCR, CSR, CRRCR: xxxRDY = xxxON
            new = (new & ~2) | ((new & 1) << 1)
            if word == RCC + 0x94 and new & (1 << 23):  # RMVF clears the reset flags
                new &= 0x00FF_FFFF
        elif word - RCC in (0x28, 0x2C, 0x38, 0x40):
            for bit in range(32):
                block = RESET_BITS.get((word - RCC, bit))
                if block and (new >> bit) & 1:
                    self.reset_block(*block)
        elif word in (ADC1 + 0x08, ADC2 + 0x08):  # ADC_CR
            isr = word - 0x08
            if new & (1 << 31):  # ADCAL: calibration done at once
                new &= ~(1 << 31)
            if new & 2:  # ADDIS
                new &= ~3
            elif new & 1:
                self.regs[isr] = self.get(isr) | 1  # ADRDY
            if new & (1 << 4):  # ADSTP
                new &= ~((1 << 4) | (1 << 2))
            if new & (1 << 5):  # JADSTP
                new &= ~((1 << 5) | (1 << 3))
        elif word in (ADC1, ADC2):  # ADC_ISR: write 1 to clear
            new = old & ~raw
        elif word in (TIM1 + 0x10, TIM8 + 0x10, TIM4 + 0x10, TIM2 + 0x10):  # SR: rc_w0
            new = old & raw
        elif word in (TIM1 + 0x14, TIM8 + 0x14, TIM4 + 0x14, TIM2 + 0x14):  # EGR reads 0
            new = 0
        elif word in (TIM1, TIM8, TIM4, TIM2):  # CR1: DIR is read-only when centre-aligned
            if (new >> 5) & 3:
                new = (new & ~0x10) | (old & 0x10)
            if word == TIM1 and new & 1 and not old & 1:
                smcr = self.get(TIM8 + 0x08)
                sms = (smcr & 7) | ((smcr >> 16) & 1) << 3
                ts = ((smcr >> 4) & 7) | ((smcr >> 20) & 3) << 3
                started = self.inject != "tim8-not-triggered"
                if sms == 0b0110 and ts == 0 and started:  # trigger mode on ITR0 = TIM1 TRGO
                    self.regs[TIM8] = self.get(TIM8) | 1
        elif word == IWDG:  # KR
            key = raw & 0xFFFF
            self.iwdg_unlocked = key == 0x5555
            new = 0
        elif word in (IWDG + 0x04, IWDG + 0x08) and not self.iwdg_unlocked:
            new = old  # PR/RLR are write-protected until KR = 0x5555
        elif word == SCB_AIRCR and (raw >> 16) == 0x05FA and raw & 4:
            self.stop_reason = "system reset requested (SCB_AIRCR.SYSRESETREQ)"
        return new & 0xFFFF_FFFF


# ---- running the ELF --------------------------------------------------------------------
@dataclass
class Run:
    log: list
    steps: int
    end: str
    end_pc: int
    idle: bool
    symbols: dict
    rtt_write: int  # defmt up-channel write offset at the end (bytes logged, mod size)
    rtt_full: bool  # the host-blocking scenario was armed
    store_reads: set  # word addresses read in the calibration store
    defmt: list  # decoded defmt frames: (format string, frame bytes)


def load_elf(path):
    with open(path, "rb") as f:
        elf = ELFFile(f)
        segments = [
            (seg["p_paddr"], seg.data())
            for seg in elf.iter_segments()
            if seg["p_type"] == "PT_LOAD" and seg["p_filesz"] > 0
        ]
        symbols, objects, defmt = {}, {}, {}
        symtab = elf.get_section_by_name(".symtab")
        defmt_section = None
        for index, section in enumerate(elf.iter_sections()):
            if section.name == ".defmt":
                defmt_section = index
        if symtab:
            for sym in symtab.iter_symbols():
                if defmt_section is not None and sym["st_shndx"] == defmt_section:
                    try:
                        defmt[sym["st_value"]] = json.loads(sym.name)["data"]
                    except (ValueError, KeyError):
                        pass
                    continue
                if sym["st_info"]["type"] == "STT_FUNC" and sym["st_size"] > 0:
                    symbols[sym["st_value"] & ~1] = (sym.name, sym["st_size"])
                elif sym["st_info"]["type"] == "STT_OBJECT":
                    objects[sym.name] = sym["st_value"]
    return segments, symbols, objects, defmt


def symbol_at(symbols, pc):
    for start, (name, size) in symbols.items():
        if start <= pc < start + size:
            return name
    return "?"


def rzcobs_decode(frame):
    """One defmt frame (without its 0x00 separator) decoded from rzCOBS, read from its end
    (defmt's encoding/rzcobs.rs: 0xxxxxxx = seven bytes, bit set = a zero byte; 1nnnnnnn =
    n+7 bytes then a zero; 0xFF = 134 bytes). Trailing padding zeros may remain."""
    out, i = [], len(frame)
    while i > 0:
        i -= 1
        x = frame[i]
        if x == 0xFF:
            out.extend(reversed(frame[max(i - 134, 0):i]))
            i -= 134
        elif x & 0x80:
            n = (x & 0x7F) + 7
            out.append(0)
            out.extend(reversed(frame[max(i - n, 0):i]))
            i -= n
        else:
            for bit in range(6, -1, -1):
                if x & (1 << bit):
                    out.append(0)
                elif i > 0:
                    i -= 1
                    out.append(frame[i])
    return bytes(reversed(out))


def defmt_frames(data, table):
    """(format string, decoded frame) of each complete frame: a frame starts with its
    format string's index, u16 little-endian."""
    frames = []
    for raw in data.split(b"\x00")[1:-1]:
        if not raw:
            continue
        frame = rzcobs_decode(raw)
        if len(frame) >= 2:
            frames.append((table.get(int.from_bytes(frame[:2], "little"), "?"), frame))
    return frames


def run_elf(path, step_limit=STEP_LIMIT, inject=None):
    segments, symbols, objects, defmt_table = load_elf(path)
    rtt = objects.get("_SEGGER_RTT")
    mu = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    mu.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M4)  # has the FPU; no CPACR gate in unicorn
    for base, size in (FLASH, RAM, CCM, SYSMEM):
        mu.mem_map(base, size)
    # Flash outside the program is erased (0xFF), as on a new board: in particular the
    # calibration store's pages, which the boot reads.
    mu.mem_write(FLASH[0], b"\xff" * FLASH[1])
    if inject == "store-zeroed":
        mu.mem_write(STORE[0], b"\x00" * STORE[1])
    for addr, data in segments:
        mu.mem_write(addr, data)
    model = Model(inject)

    def on_read(uc, offset, size, base):
        return model.read(base + offset, size)

    def on_write(uc, offset, size, value, base):
        try:
            model.write(uc.reg_read(UC_ARM_REG_PC), base + offset, size, value)
        except Stop as stop:
            state["end"] = str(stop)
            uc.emu_stop()

    for base, size in (PERIPH, PPB):
        mu.mmio_map(base, size, on_read, base, on_write, base)

    # The event register: SEV sets it, a WFE with it set clears it and does not sleep (the
    # thread executor's pender is SEV, so a task spawned or woken during a poll is polled
    # before the executor really sleeps).
    state = {"steps": 0, "end": None, "idle": False, "event": False, "rtt_full": False}
    # Up-channel 0 (defmt) in the RTT control block: header 16 + 2 * 4 bytes, then
    # name, buffer, size, write, read, flags.
    up0 = rtt + 24 if rtt is not None else None

    def host_blocks_defmt(uc):
        """Act as a host that attached with `probe-rs run`: defmt channel in 'block if
        full' mode (flags = 2), and never reading, with the buffer full."""
        buffer, size, write = struct.unpack("<III", bytes(uc.mem_read(up0 + 4, 12)))
        if buffer and size:
            uc.mem_write(up0 + 16, struct.pack("<II", (write + 1) % size, 2))
            state["rtt_full"] = True

    def on_code(uc, address, size, _):
        state["steps"] += 1
        if inject == "defmt-host-blocking" and not state["rtt_full"] and state["steps"] % 64 == 0:
            host_blocks_defmt(uc)
        op = bytes(uc.mem_read(address, 2)) if size == 2 else b""
        # unicorn cannot execute SEV/WFE in M-class mode: skip them here, modelled.
        if op == b"\x40\xbf":  # SEV
            state["event"] = True
            uc.reg_write(UC_ARM_REG_PC, (address + 2) | 1)
        elif op == b"\x20\xbf" and state["event"]:  # WFE returns at once
            state["event"] = False
            uc.reg_write(UC_ARM_REG_PC, (address + 2) | 1)
        elif op in (b"\x20\xbf", b"\x30\xbf"):  # WFE, WFI: asleep
            if uc.reg_read(UC_ARM_REG_IPSR) & 0x1FF == 0:
                state["idle"] = True
                state["end"] = "thread-mode executor sleeps (WFE/WFI) at " + hex(address)
                uc.emu_stop()
        elif state["steps"] >= step_limit:
            state["end"] = f"step limit {step_limit} reached"
            uc.emu_stop()

    mu.hook_add(UC_HOOK_CODE, on_code)
    store_reads = set()

    def on_store_read(uc, access, address, size, value, _):
        store_reads.add(address & ~3)

    mu.hook_add(UC_HOOK_MEM_READ, on_store_read, None, STORE[0], STORE[0] + STORE[1] - 1)
    sp, reset = struct.unpack("<II", bytes(mu.mem_read(FLASH[0], 8)))
    mu.reg_write(UC_ARM_REG_SP, sp)
    mu.reg_write(UC_ARM_REG_LR, 0xFFFF_FFFF)
    try:
        mu.emu_start(reset | 1, 0xFFFF_FFFF)
    except UcError as err:
        state["end"] = f"emulation error: {err}"
    pc = mu.reg_read(UC_ARM_REG_PC)
    if state["end"] is None:
        state["end"] = "emulation stopped"
    rtt_write, frames = None, []
    if up0 is not None:
        buffer, size, rtt_write = struct.unpack("<III", bytes(mu.mem_read(up0 + 4, 12)))
        if buffer and not state["rtt_full"]:
            frames = defmt_frames(bytes(mu.mem_read(buffer, rtt_write)), defmt_table)
    return Run(model.log, state["steps"], state["end"], pc, state["idle"], symbols,
               rtt_write, state["rtt_full"], store_reads, frames)


def calibration_at_boot(run):
    """What the boot said about the stored calibration: the status name in its log line
    ('calibration loaded: …' or '… : Start refused until calibrated'), or None."""
    for text, frame in run.defmt:
        if "Start refused until calibrated" in text or text.startswith("calibration loaded"):
            for status in (b"calibration_missing", b"calibration_invalid",
                           b"calibration_incomplete", b"calibrated"):
                if status in frame:
                    return status.decode(), "Start refused" in text
    return None


def store_checks(run):
    """The calibration store at boot, on an erased board: read, found empty, not written."""
    pages = sorted({(a - STORE[0]) // 2048 for a in run.store_reads})
    said = calibration_at_boot(run)
    flash_ops = [w for w in run.log if w.addr in (FLASH_R + 0x08, FLASH_R + 0x14)]
    return [
        ("calibration store read at boot (erased pages)", len(pages) == STORE[1] // 2048,
         f"{len(run.store_reads)} words read, pages {pages}", []),
        ("no calibration stored: boot logs calibration_missing and refuses Start",
         said == ("calibration_missing", True), f"logged {said}", []),
        ("store not unlocked, programmed or erased at boot (FLASH_KEYR, FLASH_CR untouched)",
         not flash_ops, f"{len(flash_ops)} writes", []),
    ]


# ---- checks (pure functions of the write log) -------------------------------------------
class Log:
    """Replays a write log: last value of a register, ordered queries."""

    def __init__(self, writes):
        self.writes = writes

    def of(self, addr):
        return [w for w in self.writes if w.addr == addr]

    def last(self, addr):
        ws = self.of(addr)
        return ws[-1] if ws else None

    def value(self, addr):
        w = self.last(addr)
        return w.value if w else RESET_VALUES.get(addr, 0)

    def before(self, seq, addr):
        """Value of `addr` in force just before write `seq` (reset value if none)."""
        value, evidence = RESET_VALUES.get(addr, 0), None
        for w in self.writes:
            if w.seq >= seq:
                break
            if w.addr == addr:
                value, evidence = w.value, w
            if (w.addr - RCC) in (0x28, 0x2C, 0x38, 0x40):
                for (off, bit), (base, size) in RESET_BITS.items():
                    if w.addr - RCC == off and (w.value >> bit) & 1 and base <= addr < base + size:
                        value, evidence = RESET_VALUES.get(addr, 0), w
        return value, evidence


def field(value, lsb, width):
    return (value >> lsb) & ((1 << width) - 1)


def fmt_ev(ws):
    return ", ".join(f"#{w.seq}" for w in ws if w is not None) or "none"


def check_value(name, addr, mask, expect_fn, describe):
    """A check on the final value of one register; `mask` is the asserted field (the bits
    the self-test flips in the last write)."""

    def check(log):
        v = log.value(addr)
        return expect_fn(v), f"{describe(v)}", [(log.last(addr), mask)]

    return name, check


def checks():
    c = []
    c.append(check_value("TIM1 ARR = 4250", TIM1 + 0x2C, 0xFFFF, lambda v: v == 4250, lambda v: f"ARR {v}"))
    c.append(check_value("TIM1 centre-aligned (CR1.CMS != 0)", TIM1, 0x60, lambda v: field(v, 5, 2) != 0,
                         lambda v: f"CMS {field(v, 5, 2)}"))
    c.append(check_value("TIM1 RCR = 1", TIM1 + 0x30, 0xFFFF, lambda v: v & 0xFFFF == 1, lambda v: f"RCR {v}"))
    c.append(check_value("TIM1 CCR4 = 4249", TIM1 + 0x40, 0xFFFF, lambda v: v == 4249, lambda v: f"CCR4 {v}"))
    c.append(check_value(
        "TIM1 CH4 PWM mode 2 (CCMR2.OC4M = 0111)", TIM1 + 0x1C, 0x0100_7000,
        lambda v: (field(v, 12, 3) | field(v, 24, 1) << 3) == 0b0111,
        lambda v: f"OC4M {field(v, 12, 3) | field(v, 24, 1) << 3:04b}"))
    c.append(check_value("TIM1 MMS2 = OC4REF (CR2.MMS2 = 7)", TIM1 + 0x04, 0x00F0_0000,
                         lambda v: field(v, 20, 4) == 7, lambda v: f"MMS2 {field(v, 20, 4)}"))
    for tim, name in ((TIM1, "TIM1"), (TIM8, "TIM8")):
        # docs/firmware.md, "The hardware over-current trip" and "Locks".
        c.append(check_value(f"{name} BDTR = 0x33F55 (DTG 85 = 500 ns, LOCK 3, OSSI, OSSR, BKE, "
                             "BKP high, BKF 3 = 47 ns, AOE 0, MOE 0, break 2 off)",
                             tim + 0x44, 0x3FFF_FFFF, lambda v: v == 0x0003_3F55,
                             lambda v: f"BDTR {v:#07x}"))
        c.append(check_value(f"{name} CCER = 0x555 (CH1-3 and CH1N-3N enabled)", tim + 0x20, 0x0FFF,
                             lambda v: v & 0xFFFF == 0x555, lambda v: f"CCER {v:#05x}"))

    def tim8_trigger(log):
        v = log.value(TIM8 + 0x08)
        sms = field(v, 0, 3) | field(v, 16, 1) << 3
        ts = field(v, 4, 3) | field(v, 20, 2) << 3
        return sms == 0b0110 and ts == 0, f"SMS {sms:04b} TS {ts}", [(log.last(TIM8 + 0x08), 0x0031_0077)]

    c.append(("TIM8 trigger mode from ITR0 (TIM1 TRGO)", tim8_trigger))
    c.append(check_value("ADC12 CCR = 0x0008A001", ADC12 + 0x08, 0x003F_E01F, lambda v: v == 0x0008_A001,
                         lambda v: f"CCR {v:#010x}"))

    def adc1_triggers(log):
        cfgr, jsqr = log.value(ADC1 + 0x0C), log.value(ADC1 + 0x4C)
        ok = field(cfgr, 5, 5) == 10 and field(cfgr, 10, 2) == 1
        ok &= field(jsqr, 2, 5) == 8 and field(jsqr, 7, 2) == 1
        return ok, (f"EXTSEL {field(cfgr, 5, 5)} EXTEN {field(cfgr, 10, 2)}, "
                    f"JEXTSEL {field(jsqr, 2, 5)} JEXTEN {field(jsqr, 7, 2)}"), \
            [(log.last(ADC1 + 0x0C), 0x0FE0), (log.last(ADC1 + 0x4C), 0x01FC)]

    c.append(("ADC1 triggers: TIM1_TRGO2 regular code 10 / injected code 8, rising", adc1_triggers))
    c.append(check_value("DMAMUX1 channel 0 request 5 (ADC1)", DMAMUX1, 0x7F, lambda v: field(v, 0, 7) == 5,
                         lambda v: f"DMAREQ_ID {field(v, 0, 7)}"))

    def iwdg(log):
        starts = [w for w in log.writes if w.addr == IWDG and w.raw & 0xFFFF == 0xCCCC]
        if not starts:
            return False, "never started", []
        pr, pr_w = log.before(starts[0].seq, IWDG + 0x04)
        rlr, rlr_w = log.before(starts[0].seq, IWDG + 0x08)
        later = [w.value for w in log.of(IWDG + 0x08) if w.seq > starts[0].seq]
        ok = pr == 0 and rlr == 159 and all(v in (159, 23) for v in later)
        return ok, f"PR {pr} (/4), RLR {rlr} at start, later RLR {later}", [(pr_w, 7), (rlr_w, 0xFFF)]

    c.append(("IWDG /4, reload 159 at start (20 ms), 159 or 23 after", iwdg))
    c.append(check_value("DAC1 high-frequency mode (MCR.HFSEL = 10, AHB > 160 MHz)", DAC1 + 0x3C, 0xC000,
                         lambda v: field(v, 14, 2) == 0b10, lambda v: f"HFSEL {field(v, 14, 2):02b}"))

    def boost(log):
        cr5 = log.value(PWR + 0x80)
        # Bit 8 must be clear when SYSCLK is switched to the PLL (CFGR.SW = 11).
        switches = [w for w in log.of(RCC + 0x08) if w.value & 3 == 3]
        if not switches:
            return False, "SYSCLK never switched to the PLL", []
        at_switch, ev = log.before(switches[0].seq, PWR + 0x80)
        ok = not cr5 & 0x100 and not at_switch & 0x100
        return ok, f"PWR_CR5 {at_switch:#x} at the PLL switch (#{switches[0].seq}), {cr5:#x} at the end", \
            [(ev, 0x100), (log.last(PWR + 0x80), 0x100)]

    c.append(("boost: PWR_CR5 bit 8 clear before and after the switch to 170 MHz", boost))

    def jqdis(log):
        ev, detail, ok = [], [], True
        for adc, name in ((ADC1, "ADC1"), (ADC2, "ADC2")):
            jsqrs = log.of(adc + 0x4C)
            if not jsqrs:
                return False, f"{name} JSQR never written", []
            for w in jsqrs:
                cfgr, cw = log.before(w.seq, adc + 0x0C)
                explicit = cw is not None and cw.addr == adc + 0x0C
                good = bool(cfgr & (1 << 31)) and explicit
                ok &= good
                ev.append((cw, 1 << 31))
                detail.append(f"{name} JSQR #{w.seq}: JQDIS {cfgr >> 31} by {'#' + str(cw.seq) if cw else 'reset'}")
        return ok, "; ".join(detail), ev

    c.append(("JQDIS set (by a CFGR write) before each JSQR write", jqdis))

    def dac_order(log):
        enables = [w for w in log.of(DAC1) if w.value & 1]
        if not enables:
            return False, "DAC1 channel 1 never enabled", []
        dhr, ev = log.before(enables[0].seq, DAC1 + 0x08)
        explicit = ev is not None and ev.addr == DAC1 + 0x08
        return dhr == 2048 and explicit, f"DHR12R1 {dhr} when EN1 set (#{enables[0].seq})", [(ev, 0xFFF)]

    c.append(("DAC mid-scale 2048 written before the channel enable", dac_order))

    def moe_low(log):
        bad = [w for w in log.writes if w.addr in (TIM1 + 0x44, TIM8 + 0x44) and w.value & (1 << 15)]
        return not bad, f"{len(bad)} BDTR writes with MOE = 1", \
            [(w, 1 << 15) for w in log.writes if w.addr in (TIM1 + 0x44, TIM8 + 0x44)]

    c.append(("BDTR.MOE low throughout boot (TIM1, TIM8)", moe_low))

    def outputs_off(log):
        # Nothing may switch the bridges on by itself: AOE = 0 in every BDTR write (else the
        # next update event sets MOE), and the counters run with the duties of bring-up only.
        bdtr = [w for w in log.writes if w.addr in (TIM1 + 0x44, TIM8 + 0x44)]
        bad = [w for w in bdtr if w.value & ((1 << 14) | (1 << 15))]
        return not bad and bool(bdtr), f"{len(bad)} BDTR writes with AOE or MOE set", \
            [(w, 1 << 14) for w in bdtr]

    c.append(("outputs never enabled before the controller returns duties (no AOE/MOE)", outputs_off))

    def watchdog_first(log):
        starts = [w for w in log.writes if w.addr == IWDG and w.raw & 0xFFFF == 0xCCCC]
        # UART5 = IRQ 53 (NVIC_ISER1 bit 21) is the control executor: enabling it is the
        # earliest the control task could run. The thread tasks' first polls show as their
        # first embassy-time alarm (TIM2 CCR2).
        uart5 = [w for w in log.writes if w.addr == NVIC_ISER + 4 and w.raw & (1 << 21)]
        alarms = [w for w in log.writes if w.addr == TIM2 + 0x38]
        if not starts or not uart5 or not alarms:
            return False, (f"IWDG start {fmt_ev(starts[:1])}, control executor IRQ enable "
                           f"{fmt_ev(uart5[:1])}, first task alarm {fmt_ev(alarms[:1])}"), []
        ok = starts[0].seq < uart5[0].seq and starts[0].seq < alarms[0].seq
        return ok, (f"IWDG started #{starts[0].seq}, control executor IRQ enabled #{uart5[0].seq}, "
                    f"first task alarm #{alarms[0].seq}"), [(starts[0], 0xFFFF)]

    c.append(("watchdog started before any task can run", watchdog_first))
    return c


def evaluate(writes):
    log = Log(writes)
    return [(name, *fn(log)) for name, fn in checks()]


# ---- mutation self-test -----------------------------------------------------------------
def mutate(w, mask):
    """The same write with the asserted field's bits flipped."""
    return replace(w, value=w.value ^ mask, raw=w.raw ^ mask)


def self_test(writes):
    """For each passing check and each write it rests on: flip the asserted field in that
    one write and re-run the checks on the altered log; the check must now fail."""
    results = evaluate(writes)
    missed = 0
    print("\nself-test: alter each asserted write, the check must fail")
    for i, (name, ok, _, evidence) in enumerate(results):
        if not ok:
            continue
        targets = [(w, m) for w, m in evidence if w is not None]
        if not targets:
            print(f"  MISSED {name}: no write to alter (value from reset)")
            missed += 1
            continue
        for target, mask in targets:
            altered = [mutate(w, mask) if w.seq == target.seq else w for w in writes]
            still_ok = evaluate(altered)[i][1]
            missed += still_ok
            print(f"  {'MISSED' if still_ok else 'caught':6s} {name}: write #{target.seq} "
                  f"{peripheral_of(target.addr)[0]} {target.value:#010x} -> "
                  f"{mutate(target, mask).value:#010x}")
    return missed


# Hardware faults injected into the model, and what the firmware must do about each: reset
# through its boot check (boost bit, ADC read-back) or stop in its panic path (TIM8 not
# started by TIM1), never reach the idle executor, and never set MOE.
INJECTIONS = [
    ("pwr-cr5-ignored", "PWR_CR5 bit 8 stays set (the boost write is lost)"),
    ("adc1-jsqr-dropped", "ADC1 ignores its JSQR write"),
    ("tim8-not-triggered", "TIM1's TRGO does not start TIM8"),
]


def store_injection_test(path, step_limit):
    """A store of zeros (not erased, no valid item): the boot must call it invalid, still
    refuse Start, and still reach the idle executor (the check above must then fail)."""
    run = run_elf(path, step_limit, inject="store-zeroed")
    said = calibration_at_boot(run)
    caught = not store_checks(run)[1][1]
    ok = caught and said == ("calibration_invalid", True) and run.idle
    print(f"  {'caught' if ok else 'MISSED':6s} calibration store all zeros: logged {said}, "
          f"{run.end}")
    return 0 if ok else 1


def injection_test(path, step_limit):
    print("\nself-test: a calibration store that is not empty must not pass as empty")
    missed = store_injection_test(path, step_limit)
    print("\nself-test: hardware faults injected, the firmware must stop before running")
    for name, what in INJECTIONS:
        run = run_elf(path, step_limit, inject=name)
        where = symbol_at(run.symbols, run.end_pc)
        # The panic handler ends in UDF, which unicorn stops on (no exception model); on the
        # chip that is a HardFault, whose handler resets.
        stopped = "reset requested" in run.end or "rust_begin_unwind" in where or "HardFault" in where
        moe = any(w.addr in (TIM1 + 0x44, TIM8 + 0x44) and w.value & (1 << 15) for w in run.log)
        ok = stopped and not run.idle and not moe
        missed += not ok
        print(f"  {'caught' if ok else 'MISSED':6s} {what}: {run.end} "
              f"(pc in {where[:60]}), MOE set: {moe}")
    return missed


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("elf", nargs="?", default=DEFAULT_ELF)
    parser.add_argument("--self-test", action="store_true")
    parser.add_argument("--log", action="store_true", help="print every peripheral write")
    parser.add_argument("--steps", type=int, default=STEP_LIMIT)
    args = parser.parse_args()

    run = run_elf(args.elf, args.steps)
    print(f"boot-check: {args.elf}")
    print(f"  run ended: {run.end} after {run.steps} instructions "
          f"(pc {run.end_pc:#010x} in {symbol_at(run.symbols, run.end_pc)})")
    per = {}
    for w in run.log:
        per.setdefault(peripheral_of(w.addr)[0], 0)
        per[peripheral_of(w.addr)[0]] += 1
    print(f"  {len(run.log)} peripheral writes: " + ", ".join(f"{k} {v}" for k, v in sorted(per.items())))
    if args.log:
        for w in run.log:
            name, off = peripheral_of(w.addr)
            print(f"    #{w.seq:5d} pc {w.pc:#010x} {name}+{off:#05x} = {w.value:#010x}")

    results = evaluate(run.log)
    results.insert(0, ("run reaches the idle executor (WFE in thread mode)", run.idle, run.end, []))
    results.insert(1, ("defmt logs written to RTT up-channel 0", bool(run.rtt_write),
                       f"write offset {run.rtt_write}", []))
    # The host attached in blocking mode and never reads: logging must not wait.
    blocked = run_elf(args.elf, args.steps, inject="defmt-host-blocking")
    results.insert(2, ("defmt never blocks: host set 'block if full', buffer full, never read",
                       blocked.rtt_full and blocked.idle,
                       f"armed: {blocked.rtt_full}; {blocked.end} after {blocked.steps} instructions", []))
    for i, check in enumerate(store_checks(run)):
        results.insert(3 + i, check)
    failed = 0
    for name, ok, detail, _ in results:
        failed += not ok
        print(f"  {'PASS' if ok else 'FAIL'}  {name}: {detail}")
    if args.self_test:
        missed = self_test(run.log) + injection_test(args.elf, args.steps)
        print(f"self-test: {'all mutations caught' if not missed else f'{missed} not caught'}")
        failed += missed
    print(f"boot-check: {'PASS' if not failed else f'FAIL ({failed})'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
