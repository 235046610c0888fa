//! The firmware's stack as a debug probe sees it: flip-link links it below the statics,
//! from SRAM's start to the initial stack pointer (`_stack_start`); the boot paints it with
//! `src/board/stack.rs`'s pattern, and the lowest word that no longer holds the pattern is the
//! deepest the stack has been.

use crate::chip::Chip;

/// The paint of a stack word never used since boot (`src/board/stack.rs`, `PAINT`).
pub const PAINT: u32 = 0x5AC4_5AC4;

/// SRAM1's start.
const SRAM_START: u32 = 0x2000_0000;

/// The stack's use: the deepest it has been since boot and its size, bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StackUse {
    /// Bytes from the top to the lowest word no longer holding the paint.
    pub high_water: u32,
    /// Bytes from the top to the stack's lowest address.
    pub size: u32,
}

impl StackUse {
    /// The high-water mark's share of the stack.
    pub fn share(&self) -> f64 {
        f64::from(self.high_water) / f64::from(self.size.max(1))
    }
}

/// Reads the stack's use from `chip`'s RAM (None if the ELF lacks the symbols, or no paint
/// is found: a firmware that does not paint).
pub fn stack_use(chip: &Chip) -> Option<StackUse> {
    let image = chip.image();
    let top = image.symbol("_stack_start")?;
    let data = image.symbol("__sdata")?;
    let bottom = if data >= top {
        SRAM_START
    } else {
        (image.symbol("_stack_end")? + 31) & !31
    };
    let mut buf = vec![0u8; top.checked_sub(bottom)? as usize];
    chip.read_mem(bottom, &mut buf).ok()?;
    let painted = buf
        .chunks_exact(4)
        .take_while(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]) == PAINT)
        .count() as u32;
    if painted == 0 {
        return None;
    }
    Some(StackUse {
        high_water: top - bottom - 4 * painted,
        size: top - bottom,
    })
}
