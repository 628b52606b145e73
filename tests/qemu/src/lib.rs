//! Support for the QEMU Cortex-M4F test binaries: exit codes through semihosting, and a
//! repeatable instruction counter.
//!
//! Run as `qemu-system-arm -cpu cortex-m4 -machine mps2-an386 -nographic
//! -semihosting-config enable=on,target=native -kernel BIN` (scripts/qemu-run). With
//! `-icount shift=0` every instruction advances virtual time by the same amount, so
//! SysTick counts are exact and repeatable; [`Counter::calibrate`] measures how many
//! instructions one SysTick tick is worth with a loop of known length.
#![no_std]

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::{syst::SystClkSource, SYST};
use cortex_m_rt::exception;
use cortex_m_semihosting::debug;

pub use cortex_m_semihosting::hprintln;

/// End the emulation with success or failure as QEMU's exit code.
pub fn exit(success: bool) -> ! {
    debug::exit(if success {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    // Only reached if semihosting is off; spin rather than return.
    loop {
        cortex_m::asm::nop();
    }
}

static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

const RELOAD: u32 = 0x00FF_FFFF;

/// SysTick, counting from the core clock and extended past its 24 bits by counting wraps.
pub struct Counter {
    syst: SYST,
    /// Instructions per SysTick tick, in 1/1024ths (from [`Counter::calibrate`]).
    per_tick_q10: u64,
}

impl Counter {
    /// Start SysTick free-running.
    pub fn start(mut syst: SYST) -> Counter {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(RELOAD);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
        // CURRENT reads 0 until the first reload, which would look like a full wrap.
        while SYST::get_current() == 0 {}
        Counter {
            syst,
            per_tick_q10: 1024,
        }
    }

    /// Ticks since start.
    pub fn now(&self) -> u64 {
        loop {
            let w1 = WRAPS.load(Ordering::Relaxed);
            let cur = SYST::get_current();
            let w2 = WRAPS.load(Ordering::Relaxed);
            if w1 == w2 {
                return u64::from(w1) * u64::from(RELOAD + 1) + u64::from(RELOAD - cur);
            }
        }
    }

    /// Measure instructions per tick with a loop of exactly `2·n` instructions
    /// (`subs` + `bne`). Returns the ratio in 1/1024ths.
    pub fn calibrate(&mut self) -> u64 {
        const N: u32 = 4_000_000;
        let t0 = self.now();
        spin(N);
        let t1 = self.now();
        let ticks = (t1 - t0).max(1);
        self.per_tick_q10 = (2 * u64::from(N) * 1024 + ticks / 2) / ticks;
        self.per_tick_q10
    }

    /// Ticks converted to instructions with the calibration.
    pub fn instructions(&self, ticks: u64) -> u64 {
        (ticks * self.per_tick_q10 + 512) / 1024
    }

    /// Give SysTick back.
    pub fn free(self) -> SYST {
        self.syst
    }
}

/// A loop of exactly `2·n` instructions.
#[inline(never)]
pub fn spin(n: u32) {
    if n == 0 {
        return;
    }
    // SAFETY: register-only loop; touches no memory and no stack.
    unsafe {
        core::arch::asm!(
            "1:",
            "subs {0}, {0}, #1",
            "bne 1b",
            inout(reg) n => _,
            options(nomem, nostack),
        );
    }
}

/// The deepest the stack went below a point: paint the stack below the caller's frame with
/// a pattern, run the code, and find the lowest word it overwrote.
pub mod stack {
    const PATTERN: u32 = 0x5A5A_A5A5;
    /// Bytes painted below the painter's frame.
    const SPAN: usize = 48 * 1024;
    /// Left alone just below the painter's own stack pointer (its frame and calls).
    const GUARD: usize = 256;

    /// A painted stack below the current frame.
    pub struct Painted {
        top: usize,
    }

    /// Paint [`SPAN`] bytes of the stack below the current one.
    #[inline(never)]
    pub fn paint() -> Painted {
        let top = cortex_m::register::msp::read() as usize - GUARD;
        let mut p = top - SPAN;
        while p < top {
            // SAFETY: the words lie below the live stack (MSP less a guard) and inside the
            // emulated RAM (4 MiB, the stack at its top), and nothing else runs.
            unsafe { core::ptr::write_volatile(p as *mut u32, PATTERN) };
            p += 4;
        }
        Painted { top }
    }

    impl Painted {
        /// Bytes below the painted top that were written since: how deep the code went,
        /// beyond the frame that painted (at most [`SPAN`]; SPAN means it may have gone
        /// further).
        pub fn used(&self) -> usize {
            let mut p = self.top - SPAN;
            // SAFETY: the same words [`paint`] wrote, read back.
            while p < self.top && unsafe { core::ptr::read_volatile(p as *const u32) } == PATTERN {
                p += 4;
            }
            self.top - p + GUARD
        }
    }
}
