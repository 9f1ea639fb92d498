//! The EtherCAT application layer of the drive, over a narrow [`esc::Esc`] trait (register and process-RAM read
//! and write from the PDI side), so the same code runs on `hal-sim`'s emulated ESC and, through a board driver,
//! on an SPI ESC chip (LAN9252 / AX58100 class).
//!
//! Module map:
//! - [`esc`]: the [`esc::Esc`] trait, the ESC register addresses the firmware uses, the sync-manager
//!   configuration as the firmware reads it, and the AL status codes ([`esc::AlStatusCode`]).
//! - [`esm`]: the EtherCAT state machine INIT, PRE-OP, SAFE-OP, OP, BOOT with the checks of each transition.
//! - [`mailbox`]: the mailbox on SM0/SM1: header, counter and repeat rules, mailbox error replies.
//! - [`coe`]: CoE over the mailbox: SDO (the shared [`crate::comm::sdo::coe::CoeSdoServer`]), the SDO information
//!   service, emergencies.
//! - [`foe`]: FoE read/write requests, accepted only in BOOT and handed to a [`foe::FoeSink`].
//! - [`process_data`]: the PDO mapping and assignment validated as a whole, and the process images packed and
//!   unpacked through the dictionary without searching.
//! - [`slave`]: [`slave::EthercatSlave`], the drive as a slave: the above tied to the device
//!   ([`crate::comm::device::FieldbusDevice`]).
//! - [`sync`]: the synchronisation objects 0x1C32/0x1C33 (free run, SM-synchronous, DC SYNC0) and their checks.
//! - [`sync_pll`]: the DC phase-locked loop that locks the PWM period to SYNC0.
//! - [`spi_pdi`]: the ET1100/AX58100-class SPI PDI: the framing of an access and [`spi_pdi::SpiEsc`], the
//!   [`esc::Esc`] over a board's SPI bus.

pub mod coe;
pub mod esc;
pub mod esm;
pub mod foe;
pub mod mailbox;
pub mod process_data;
pub mod slave;
pub mod spi_pdi;
pub mod sync;
pub mod sync_pll;
