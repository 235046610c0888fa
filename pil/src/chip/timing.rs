//! Clock cycles of Thumb-2 instructions on the Cortex-M4, from the Cortex-M4 Technical
//! Reference Manual (ARM DDI 0439B, §3.3.1 "Cortex-M4 instruction set summary", Table 3-1,
//! and §7.2.3 "FPU instruction set", Table 7-1), so that the emulator counts cycles instead
//! of assuming a CPI.
//!
//! Each instruction is classified from its encoding (ARMv7-M ARM, A5 "Thumb instruction set
//! encoding") into a base cost. Branches cost `1 + P` when taken (P: the pipeline refill);
//! whether a branch was taken is known only from where execution went on, so the decoder
//! says what kind of branch ends a block and the chip adds P when the next block does not
//! follow on.
//!
//! Where the TRM gives a range, the worst case is taken, so the count is an upper bound of
//! the core's cycles at zero wait states:
//! - P = 3 (the TRM: 1–3, by the target's alignment and width and whether the address was
//!   speculated early);
//! - loads and stores 2 (the TRM: 2, but 1 when pipelined after another load or store with
//!   no dependency), LDRD/STRD 3;
//! - SDIV/UDIV 12 (2–12, by the operands);
//! - DMB/DSB/ISB 4 (the TRM: 1 + B, B the cycles to complete the barrier; not on the
//!   control path);
//! - an instruction skipped by its IT block is counted as if it executed;
//! - multiplies with an accumulator 2, other multiplies (long ones included) 1.
//!
//! What this does not model: wait states (the chip adds them for flash, see
//! [`super::Soc`]), bus contention between the I-code and D-code/system buses, and the
//! store buffer. The exception entry and return are costed by the chip (12 cycles each,
//! 6 for a tail-chain, TRM §3.3.1 "Exception timing" and §5.5).

/// Pipeline refill after a taken branch, cycles (the TRM's P, its upper end).
pub const BRANCH_REFILL: u32 = 3;

/// How an instruction may change the flow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Flow {
    /// Falls through.
    #[default]
    Next,
    /// Always branches (B, BL, BX, POP {pc}, LDR pc, TBB): its P is always paid.
    Branch,
    /// Branches on a condition (B<c>, CBZ, CBNZ): P is paid when taken.
    Conditional,
}

/// The cost of one instruction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cost {
    /// Cycles, without the branch refill.
    pub cycles: u32,
    /// Whether it branches.
    pub flow: Flow,
    /// Length, bytes (2 or 4).
    pub bytes: u32,
}

/// Whether the half-word `hw` starts a 32-bit instruction.
pub fn is_wide(hw: u16) -> bool {
    matches!(hw >> 11, 0b11101..=0b11111)
}

fn c(cycles: u32) -> (u32, Flow) {
    (cycles, Flow::Next)
}

/// The cost of the instruction whose first half-word is `hw1` (and second `hw2` if it is a
/// 32-bit one).
pub fn cost(hw1: u16, hw2: u16) -> Cost {
    if is_wide(hw1) {
        let (cycles, flow) = wide(hw1, hw2);
        Cost {
            cycles,
            flow,
            bytes: 4,
        }
    } else {
        let (cycles, flow) = narrow(hw1);
        Cost {
            cycles,
            flow,
            bytes: 2,
        }
    }
}

