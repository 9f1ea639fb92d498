//! The EtherCAT slave in the runtime (feature `ethercat`, not in the QEMU image): the firmware's
//! [`EthercatSlave`] on the ET1100-class SPI ESC ([`SpiEsc`] over `board::esc_spi::Spi1`), with the DC
//! phase-locked loop ([`SyncPll`]) on the SYNC0 capture (`board::sync_timer`).
//!
//! | what                                   | runs in                                          | priority          |
//! |----------------------------------------|--------------------------------------------------|-------------------|
//! | [`EthercatSlave::poll`] (ESM, mailbox, supervision), PLL supervision, cycle-source set-up | tier-3 supervisor, every tier-3 tick (2.5 kHz) | thread mode |
//! | [`EthercatSlave::cycle`], SM-synchronous | [`on_pdi_irq`]: the ESC's SPI_IRQ on EXTI0, AL event mask = SM2 event only | `TIER2_PRIORITY` |
//! | [`SyncPll::on_sync0`], ARR table; [`EthercatSlave::cycle`] in DC | [`on_sync0`]: TIM3 CH2 capture of SYNC0 | `TIER2_PRIORITY` |
//! | [`EthercatSlave::cycle`], free run     | `free_run_tick` from the tier-2 slow loop, once per 0x1C32 cycle (on the 400 us grid) | `TIER2_PRIORITY` |
//!
//! Both interrupts have tier 2's priority, so they never preempt the slow loop or each other: the process-data
//! cycle and the slow tick are serialised, as the drive expects (outputs handed over between slow ticks).
//!
//! **Sharing**: the ESC, the slave and the PLL are one `Ethercat` value in a `tier2::Tier2Slot`, reached only
//! inside it and `tier2::with_drive` (BASEPRI at tier 2's priority: tier 1 keeps running). So the SPI bus is never
//! used by two contexts at once and the slave gets the drive exclusively, as `poll`/`cycle` require.
//!
//! **Cycle sources**: when the ESM's synchronisation (PRE-OP -> SAFE-OP) names the mode, the poll sets it up:
//! SM-synchronous: AL event mask 0x0204 = SM2 event only, so SPI_IRQ means "outputs arrived"; DC: mask 0, TIM3's
//! capture interrupt unmasked, the PLL started with the SYNC0 cycle and the ARR DMA stream (started on first
//! use) fed with its pattern; free run: mask 0. Leaving SAFE-OP undoes it (the PLL stops, the table goes back to
//! the nominal period). EXTI0 is edge-triggered while SPI_IRQ is a level: if the line is low when the poll
//! looks (an edge missed while the mask changed), the poll raises EXTI0 by software.
//!
//! **Open points (precise)**:
//! - *Tier-2 latency.* The SPI transfers of a poll or a cycle run inside the tier-2 lock (the slave mixes ESC
//!   access and drive access in one call). They no longer hold tier 1 off, but a poll from tier 3 holds the cycle
//!   interrupts and the slow loop off for its length. At 21 MHz with polled bytes (about 0.5 us each): an idle
//!   poll is about 10 accesses of 5..8 bytes, ~30 us; a mailbox exchange adds the SM0 window read and the SM1
//!   window write (2 x 128 bytes, ~130 us); a cycle with the largest images (40 + 40 bytes) ~45 us; all inside
//!   tier 2's 400 us, but a SYNC0 capture waits up to that long for its handler. Splitting `EthercatSlave` into
//!   an ESC phase and a drive phase would not shorten that wait: the ESC and the drive sit under the same ceiling
//!   (tier 2's priority), which the bus needs as much as the drive does, since the cycle interrupts use the same
//!   SPI bus. What would shorten it is a bus that a poll can yield mid-way: SPI by DMA (DMA2 stream 0/3, SPI1
//!   RX/TX channel 3) with a queue of transfers, the cycle's first in line.
//! - *SYNC0 period index.* TIM3 is reset at TIM1's channel-4 compare (the ADC trigger), `FAST_TICKS` increments
//!   in the ADC interrupt a few us later: a pulse captured in that window is attributed to the previous period.
//!   The PLL's target (the middle of the period) keeps a locked loop 20 us away from it; while acquiring, the
//!   loop's jump detection absorbs a one-period error. A period counter latched by hardware (TIM1's repetition
//!   interrupt, or TIM3's update counted in TIM3's own interrupt) would remove it.
//! - *ESC restart.* The AL event mask is written when the mode changes; an ESC that reloads its EEPROM meanwhile
//!   (mask back to its reset value 0x00FF_FF0F) keeps SPI_IRQ low with mailbox events until the next change.
//! - *Start-up*: nothing here waits for the ESC's EEPROM_LOADED; accesses before it read 0 and the ESM stays in
//!   INIT, which is harmless; the poll simply repeats.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU16, AtomicU32, Ordering};

