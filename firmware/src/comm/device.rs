//! What a fieldbus stack needs of the device it serves: its object dictionary, and the few events a fieldbus
//! causes in a CiA 402 device. The CANopen node (`canopen`) and the EtherCAT slave (`ecat`) work against this
//! trait, not against the drive, so that each is testable alone and serves any device (a second axis, a test
//! double) that implements it; `drive::Drive` is the implementation the firmware uses.

use crate::od::access::Dictionary;
use crate::supervision::communication::LinkLoss;

/// Object access and drive events for a fieldbus stack.
pub trait FieldbusDevice {
    /// The object dictionary, to read (SDO upload, TPDO and SM3 packing, the stack's own configuration).
    fn dictionary(&self) -> &Dictionary;

    /// The object dictionary, to write (SDO download, RPDO and SM2 unpacking, the stack's own status objects).
    fn dictionary_mut(&mut self) -> &mut Dictionary;

    /// Whether the power stage is enabled (or about to be): the write conditions "power disabled" of the
    /// dictionary, and the parameter store's refusal to erase flash while the motor is driven.
    fn power_stage_enabled(&self) -> bool;

    /// New set-points were written into the dictionary by process data (an RPDO, the SM2 outputs): the device
    /// takes them now (CiA 402 cyclic modes: one set-point per master cycle).
    fn setpoint_received(&mut self);

    /// The fieldbus is (or is no longer) in the state that lets it command the device (CANopen operational,
    /// EtherCAT OP): the statusword's "remote" bit 9.
    fn set_remote(&mut self, remote: bool);

    /// The link was lost (heartbeat, process-data or SYNC timeout, EtherCAT watchdog, a PDO of the wrong length):
    /// the device reacts as 0x6007 selects.
    fn communication_lost(&mut self, loss: LinkLoss);

    /// The link of an earlier [`Self::communication_lost`] is back (the fault's cause has gone).
    fn communication_restored(&mut self, loss: LinkLoss);

    /// The next emergency message to send (CiA 301, 8 bytes), or `None`; the device respects the inhibit time.
    fn poll_emcy(&mut self) -> Option<[u8; 8]>;

    /// An NMT reset node: the power stage to a safe state before the reset (outputs off, the motor coasts).
    fn shutdown(&mut self);
}