/// 16-bit encodings (ARMv7-M ARM A5.2).
fn narrow(hw: u16) -> (u32, Flow) {
    let regs = |list: u16| (list & 0xFF).count_ones();
    match hw >> 10 {
        // Shifts, add, subtract, move, compare (immediate and register).
        0b000000..=0b001111 => c(1),
        // Data processing (register): AND .. MVN, MUL.
        0b010000 => c(1),
        // Special data processing and branch/exchange.
        0b010001 => {
            if hw & 0xFF00 == 0x4700 {
                // BX / BLX register.
                (1, Flow::Branch)
            } else if hw & 0x0087 == 0x0087 && hw & 0x0300 != 0x0100 {
                // ADD/MOV with Rd = PC (CMP does not write): a branch.
                (1, Flow::Branch)
            } else {
                c(1)
            }
        }
        // LDR (literal).
        0b010010 | 0b010011 => c(2),
        // Load/store single.
        0b010100..=0b100111 => c(2),
        // ADR, ADD (SP plus immediate).
        0b101000..=0b101011 => c(1),
        // Miscellaneous.
        0b101100..=0b101111 => {
            if hw & 0xF500 == 0xB100 {
                // CBZ / CBNZ.
                (1, Flow::Conditional)
            } else if hw & 0xFE00 == 0xB400 {
                // PUSH: 1 + N.
                c(1 + regs(hw) + u32::from(hw >> 8 & 1))
            } else if hw & 0xFE00 == 0xBC00 {
                // POP: 1 + N, + P with the PC.
                let pc = hw & 0x100 != 0;
                let n = 1 + regs(hw) + u32::from(pc);
                (n, if pc { Flow::Branch } else { Flow::Next })
            } else {
                // ADD/SUB SP, extends, REV, CPS, IT, hints (1 each; IT may fold to 0).
                c(1)
            }
        }
        // STM / LDM: 1 + N.
        0b110000..=0b110011 => c(1 + regs(hw)),
        // Conditional branch, UDF (cond 1110), SVC (1111).
        0b110100..=0b110111 => {
            if (hw >> 8) & 0xF >= 0xE {
                c(1)
            } else {
                (1, Flow::Conditional)
            }
        }
        // B (unconditional).
        0b111000 | 0b111001 => (1, Flow::Branch),
        _ => c(1),
    }
}

/// 32-bit encodings (ARMv7-M ARM A5.3).
fn wide(hw1: u16, hw2: u16) -> (u32, Flow) {
    let op1 = (hw1 >> 11) & 3;
    let op2 = (hw1 >> 4) & 0x7F;
    // Coprocessor space: the FPU (coprocessors 10 and 11).
    if (op1 == 1 || op1 == 3) && op2 & 0x40 != 0 {
        return c(fp(hw1, hw2));
    }
    match op1 {
        1 => {
            if op2 & 0x64 == 0x00 {
                // LDM/STM (PUSH.W/POP.W): 1 + N, + P when the PC is loaded.
                let load = hw1 & 0x10 != 0;
                let pc = load && hw2 & 0x8000 != 0;
                let n = 1 + (hw2 & 0x5FFF).count_ones() + u32::from(pc);
                (n, if pc { Flow::Branch } else { Flow::Next })
            } else if op2 & 0x64 == 0x04 {
                if hw1 & 0xFFF0 == 0xE8D0 && hw2 & 0xFFE0 == 0xF000 {
                    // TBB / TBH: 2 + P.
                    (2, Flow::Branch)
                } else if hw1 & 0x0120 == 0 && hw1 & 0x0080 == 0 {
                    // LDREX / STREX (and their byte/half-word forms).
                    c(2)
                } else {
                    // LDRD / STRD.
                    c(3)
                }
            } else {
                // Data processing (shifted register).
                c(1)
            }
        }
        2 => {
            if hw2 & 0x8000 == 0 {
                // Data processing (modified or plain immediate), bitfields, saturation.
                return c(1);
            }
            // Branches and miscellaneous control.
            let op = (hw2 >> 12) & 0x7;
            if op & 0x5 == 0 {
                if op2 & 0x38 != 0x38 {
                    (1, Flow::Conditional)
                } else if op2 & 0x7E == 0x38 {
                    // MSR.
                    c(2)
                } else if op2 == 0x3B {
                    // DSB / DMB / ISB.
                    c(4)
                } else {
                    // MRS, hints, CPS.
                    c(1)
                }
            } else {
                // B.W, BL.
                (1, Flow::Branch)
            }
        }
        _ => {
            if op2 & 0x71 == 0x00 {
                // Store single.
                c(2)
            } else if op2 & 0x60 == 0x00 {
                // Load byte, half-word, word; to the PC: 2 + P.
                if hw2 >> 12 == 0xF && op2 & 0x67 == 0x05 {
                    (2, Flow::Branch)
                } else {
                    c(2)
                }
            } else if op2 & 0x70 == 0x20 {
                // Data processing (register): shifts, extends, parallel, misc.
                c(1)
            } else if op2 & 0x78 == 0x30 {
                // Multiply, multiply-accumulate: MUL 1, with an accumulator 2.
                if hw2 >> 12 == 0xF {
                    c(1)
                } else {
                    c(2)
                }
            } else if op2 & 0x78 == 0x38 {
                // Long multiply (1) and divide (2..12: 12).
                if matches!(op2 & 0x7, 0b001 | 0b011) {
                    c(12)
                } else {
                    c(1)
                }
            } else {
                c(1)
            }
        }
    }
}

