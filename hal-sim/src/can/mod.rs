//! The simulated CAN side of the drive: the bus with frame timing and injected errors ([`bus`]), the bit-level
//! frame length it uses ([`timing`]), and the socketcand TCP front end through which python-can tools join the
//! bus ([`socketcand`]). The frame type is the firmware's ([`CanFrame`]), so frames pass between the node and
//! the bus unchanged.

pub mod bus;
pub mod socketcand;
pub mod timing;

pub use firmware::canopen::frame::CanFrame;
