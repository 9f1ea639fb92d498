//! The runtime (target only): the three timing tiers of `shared/design/ARCHITECTURE.md` on the STM32F405.
//!
//! | tier | rate    | runs as                                               | priority        | code            |
//! |------|---------|-------------------------------------------------------|-----------------|-----------------|
//! | 1    | 25 kHz  | raw handler of the ADC interrupt (JEOC of ADC1)       | 0 (highest)     | [`tier1`]       |
//! | 2    | 2.5 kHz | embassy `InterruptExecutor` on a spare vector (IRQ 44) | `TIER2_PRIORITY` | [`tier2`]      |
//! | 3    | -       | embassy thread executor, WFE when idle                | thread mode     | [`tier3`]       |
//!
//! Every item shared between tiers has exactly one writer:
//!
//! | item                        | kind                         | writer            | readers                 |
//! |-----------------------------|------------------------------|-------------------|-------------------------|
//! | tier-1 state (`drive::tier1::Tier1State`, power stage) | slot, set before the IRQ is unmasked | start-up, then tier 1 | tier 1 |
//! | the drive (`drive::Drive`: dictionary, axis, supervision) | `tier2::Tier2Slot`, BASEPRI at tier 2's priority | tier 2, the EtherCAT cycle interrupts and tier 3, one at a time through `tier2::with_drive` | same |
//! | `tier1::SETTINGS`, `tier1::SETPOINT` | `handoff::Command` (double buffer) | `tier2::with_drive` when a section ends (one at a time: under the tier-2 lock) | tier 1 |
//! | `tier1::REPORT`             | `handoff::Report` (sequence lock) | tier 1, every tenth period after the PWM write | tier 2 |
//! | `tier1::PERIODS_LOST`, `tier1::REPORT_MAX` | `AtomicU32`      | tier 1            | tier 3, QEMU bench      |
//! | `tier1::PERIOD_SUPERVISED`  | `AtomicBool`                 | start-up; the QEMU bench with the timer stopped | tier 1 |
//! | `tier1::FAST_TICK_MAX`      | `AtomicU32`                  | tier 1            | tier 3, QEMU bench      |
//! | `tier1::FAST_TICKS`         | `AtomicU32`                  | tier 1            | tier 3, QEMU bench      |
//! | `tier1::OVERRUN`            | `AtomicBool`, latched        | tier 1            | tier 2, tier 3          |
//! | `tier1::TIER1_LATENCY_MAX`, `tier1::TIER1_LATENCY_MIN`, `tier1::FAST_MISSED`, `tier1::LAST_UPDATE` | `AtomicU32` (QEMU image) | tier 1 (period timer); the bench before it starts the timer | QEMU bench |
//! | `tier1::RECORDER_RING`      | `recorder::ring::SampleRing` (atomics, the count after each slot) | tier 1, every period inside the fast tick | tier 2 (the recorder's drain after the slow tick) |
//! | `tier2::RECORDER` (`recorder::Recorder`, its sample memory [`RECORDER_BUFFER`]) | `tier2::Tier2Slot`, under the tier-2 lock | tier 2 (the drain: samples), tier 3 (SDO: configuration, arm), one at a time | tier 2, tier 3 (SDO upload) |
//! | `tier2::SLOW_TICK`          | [`signal::TickSignal`]       | tier 1 (raise)    | tier-2 slow loop (wait) |
//! | `tier2::SLOW_TICKS`         | `AtomicU32`                  | tier 2            | tier 3, QEMU bench      |
//! | `tier2::SLOW_TICK_MAX`      | `AtomicU32`                  | tier 2            | tier 3, QEMU bench      |
//! | `tier2::BACKGROUND_MAX`     | `AtomicU32`                  | tier 2            | QEMU bench              |
//! | `tier2::SLOW_MISSED`, `tier2::TIER2_TOTAL_MAX`, `tier2::REPORTS_TORN` | `AtomicU32` | tier 2 (the bench resets the total with tier 2 idle) | tier 3, QEMU bench |
//! | `tier3::TICK`               | [`signal::TickSignal`]       | tier 2 (raise)    | tier-3 supervisor       |
//! | `ethercat` state (SPI ESC, slave, PLL) | `tier2::Tier2Slot`, feature `ethercat` | tier 3 (poll), EXTI0/TIM3 and tier 2 (cycle), each in the slot, under the tier-2 lock (`tier2::with_drive`: BASEPRI, never tier 1) | same |
//! | TIM1 registers (duties, MOE)| peripheral                   | tier 1; the panic/fault handlers force MOE off | - |
//! | parameter flash (FLASH_CR, PARAMS_A/B) | `board::flash::ParamFlash` in `app::Params`, owned | start-up reads it (`app::boot`); then tier 3 only, erasing and programming under the tier-2 lock (`tier2::with_drive`) with the power stage off and no request pending (tier 1 keeps running, stalled by the flash with its outputs off) | start-up, tier 3 |
//! | update flash (slot A, slot B, BOOT_STATE) | `board::boot::UpdateRegion`s in [`program::BoardProgram`], owned | start-up reads slot A's header and the state log ([`program::start`]); then tier 3 only: the confirmation and the download, under the tier-2 lock (`tier2::with_drive`) with the power stage off | start-up, tier 3 |
//! | independent watchdog (IWDG_KR), reset flags (RCC_CSR) | `board::watchdog` | start-up reads and clears the flags and starts the watchdog; then tier 3 only feeds it: the supervisor when every tier ran (`supervision::watchdog`), the flash driver before an erase | - |
//!
//! Nothing masks tier 1: tiers 2 and 3 share the drive under BASEPRI at tier 2's priority, and tier 1 shares only
//! the hand-off blocks (atomics, no lock) with them. The libraries' critical sections (embassy, defmt's RTT
//! logger, semihosting) use the same ceiling once the tiers run ([`critical`]). The QEMU bench shows it
//! (`insn.tier1_latency_max`, `insn.masked_max`).
//!
//! Start-up order: board init (outputs off) -> the reset cause read and cleared (`board::watchdog`) -> parameters
//! loaded from flash and the drive built from them (`app::boot`; defaults in the QEMU image) -> program control for the
//! running image ([`program::start`]; not in the QEMU image) -> the drive placed for tier 2 and its first blocks
//! published -> tier 2 started (its interrupt unmasked, slow loop spawned) -> tier 1 started (ADC interrupt unmasked)
//! -> the independent watchdog started (not in the QEMU image) -> tier 3 runs forever (owning the parameter store and
//! program control). Logging (defmt, feature `defmt`) happens in
//! start-up, tier 2 and tier 3, never in tier 1 ([`log`]).

