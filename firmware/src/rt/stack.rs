//! The stack's high-water mark: how deep the stack has ever been, so that the QEMU bench can show the room left
//! between it and the statics below it (`insn`-free figures `bytes.stack_used_max` and `bytes.stack_free_min`).
//!
//! The stack starts at the top of the SRAM (`_stack_start`) and grows down towards the end of `.bss` (`__sheap`,
//! cortex-m-rt's symbol; this image has no heap). Nothing stops it there: a stack that grows past `__sheap`
//! overwrites the statics at the top of `.bss` without a fault. [`paint`] fills the free stack with a pattern at
//! start-up; [`high_water`] finds the lowest word that is no longer the pattern.

use core::sync::atomic::{compiler_fence, Ordering};

/// The fill word: not a plausible address, small integer or float, so that a stack frame rarely leaves it.
const PAINT: u32 = 0x5A5A_A5A5;
/// Bytes below the stack pointer that [`paint`] leaves alone: its own frame's callees and an interrupt's frame.
const MARGIN: usize = 256;

extern "C" {
    /// End of `.bss` (cortex-m-rt): the lowest address the stack may reach.
    static __sheap: u32;
    /// Top of the stack (cortex-m-rt): the initial stack pointer.
    static _stack_start: u32;
}

fn bottom() -> usize {
    // Only the linker symbol's address is taken, never its (meaningless) value.
    core::ptr::addr_of!(__sheap) as usize
}

fn top() -> usize {
    core::ptr::addr_of!(_stack_start) as usize
}

/// Fills the unused stack (from the end of `.bss` to [`MARGIN`] below the current stack pointer) with the pattern.
/// Call once, first thing at start-up, before any interrupt is enabled.
pub(crate) fn paint() {
    let sp = cortex_m::register::msp::read() as usize;
    let end = sp.saturating_sub(MARGIN) & !3;
    let mut at = bottom();
    while at < end {
        // SAFETY: `[bottom, end)` lies below the live stack (below the stack pointer less a margin for this
        // function's callees) and above every static: memory nothing else uses now, word aligned.
        unsafe { core::ptr::write_volatile(at as *mut u32, PAINT) };
        at = at.wrapping_add(4);
    }
    compiler_fence(Ordering::SeqCst);
}

/// Bytes of stack used at most since [`paint`]: from the top down to the lowest word that no longer holds the
/// pattern (0 before `paint`'s pattern is found at all).
#[must_use]
pub fn high_water() -> u32 {
    let (mut at, top) = (bottom(), top());
    while at < top {
        // SAFETY: `[bottom, top)` is the stack's SRAM, word aligned; reading it races with nothing that matters
        // (a word the stack takes while this runs is counted a word later).
        if unsafe { core::ptr::read_volatile(at as *const u32) } != PAINT {
            break;
        }
        at = at.wrapping_add(4);
    }
    u32::try_from(top.saturating_sub(at)).unwrap_or(u32::MAX)
}

/// Bytes between the end of `.bss` and the top of the stack: the most the stack can use.
#[must_use]
pub fn size() -> u32 {
    u32::try_from(top().saturating_sub(bottom())).unwrap_or(u32::MAX)
}