/// FPU instructions (TRM Table 7-1).
fn fp(hw1: u16, hw2: u16) -> u32 {
    // Not coprocessor 10/11: none on this core; count 1.
    if (hw2 >> 9) & 0x7 != 0b101 {
        return 1;
    }
    if hw1 & 0xFF00 == 0xEE00 {
        if hw2 & 0x10 != 0 {
            // VMOV between a core and a single register, VMRS, VMSR.
            return if hw1 & 0x00F0 == 0x00E0 { 2 } else { 1 };
        }
        // Data processing: opc1 = hw1 bits 7, 5, 4 (bit 6 is D).
        let opc1 = ((hw1 >> 4) & 0x3) | ((hw1 >> 5) & 0x4);
        return match opc1 {
            // VMLA/VMLS, VNMLA/VNMLS: 3.
            0b000 | 0b001 => 3,
            // VMUL/VNMUL, VADD/VSUB: 1.
            0b010 | 0b011 => 1,
            // VDIV: 14.
            0b100 => 14,
            // VFNMA/VFNMS, VFMA/VFMS: 3.
            0b101 | 0b110 => 3,
            // Others: VMOV, VABS, VNEG, VCMP, VCVT 1; VSQRT 14.
            _ => {
                let opc2 = hw1 & 0xF;
                let opc3 = (hw2 >> 6) & 0x3;
                if opc2 == 0b0001 && opc3 == 0b11 {
                    14
                } else {
                    1
                }
            }
        };
    }
    // Extension register load/store, and 64-bit transfers.
    if hw1 & 0xFFE0 == 0xEC40 {
        // VMOV two core registers to/from a double or two singles: 2.
        return 2;
    }
    if hw1 & 0xFF20 == 0xED00 {
        // VLDR / VSTR: 2 for a single, 3 for a double (coprocessor field 0xB; TRM Table 7-1).
        return if hw2 & 0x0F00 == 0x0B00 { 3 } else { 2 };
    }
    // VLDM/VSTM/VPUSH/VPOP: 1 + N words (imm8 counts words for both sizes, + 1 for FLDMX).
    1 + u32::from(hw2 & 0xFF)
}

/// The instructions of a block of Thumb code: their count, cycles without refills, the flow
/// of the last one, and whether one is SEV.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Block {
    /// Instructions.
    pub instructions: u32,
    /// Cycles at zero wait states, without the last branch's refill.
    pub cycles: u32,
    /// How the last instruction may branch.
    pub flow: Flow,
    /// Contains SEV.
    pub sev: bool,
}