pub mod app;
#[cfg(not(feature = "qemu"))]
pub mod canopen;
mod critical;
#[cfg(all(feature = "ethercat", not(feature = "qemu")))]
pub mod ethercat;
mod figures;
pub mod log;
mod panic;
pub mod program;
pub mod signal;
pub mod stack;
pub mod tier1;
pub mod tier2;
pub mod tier3;
mod vectors;

#[cfg(feature = "qemu")]
pub mod bench;

use cortex_m::peripheral::NVIC;

use crate::board::{self, interrupt::Interrupt};

/// NVIC priority of tier 1 (the F405 implements the top 4 bits: 16 levels, 0 highest).
pub const TIER1_PRIORITY: u8 = 0x00;
/// NVIC priority of tier 2's executor interrupt: below tier 1, above thread mode.
pub const TIER2_PRIORITY: u8 = 0x40;

/// Half-words of the data recorder's sample memory: on the board the whole 64 KiB CCM RAM, which holds 2,048
/// samples of 8 channels of 32 bits (82 ms at 25 kHz) or 32,768 of one 16-bit channel (1.3 s).
///
/// In the CCM, not the SRAM: the SRAM's top is the stack, which grows down towards `.bss` with nothing to stop it
/// ([`stack`]); with a 64 KiB buffer in `.bss` the QEMU bench's stack ran into the statics below it. Only the core
/// reads and writes the buffer (the CCM is not on the DMA's bus matrix, RM0090 section 2.3.1).
#[cfg(not(feature = "qemu"))]
pub const RECORDER_BUFFER_HALVES: usize = 32 * 1024;
/// Half-words of the data recorder's sample memory in the QEMU image: 16 KiB in the SRAM, as QEMU's
/// `netduinoplus2` has no CCM RAM (a store to 0x1000_0000 is a bus fault there). The recorder's code is the
/// board's; only the number of samples a recording holds is smaller.
#[cfg(feature = "qemu")]
pub const RECORDER_BUFFER_HALVES: usize = 8 * 1024;

/// The data recorder's sample memory (`crate::recorder`), given to it at start-up. On the board in `.ccmram`
/// (`memory.x`), which start-up does not zero: [`run`] clears it before the recorder gets it.
#[cfg_attr(not(feature = "qemu"), link_section = ".ccmram.recorder")]
static RECORDER_BUFFER: [core::sync::atomic::AtomicU16; RECORDER_BUFFER_HALVES] =
    [const { core::sync::atomic::AtomicU16::new(0) }; RECORDER_BUFFER_HALVES];