use cortex_m::peripheral::NVIC;

use super::app;
use super::program::BoardProgram;
use crate::board::esc_spi::{self, Spi1};
use crate::board::interrupt::Interrupt;
use crate::board::sync_timer::{self, ARR_TABLE_LEN};
use crate::boot::program::{Interface, SharedPort};
use crate::drive::objects::DriveObjects;
use crate::drive::Drive;
use crate::ecat::esc::{al_event, Esc};
use crate::ecat::esm::AlState;
use crate::ecat::foe::{FoeSink, NoFoeSink};
use crate::ecat::slave::EthercatSlave;
use crate::ecat::spi_pdi::{Addressing, SpiEsc};
use crate::ecat::sync::SyncMode;
use crate::ecat::sync_pll::{Sync0Capture, SyncPll, DITHER_LEN, NOMINAL_ARR};
use crate::od::access::{ApplicationObjects, NoApplicationObjects};
use crate::recorder::objects::RecorderObjects;

/// AL event mask (u32): which AL event request bits drive SPI_IRQ (ESC datasheet section II, 0x0204).
const AL_EVENT_MASK: u16 = 0x0204;
/// The ESC's local copy of the DC system time, low 32 bits (0x0910): the slave's `now_ns`.
const DC_SYSTEM_TIME: u16 = 0x0910;
/// SM2's bit in the AL event registers (0x0220/0x0204): bit 8 + n.
const SM2_EVENT: u32 = al_event::SM0 << 2;

/// Process-data cycles run (all sources). Writer: the cycle's context (tier-2 priority).
pub static CYCLES: AtomicU32 = AtomicU32::new(0);
/// SYNC0 pulses captured. Writer: [`on_sync0`].
pub static SYNC0_PULSES: AtomicU32 = AtomicU32::new(0);

/// TIM1's ARR, one entry per update event, streamed by DMA2 (in SRAM: a plain static). Nominal until DC mode.
static ARR_TABLE: [AtomicU16; ARR_TABLE_LEN] = [const { AtomicU16::new(NOMINAL_ARR) }; ARR_TABLE_LEN];

/// Everything of the slave that the contexts share (see the module documentation).
struct Ethercat {
    esc: SpiEsc<Spi1>,
    slave: EthercatSlave,
    pll: SyncPll,
    /// The cycle source currently set up (`None` below SAFE-OP).
    mode: Option<SyncMode>,
    /// The free-run cycle in 40 us periods (0 unless free run).
    free_run_periods: u32,
    /// The free-run cycle index the last free-run cycle ran in.
    free_run_last: u32,
    /// DMA2 streams [`ARR_TABLE`] into TIM1's ARR (started on the first DC entry).
    arr_stream: bool,
}

/// The slave's state, placed once by [`start`].
static STATE: super::tier2::Tier2Slot<Ethercat> = super::tier2::Tier2Slot::new();

/// Runs `f` on the slave's state and the drive inside the tier-2 lock (see the module documentation). `None`
/// before [`start`], before tier 2 has the drive, or when nested inside another section that holds either.
fn with_slave<R>(f: impl FnOnce(&mut Ethercat, &mut Drive) -> R) -> Option<R> {
    STATE.with(|slave| super::tier2::with_drive(|drive| f(slave, drive))).flatten()
}