/// Decodes a block of code.
pub fn block(bytes: &[u8]) -> Block {
    let mut b = Block::default();
    let mut i = 0;
    while i + 1 < bytes.len() {
        let hw1 = u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        let hw2 = bytes
            .get(i + 2..i + 4)
            .map_or(0, |s| u16::from_le_bytes([s[0], s[1]]));
        let k = cost(hw1, hw2);
        b.instructions += 1;
        b.cycles += k.cycles;
        b.flow = k.flow;
        if hw1 == 0xBF40 {
            b.sev = true;
        }
        i += k.bytes as usize;
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(bytes: &[u8]) -> (u32, Flow) {
        let hw = |i: usize| u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        let k = cost(hw(0), if bytes.len() > 2 { hw(2) } else { 0 });
        assert_eq!(k.bytes as usize, bytes.len());
        (k.cycles, k.flow)
    }

    // Encodings as `llvm-mc -triple=thumbv7em-none-eabihf -mattr=+vfp4d16sp -show-encoding`
    // assembles them.
    #[test]
    fn the_trm_cycle_counts_of_the_instructions_the_control_path_uses() {
        assert_eq!(one(&[0x01, 0x20]), (1, Flow::Next)); // movs r0, #1
        assert_eq!(one(&[0x08, 0x68]), (2, Flow::Next)); // ldr r0, [r1]
        assert_eq!(one(&[0xD2, 0xF8, 0x00, 0x10]), (2, Flow::Next)); // ldr.w r1, [r2]
        assert_eq!(one(&[0x70, 0x47]), (1, Flow::Branch)); // bx lr
        assert_eq!(one(&[0xF0, 0xB5]), (6, Flow::Next)); // push {r4-r7, lr}
        assert_eq!(one(&[0xF0, 0xBD]), (6, Flow::Branch)); // pop {r4-r7, pc}
        assert_eq!(one(&[0x2D, 0xE9, 0xF0, 0x4F]), (10, Flow::Next)); // push.w {r4-r11, lr}
        assert_eq!(one(&[0xBD, 0xE8, 0xF0, 0x8F]), (10, Flow::Branch)); // pop.w {r4-r11, pc}
        assert_eq!(one(&[0x01, 0xD0]), (1, Flow::Conditional)); // beq
        assert_eq!(one(&[0x08, 0xB1]), (1, Flow::Conditional)); // cbz r0
        assert_eq!(one(&[0x00, 0xE0]), (1, Flow::Branch)); // b
        assert_eq!(one(&[0x00, 0xF0, 0x00, 0xF8]), (1, Flow::Branch)); // bl
        assert_eq!(one(&[0x40, 0xF0, 0x00, 0x80]), (1, Flow::Conditional)); // bne.w
        assert_eq!(one(&[0xB1, 0xFB, 0xF2, 0xF0]), (12, Flow::Next)); // udiv r0, r1, r2
        assert_eq!(one(&[0x91, 0xFB, 0xF2, 0xF0]), (12, Flow::Next)); // sdiv r0, r1, r2
        assert_eq!(one(&[0x01, 0xFB, 0x02, 0xF0]), (1, Flow::Next)); // mul r0, r1, r2 (T2)
        assert_eq!(one(&[0x01, 0xFB, 0x12, 0x30]), (2, Flow::Next)); // mls r0, r1, r2, r3
        assert_eq!(one(&[0x87, 0x46]), (1, Flow::Branch)); // mov pc, r0
        assert_eq!(one(&[0x8F, 0x44]), (1, Flow::Branch)); // add pc, r1
        assert_eq!(one(&[0xC8, 0x45]), (1, Flow::Next)); // cmp r8, r9
        assert_eq!(one(&[0x0E, 0xC8]), (4, Flow::Next)); // ldm r0!, {r1, r2, r3}
        assert_eq!(one(&[0x02, 0x48]), (2, Flow::Next)); // ldr r0, [pc, #8]
        assert_eq!(one(&[0x51, 0xE8, 0x00, 0x0F]), (2, Flow::Next)); // ldrex r0, [r1]
        assert_eq!(one(&[0xB1, 0xF9, 0x02, 0x00]), (2, Flow::Next)); // ldrsh.w r0, [r1, #2]
        assert_eq!(one(&[0x81, 0xF8, 0x90, 0x01]), (2, Flow::Next)); // strb.w r0, [r1, #400]
        assert_eq!(one(&[0x80, 0xF3, 0x11, 0x88]), (2, Flow::Next)); // msr basepri, r0
        assert_eq!(one(&[0xEF, 0xF3, 0x11, 0x80]), (1, Flow::Next)); // mrs r0, basepri
        assert_eq!(one(&[0xC1, 0xF3, 0x82, 0x00]), (1, Flow::Next)); // ubfx r0, r1, #2, #3
        assert_eq!(one(&[0x01, 0xFB, 0x02, 0x30]), (2, Flow::Next)); // mla r0, r1, r2, r3
        assert_eq!(one(&[0xA1, 0xFB, 0x02, 0x01]), (1, Flow::Next)); // umull r0, r1, r1, r2
        assert_eq!(one(&[0xD0, 0xE8, 0x01, 0xF0]), (2, Flow::Branch)); // tbb [r0, r1]
        assert_eq!(one(&[0xD1, 0xE9, 0x00, 0x23]), (3, Flow::Next)); // ldrd r2, r3, [r1]
        assert_eq!(one(&[0x5D, 0xF8, 0x04, 0xFB]), (2, Flow::Branch)); // ldr pc, [sp], #4
        assert_eq!(one(&[0xBF, 0xF3, 0x5F, 0x8F]), (4, Flow::Next)); // dmb sy
                                                                     // FPU (TRM Table 7-1).
        assert_eq!(one(&[0x30, 0xEE, 0x01, 0x0A]), (1, Flow::Next)); // vadd.f32 s0, s0, s2
        assert_eq!(one(&[0x20, 0xEE, 0x01, 0x0A]), (1, Flow::Next)); // vmul.f32 s0, s0, s2
        assert_eq!(one(&[0x00, 0xEE, 0x01, 0x0A]), (3, Flow::Next)); // vmla.f32 s0, s0, s2
        assert_eq!(one(&[0xA0, 0xEE, 0x01, 0x0A]), (3, Flow::Next)); // vfma.f32 s0, s0, s2
        assert_eq!(one(&[0x80, 0xEE, 0x01, 0x0A]), (14, Flow::Next)); // vdiv.f32 s0, s0, s2
        assert_eq!(one(&[0xB1, 0xEE, 0xC0, 0x0A]), (14, Flow::Next)); // vsqrt.f32 s0, s0
        assert_eq!(one(&[0xB4, 0xEE, 0x41, 0x0A]), (1, Flow::Next)); // vcmp.f32 s0, s2
        assert_eq!(one(&[0x90, 0xED, 0x00, 0x0A]), (2, Flow::Next)); // vldr s0, [r0]
        assert_eq!(one(&[0x2D, 0xED, 0x04, 0x8B]), (5, Flow::Next)); // vpush {d8, d9}
        assert_eq!(one(&[0xF1, 0xEE, 0x10, 0xFA]), (1, Flow::Next)); // vmrs APSR_nzcv, fpscr
        assert_eq!(one(&[0x00, 0xEE, 0x10, 0x0A]), (1, Flow::Next)); // vmov s0, r0
        assert_eq!(one(&[0x41, 0xEC, 0x10, 0x0B]), (2, Flow::Next)); // vmov d0, r0, r1
        assert_eq!(one(&[0xBD, 0xEC, 0x04, 0x8A]), (5, Flow::Next)); // vpop {s16-s19}
        assert_eq!(one(&[0x80, 0xED, 0x01, 0x0A]), (2, Flow::Next)); // vstr s0, [r0, #4]
        assert_eq!(one(&[0x90, 0xED, 0x00, 0x0B]), (3, Flow::Next)); // vldr d0, [r0]
        assert_eq!(one(&[0x80, 0xED, 0x02, 0x0B]), (3, Flow::Next)); // vstr d0, [r0, #8]
        assert_eq!(one(&[0x00, 0xEE, 0xC1, 0x0A]), (3, Flow::Next)); // vmls.f32 s0, s1, s2
        assert_eq!(one(&[0x20, 0xEE, 0xC1, 0x0A]), (1, Flow::Next)); // vnmul.f32 s0, s1, s2
        assert_eq!(one(&[0xB1, 0xEE, 0x60, 0x0A]), (1, Flow::Next)); // vneg.f32 s0, s1
        assert_eq!(one(&[0xBD, 0xEE, 0xC0, 0x0A]), (1, Flow::Next)); // vcvt.s32.f32 s0, s0
    }

    #[test]
    fn a_block_adds_up_its_instructions_and_ends_with_the_last_ones_flow() {
        // movs r0,#1 ; ldr.w r1,[r2] ; sev ; bx lr
        let code = [0x01, 0x20, 0xD2, 0xF8, 0x00, 0x10, 0x40, 0xBF, 0x70, 0x47];
        let b = block(&code);
        assert_eq!(b.instructions, 4);
        assert_eq!(b.cycles, 1 + 2 + 1 + 1);
        assert_eq!(b.flow, Flow::Branch);
        assert!(b.sev);
        assert_eq!(block(&code[..6]).instructions, 2);
        assert!(!block(&code[..6]).sev);
    }
}
