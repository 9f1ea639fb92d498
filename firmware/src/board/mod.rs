//! The STM32F405 reference board (target only): clock tree, power-stage PWM, current/voltage sampling, encoder,
//! Halls, the interrupt table and the cost counter. Direct register access at RM0090 addresses ([`reg`]); no
//! vendor crate. The drive logic stays in the pure library: this module only moves [`Measurements`] in and
//! [`PwmCommand`] out ([`PowerStage`]).
//!
//! Pin map of the reference board:
//!
//! | function                    | pins                   | peripheral                     |
//! |-----------------------------|------------------------|--------------------------------|
//! | high-side gates A/B/C       | PA8, PA9, PA10 (AF1)   | TIM1 CH1..3                    |
//! | low-side gates A/B/C        | PB13, PB14, PB15 (AF1) | TIM1 CH1N..3N                  |
//! | over-current break          | PB12 (AF1)             | TIM1 BKIN                      |
//! | phase shunts A/B/C          | PC0, PC1, PC2 (analog) | ADC1/2/3 IN10/11/12 (injected) |
//! | DC-bus voltage, temperature | PC3, PC4 (analog)      | ADC1 IN13, ADC2 IN14           |
//! | motor temperature sensor    | PA3 (analog)           | ADC3 IN3                       |
//! | encoder A/B, index          | PB6, PB7, PB8 (AF2)    | TIM4 CH1/CH2 (encoder), CH3    |
//! | load encoder A/B (sensor 2) | PA0, PA1 (AF2)         | TIM5 CH1/CH2 (load_encoder)    |
//! | Halls H1/H2/H3              | PC6, PC7, PC8 (inputs) | GPIOC IDR                      |
//! | digital inputs 1..4         | PC9..PC12 (inputs)     | GPIOC IDR                      |
//! | STO-IN1/IN2 feedback        | PB10, PB11 (inputs)    | GPIOB IDR (sto, tier 2)        |
//! | SYNC0 from the ESC          | PB5 (AF2)              | TIM3 CH2 capture (sync_timer)  |
//! | CAN RX/TX (transceiver)     | PA11, PA12 (AF9)       | CAN1 (can)                     |
//! | ESC SPI SEL/CLK/DO/DI       | PA4 (out), PA5..7 (AF5)| SPI1 (esc_spi, `ethercat`)     |
//! | ESC SPI_IRQ (AL event)      | PB0 (input)            | EXTI0 (esc_spi, `ethercat`)    |
//! | braking chopper gate        | PB1 (output)           | GPIOB BSRR (chopper)           |
//! | SSI clock / data            | PB3, PB4 (AF6)         | SPI3 SCK/MISO, DMA1 S0 (ssi)   |
//!
//! With the `qemu` feature (QEMU's `netduinoplus2`, which models neither the RCC nor these peripherals) [`init`]
//! only starts the cost counter, and [`PowerStage`] is fed by a small built-in motor model (`plant`, present only in that build).

pub mod adc;
pub mod boot;
pub mod can;
pub mod chopper;
pub mod clock;
pub mod counter;
#[cfg(not(feature = "qemu"))]
pub mod device_id;
#[cfg(feature = "ethercat")]
pub mod esc_spi;
pub mod feedback;
pub mod flash;
pub mod interrupt;
pub mod load_encoder;
pub mod pwm;
pub mod reg;
pub mod ssi;
pub mod sto;
pub mod sync_timer;
pub mod watchdog;

#[cfg(feature = "qemu")]
pub mod period_timer;
#[cfg(feature = "qemu")]
pub mod plant;
#[cfg(feature = "qemu")]
pub mod semihosting;

pub use clock::ClockError;

use crate::hal::power::{Measurements, PwmCommand};

/// The board after [`init`]: owns the peripherals the tiers use.
#[derive(Debug)]
pub struct Board {
    /// Power stage and its sensors: tier 1 owns it.
    pub power: PowerStage,
}

/// What tier 1 reads and writes once per PWM period: ADC results, encoder, Halls, break flag in; duties and
/// main output enable out.
#[derive(Debug)]
pub struct PowerStage {
    #[cfg(feature = "qemu")]
    plant: plant::Plant,
    #[cfg(not(feature = "qemu"))]
    _owned: (),
}

