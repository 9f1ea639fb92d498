//! The firmware's view of the emulated ESC: [`firmware::ecat::esc::Esc`] over the PDI accessors
//! ([`Esc::pdi_read`](super::Esc::pdi_read) / [`Esc::pdi_write`](super::Esc::pdi_write)), so the firmware's
//! EtherCAT application layer runs on the emulation exactly as it runs on an SPI ESC through the board driver:
//! register reads with their side effects (reading 0x0120 clears the AL control event, reading an SM activate
//! register the SM-activation event), PDI write masks (only AL status/code, AL event mask, SM PDI control and
//! user RAM change), and the sync managers' buffer rules for the process RAM.

use firmware::ecat::esc::Esc as PdiEsc;

impl PdiEsc for super::Esc {
    fn read(&mut self, address: u16, buf: &mut [u8]) {
        self.pdi_read(address, buf);
    }

    fn write(&mut self, address: u16, data: &[u8]) {
        self.pdi_write(address, data);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_trait_reads_and_writes_through_the_pdi_with_its_side_effects() {
        let mut esc = super::super::Esc::with_drive_sii().expect("drive SII");
        // The PDI may write AL status, not the station address (PDI write mask).
        PdiEsc::write_u16(&mut esc, 0x0130, 0x0002);
        PdiEsc::write_u16(&mut esc, 0x0010, 0x1234);
        assert_eq!(esc.register_u16(0x0130), 0x0002);
        assert_eq!(esc.register_u16(0x0010), 0x0000);
        assert_eq!(PdiEsc::read_u16(&mut esc, 0x0130), 0x0002);
    }
}