/// Sets the ESC's SPI bus, the PDI interrupt pin and the SYNC0 capture up, and places the slave (INIT). Call once
/// from start-up after board init and before tier 1 starts; the interrupts' priorities are set by the caller.
pub(crate) fn start() {
    let spi = esc_spi::init();
    // TIM3 capture armed, its NVIC entry masked until DC mode.
    sync_timer::init();
    NVIC::mask(Interrupt::Sync0);
    let state = Ethercat {
        // ET1100 and AX58100 alike: the 3-byte address works on both (see `spi_pdi::Addressing`).
        esc: SpiEsc::new(spi, Addressing::Extended),
        slave: EthercatSlave::new(),
        pll: SyncPll::new(),
        mode: None,
        free_run_periods: 0,
        free_run_last: 0,
        arr_stream: false,
    };
    STATE.place(state);
    // SAFETY: the handler's state is in place; unmasking breaks no critical section (none is held here).
    unsafe { NVIC::unmask(Interrupt::EscPdi) };
}

/// Tier 3, every tick: the slave's poll with the drive's application objects (the parameter store for
/// 0x1010/0x1011 when there is one, program control for 0x1F50..0x1F57 and the FoE download in BOOT), then
/// program control's request (`super::program::follow`), the PLL's supervision, the cycle source for the
/// current mode. `now_ms` is tier 3's millisecond clock.
pub(crate) fn poll(params: &mut Option<app::Params>, program: Option<&RefCell<BoardProgram>>, now_ms: u32) {
    let _ = with_slave(|s, drive| {
        let power_stage_enabled = drive.power_stage_enabled();
        let before = s.slave.state();
        // One instance of the slave's code for every case (`dyn`): an instance per objects type would not fit
        // slot A next to the CANopen node.
        let (mut port, mut no_program, mut drive_objects, mut no_objects, mut program_foe);
        let mut no_foe = NoFoeSink;
        let (objects, foe): (&mut dyn ApplicationObjects, &mut dyn FoeSink) = match params.as_mut() {
            Some(store) => {
                // The program port as `dyn` too: one instance of the drive objects' code with or without it.
                let (program_objects, foe): (&mut dyn ApplicationObjects, &mut dyn FoeSink) = match program {
                    Some(program) => {
                        port = SharedPort::new(program, Interface::Ethercat, power_stage_enabled);
                        program_foe = SharedPort::new(program, Interface::Ethercat, power_stage_enabled);
                        (&mut port, &mut program_foe)
                    }
                    None => {
                        no_program = NoApplicationObjects;
                        (&mut no_program, &mut no_foe)
                    }
                };
                drive_objects = DriveObjects::new(store, power_stage_enabled).with_program_control(program_objects);
                (&mut drive_objects, foe)
            }
            None => {
                no_objects = NoApplicationObjects;
                (&mut no_objects, &mut no_foe)
            }
        };
        // The data recorder in front of them (0x3300..0x3302), under the same lock.
        super::tier2::RECORDER.with_or_none(|recorder| {
            let mut recorder_objects;
            let objects: &mut dyn ApplicationObjects = match recorder {
                Some(recorder) => {
                    recorder_objects = RecorderObjects::new(recorder, objects);
                    &mut recorder_objects
                }
                None => objects,
            };
            s.slave.poll_with_foe(&mut s.esc, drive, objects, foe, now_ms);
        });
        if let Some(program) = program {
            // Leaving BOOT after an FoE download (E4 Table 4-29 step D) asks for the reset that activates it.
            if before == AlState::Boot && s.slave.state() != AlState::Boot {
                if let Ok(mut p) = program.try_borrow_mut() {
                    p.leave_bootstrap();
                }
            }
            // The answer is in the ESC's mailbox already (the SPI writes are done): reset at once.
            if super::program::follow(program, drive) {
                super::program::reset();
            }
        }
        s.pll.supervise(super::tier1::FAST_TICKS.load(Ordering::Relaxed));
        s.follow_mode();
        if s.mode == Some(SyncMode::SmSynchronous) && esc_spi::irq_active() {
            esc_spi::pend_irq();
        }
    });
}