impl PowerStage {
    /// Reads everything tier 1 needs, sampled at this period's PWM centre. Acknowledges the ADC interrupt.
    #[inline(always)]
    pub fn read(&mut self) -> Measurements {
        #[cfg(not(feature = "qemu"))]
        {
            Measurements { adc: adc::read(), feedback: feedback::read(), break_input: pwm::take_break() }
        }
        #[cfg(feature = "qemu")]
        {
            self.plant.measure()
        }
    }

    /// Applies a command from the next PWM update on. [`PwmCommand::OFF`] clears MOE: all switches off.
    #[inline(always)]
    pub fn write(&mut self, cmd: &PwmCommand) {
        #[cfg(not(feature = "qemu"))]
        pwm::write(cmd);
        #[cfg(feature = "qemu")]
        self.plant.step(cmd);
    }
}

/// The safe state, from any context (panic, fault, unexpected interrupt): PWM main output off.
#[inline(always)]
pub fn safe_state() {
    #[cfg(not(feature = "qemu"))]
    pwm::disable();
}

/// Brings the board up: clocks to 168 MHz, peripheral clocks, pins, TIM1 (running, outputs off), ADCs (armed),
/// encoder timer, cost counter. Interrupts stay masked in the NVIC; `rt` enables them.
pub fn init() -> Result<Board, ClockError> {
    #[cfg(not(feature = "qemu"))]
    {
        clock::init()?;
        enable_peripheral_clocks();
        // TIM1 first: when the gate pins switch to TIM1 they are already driven to the off level.
        pwm::init();
        init_pins();
        chopper::init();
        adc::init();
        feedback::init();
        load_encoder::init();
        sto::init();
        counter::init();
        Ok(Board { power: PowerStage { _owned: () } })
    }
    #[cfg(feature = "qemu")]
    {
        counter::init();
        Ok(Board { power: PowerStage { plant: plant::Plant::new() } })
    }
}

#[cfg(not(feature = "qemu"))]
fn enable_peripheral_clocks() {
    use reg::rcc;
    rcc::AHB1ENR.modify(0, 0b111); // GPIOA, GPIOB, GPIOC
    rcc::APB2ENR.modify(0, 1 | (0b111 << 8)); // TIM1, ADC1..3
    rcc::APB1ENR.modify(0, 1 << 2); // TIM4

    // Read back once: the clock enable takes effect after a bus cycle (RM0090 section 6.3.10 note).
    let _ = rcc::APB1ENR.read();
}

/// GPIO modes (MODER encoding).
#[cfg(not(feature = "qemu"))]
#[derive(Clone, Copy)]
enum Mode {
    Input = 0b00,
    Alternate = 0b10,
    Analog = 0b11,
}

#[cfg(not(feature = "qemu"))]
fn pin(port: reg::Gpio, n: u32, mode: Mode, af: u32) {
    let two = n.wrapping_mul(2);
    port.moder().modify(0b11 << two, (mode as u32) << two);
    if let Mode::Alternate = mode {
        port.ospeedr().modify(0b11 << two, 0b10 << two); // fast: clean gate edges without ringing
        let (afr, shift) =
            if n < 8 { (port.afrl(), n.wrapping_mul(4)) } else { (port.afrh(), n.wrapping_sub(8).wrapping_mul(4)) };
        afr.modify(0xF << shift, af << shift);
    }
    if let Mode::Input = mode {
        port.pupdr().modify(0b11 << two, 0b01 << two); // pull-up (open-collector Hall outputs)
    }
}

#[cfg(not(feature = "qemu"))]
fn init_pins() {
    use reg::{base, Gpio};
    let (a, b, c) = (Gpio(base::GPIOA), Gpio(base::GPIOB), Gpio(base::GPIOC));
    // TIM1 already runs with MOE = 0 and OSSI = 1: the gates are held off from the moment they connect.
    for n in [8, 9, 10] {
        pin(a, n, Mode::Alternate, 1);
    }
    for n in [12, 13, 14, 15] {
        pin(b, n, Mode::Alternate, 1);
    }
    for n in [6, 7, 8] {
        pin(b, n, Mode::Alternate, 2);
    }
    for n in 0..=4 {
        pin(c, n, Mode::Analog, 0);
    }
    pin(a, 3, Mode::Analog, 0); // motor temperature sensor (ADC3 IN3); the pull-down is on the board
                                // Halls, then the digital inputs 1..4.
    for n in [6, 7, 8, 9, 10, 11, 12] {
        pin(c, n, Mode::Input, 0);
    }
}