/// Brings the board up and runs the three tiers forever. Called from the application's entry point.
pub fn run() -> ! {
    stack::paint();
    let board = match board::init() {
        Ok(board) => board,
        Err(_e) => {
            crate::rt_error!("clock start-up failed: {}", defmt::Debug2Format(&_e));
            halt("clock start-up failed");
        }
    };
    crate::rt_info!("board up");
    // Why this start happened, read and cleared before anything else could reset the device again: a reset by
    // the independent watchdog is a fault of this start (0xFF02, `Drive::report_reset`). QEMU models neither the
    // RCC's reset flags nor the watchdog.
    #[cfg(not(feature = "qemu"))]
    let reset_cause = board::watchdog::take_reset_cause();
    let Some(mut peripherals) = cortex_m::Peripherals::take() else {
        halt("core peripherals already taken");
    };
    // SAFETY: priorities are set before either interrupt is unmasked, so no priority-based critical section can
    // be broken by the change.
    unsafe {
        peripherals.NVIC.set_priority(Interrupt::Adc, TIER1_PRIORITY);
        peripherals.NVIC.set_priority(Interrupt::Tier2, TIER2_PRIORITY);
        // The QEMU bench's period timer (SysTick) stands in for the ADC interrupt at the real period: tier 1's
        // priority.
        #[cfg(feature = "qemu")]
        peripherals.SCB.set_priority(cortex_m::peripheral::scb::SystemHandler::SysTick, TIER1_PRIORITY);
        // The EtherCAT cycle sources share tier 2's priority: serialised with the slow loop (`ethercat`).
        #[cfg(all(feature = "ethercat", not(feature = "qemu")))]
        {
            peripherals.NVIC.set_priority(Interrupt::EscPdi, TIER2_PRIORITY);
            peripherals.NVIC.set_priority(Interrupt::Sync0, TIER2_PRIORITY);
        }
    }
    // From here on a critical section (embassy, defmt, semihosting) masks up to tier 2's priority, never tier 1.
    critical::tiers_running();
    #[cfg_attr(feature = "qemu", allow(unused_mut))]
    let mut boot = app::boot();
    if let Some(_report) = boot.report {
        crate::rt_info!("parameters: {}", defmt::Debug2Format(&_report));
    }
    #[cfg(not(feature = "qemu"))]
    {
        crate::rt_info!("reset cause: {}", defmt::Debug2Format(&reset_cause));
        boot.drive.report_reset(reset_cause);
        // The SSI port, when the stored configuration has an SSI sensor (the QEMU image runs on the encoder).
        if let Some((frame_bits, rate_kbit)) = boot.drive.ssi_port() {
            board::ssi::init(frame_bits, rate_kbit);
        }
    }
    // Program control for the image that runs (0x1F5x, FoE; its confirmation runs in tier 3). The QEMU image
    // has no flash interface to drive it.
    #[cfg(not(feature = "qemu"))]
    let program = program::start(&mut boot.drive);
    #[cfg(feature = "qemu")]
    let program: Option<core::cell::RefCell<program::BoardProgram>> = None;
    // The board's own serial number (0x1018:04), from the chip's unique ID: what tells drives apart on one bus
    // (LSS fastscan, tools). QEMU's machine has no unique-ID area.
    #[cfg(not(feature = "qemu"))]
    {
        let serial = crate::board::device_id::serial_number();
        let _ = crate::canopen::ids::write(boot.drive.dictionary_mut(), 0x1018, 4, u64::from(serial));
    }
    // CAN1 with the stored node-ID and bit rate, before tier 1 runs (bringing the controller up waits for bus
    // idle, milliseconds that must not be spent with tier 1 held off).
    #[cfg(not(feature = "qemu"))]
    let can = canopen::start(&boot.drive);
    #[cfg(feature = "qemu")]
    let can = None;
    #[cfg(all(feature = "ethercat", not(feature = "qemu")))]
    ethercat::start();
    // Tier 1's state from the drive's first settings; the drive goes to tier 2, which publishes those blocks
    // before tier 1 runs.
    let tier1_state = crate::drive::tier1::Tier1State::new(boot.drive.settings());
    tier2::place_drive(boot.drive);
    let mut recorder = crate::recorder::Recorder::new();
    // The CCM's contents after a reset are whatever they were (`RECORDER_BUFFER`): the recorder starts on zeros.
    // (In the QEMU image the buffer is in `.bss`, already zero.)
    for half in &RECORDER_BUFFER {
        half.store(0, core::sync::atomic::Ordering::Relaxed);
    }
    recorder.attach(&RECORDER_BUFFER);
    tier2::RECORDER.place(recorder);
    let _ = tier2::start();
    tier1::start(board.power, tier1_state);
    crate::rt_info!("tiers 1 and 2 running");
    // The independent watchdog, fed by tier 3 only when every tier ran since the last feed (`tier3`); from here
    // on a tier that stops resets the device within 2.7 to 7.5 s (`board::watchdog`).
    #[cfg(not(feature = "qemu"))]
    board::watchdog::start();
    tier3::run(boot.params, program, can)
}

/// Stops for good with the power stage off: after an unrecoverable start-up error.
pub fn halt(_why: &'static str) -> ! {
    board::safe_state();
    NVIC::mask(Interrupt::Adc);
    #[cfg(feature = "qemu")]
    {
        board::semihosting::eprint(format_args!("halt: {_why}\n"));
        board::semihosting::exit(board::semihosting::EXIT_CHECK_FAILED);
    }
    #[cfg(not(feature = "qemu"))]
    loop {
        cortex_m::asm::wfi();
    }
}
