//! Communication: wire formats and protocol state machines shared by the CANopen and EtherCAT front ends.
//!
//! Every protocol here is sans-IO (ARCHITECTURE convention 1): it takes the bytes received and the time, and
//! returns the bytes to send; the bus drivers own the hardware. The stacks reach the device through
//! [`device::FieldbusDevice`].

pub mod device;
pub mod pdo;
pub mod sdo;