/// The tier-2 slow loop, after each slow tick: one free-run cycle when a 0x1C32 cycle boundary was passed since
/// the last one (free run only; the 400 us slow-tick grid is the jitter).
pub(crate) fn free_run_tick() {
    let period = super::tier1::FAST_TICKS.load(Ordering::Relaxed);
    let _ = with_slave(|s, drive| {
        if s.mode != Some(SyncMode::FreeRun) {
            return;
        }
        let index = period.checked_div(s.free_run_periods).unwrap_or(period);
        if index != s.free_run_last {
            s.free_run_last = index;
            s.cycle(drive);
        }
    });
}

/// EXTI0: the ESC's SPI_IRQ (AL event). Only SM2's event is unmasked, and only SM-synchronous.
///
/// # Safety
/// Only the vector table calls this (`rt::vectors`), as the EXTI0 handler.
pub unsafe extern "C" fn on_pdi_irq() {
    esc_spi::acknowledge_irq();
    let _ = with_slave(|s, drive| {
        if s.mode == Some(SyncMode::SmSynchronous) {
            s.cycle(drive);
        }
    });
}

/// TIM3: the SYNC0 capture. The PLL gets the pulse's position in the PWM timebase; in DC mode the cycle runs.
///
/// # Safety
/// Only the vector table calls this (`rt::vectors`), as the TIM3 handler.
pub unsafe extern "C" fn on_sync0() {
    let Some(raw) = sync_timer::take_capture() else {
        return;
    };
    // The count is read after the capture: a new period began in between when TIM3's count is below the pulse's.
    let now = super::tier1::FAST_TICKS.load(Ordering::Relaxed);
    let period = if raw.ticks_now < raw.ticks { now.wrapping_sub(1) } else { now };
    SYNC0_PULSES.store(SYNC0_PULSES.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
    let _ = with_slave(|s, drive| {
        let before = s.pll.trim();
        if s.pll.on_sync0(Sync0Capture { period, ticks: raw.ticks }) != before {
            s.write_pattern();
        }
        if s.mode == Some(SyncMode::DcSync0) {
            s.cycle(drive);
        }
    });
}

impl Ethercat {
    /// One process-data cycle at the ESC's local time.
    fn cycle(&mut self, drive: &mut Drive) {
        let now_ns = self.esc.read_u32(DC_SYSTEM_TIME);
        self.slave.cycle(&mut self.esc, drive, now_ns);
        CYCLES.store(CYCLES.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
    }

    /// The PLL's 64-period pattern into the DMA table.
    fn write_pattern(&self) {
        let mut pattern = [NOMINAL_ARR; DITHER_LEN];
        self.pll.fill_pattern(&mut pattern);
        sync_timer::write_arr_table(&ARR_TABLE, &pattern);
    }

    /// Sets the cycle source up when the ESM's synchronisation changed (module documentation).
    fn follow_mode(&mut self) {
        let sync = self.slave.esm().synchronisation().copied();
        let mode = sync.map(|s| s.mode);
        if mode == self.mode {
            return;
        }
        let mask = if mode == Some(SyncMode::SmSynchronous) { SM2_EVENT } else { 0 };
        self.esc.write(AL_EVENT_MASK, &mask.to_le_bytes());
        match sync {
            Some(sync) if sync.mode == SyncMode::DcSync0 => {
                // The ESM accepted only supported SYNC0 cycles; a refusal here leaves the nominal period.
                if self.pll.start(sync.sync0_cycle_ns).is_ok() {
                    if !self.arr_stream {
                        sync_timer::start_arr_stream(&ARR_TABLE);
                        self.arr_stream = true;
                    }
                    self.write_pattern();
                    // SAFETY: called inside `with_slave` (BASEPRI at tier 2's priority); TIM3 has that priority, so
                    // BASEPRI keeps it out until the section ends, and the section's exclusion holds.
                    unsafe { NVIC::unmask(Interrupt::Sync0) };
                }
            }
            _ => {
                NVIC::mask(Interrupt::Sync0);
                self.pll.stop();
                sync_timer::write_arr_table(&ARR_TABLE, &[NOMINAL_ARR; DITHER_LEN]);
            }
        }
        self.free_run_periods = match sync {
            Some(sync) if sync.mode == SyncMode::FreeRun => sync.current_periods,
            _ => 0,
        };
        self.mode = mode;
    }
}
