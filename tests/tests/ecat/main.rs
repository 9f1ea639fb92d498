//! The EtherCAT slave in-process: the state machine, the mailbox and CoE, process data, the SPI PDI, the SYNC0 loop,
//! and random input.
//!
//! One test binary for the area; each module is one of its test files.

mod esm;
mod fuzz;
mod mailbox;
mod process_data;
mod recorder;
mod slave;
mod spi_pdi;
mod sync_pll;
