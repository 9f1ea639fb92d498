//! The drive as the device the fieldbus stacks serve ([`FieldbusDevice`]): each event goes to the drive's own
//! method of the same name.

use super::Drive;
use crate::comm::device::FieldbusDevice;
use crate::od::access::Dictionary;
use crate::supervision::communication::LinkLoss;

impl FieldbusDevice for Drive {
    fn dictionary(&self) -> &Dictionary {
        Drive::dictionary(self)
    }

    fn dictionary_mut(&mut self) -> &mut Dictionary {
        Drive::dictionary_mut(self)
    }

    fn power_stage_enabled(&self) -> bool {
        Drive::power_stage_enabled(self)
    }

    fn setpoint_received(&mut self) {
        Drive::setpoint_received(self);
    }

    fn set_remote(&mut self, remote: bool) {
        Drive::set_remote(self, remote);
    }

    fn communication_lost(&mut self, loss: LinkLoss) {
        Drive::communication_lost(self, loss);
    }

    fn communication_restored(&mut self, loss: LinkLoss) {
        Drive::communication_restored(self, loss);
    }

    fn poll_emcy(&mut self) -> Option<[u8; 8]> {
        Drive::poll_emcy(self)
    }

    fn shutdown(&mut self) {
        Drive::shutdown(self);
    }
}
