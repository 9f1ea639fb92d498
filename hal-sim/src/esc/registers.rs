//! The ESC register file (0x0000..=0x0FFF): addresses, reset values and who may write which bit.
//!
//! Register addresses and layouts follow the EtherCAT slave controller datasheets (Beckhoff "EtherCAT Slave
//! Controller, Section II – Register Description", the ET1100/ET1200/IP-core register map; the same map is
//! normative in ETG.1000.4 §6 "DL management" tables). The reset values marked "spec file" are the values
//! the project's throwaway emulator used with SOEM, ethercrab and KickCAT
//! (`shared/spec/fieldbus-real-masters.md`, "Behaviour an emulated ESC had to get right").

/// Register addresses (ESC datasheet section II, ETG.1000.4 Table 31 ff.).
pub mod reg {
    /// ESC type (u8). 0x04 per the spec file.
    pub const TYPE: u16 = 0x0000;
    /// ESC revision (u8).
    pub const REVISION: u16 = 0x0001;
    /// ESC build (u16).
    pub const BUILD: u16 = 0x0002;
    /// Number of supported FMMU channels (u8).
    pub const FMMU_COUNT: u16 = 0x0004;
    /// Number of supported sync managers (u8).
    pub const SM_COUNT: u16 = 0x0005;
    /// Process RAM size in KiB (u8).
    pub const RAM_SIZE: u16 = 0x0006;
    /// Port descriptor (u8): two bits per port, 0b11 = MII.
    pub const PORT_DESC: u16 = 0x0007;
    /// ESC features supported (u16): bit 2 DC, bit 3 64-bit DC.
    pub const FEATURES: u16 = 0x0008;
    /// Configured station address (u16), ECAT read/write.
    pub const STATION_ADDRESS: u16 = 0x0010;
    /// Configured station alias (u16), loaded from SII word 4; PDI read/write, ECAT read-only.
    pub const STATION_ALIAS: u16 = 0x0012;
    /// DL control (u32); byte 0x0103 bit 0 enables the station alias for FP addressing.
    pub const DL_CONTROL: u16 = 0x0100;
    /// DL control byte 3 (alias enable in bit 0).
    pub const DL_CONTROL_ALIAS: u16 = 0x0103;
    /// DL status (u16), read-only.
    pub const DL_STATUS: u16 = 0x0110;
    /// AL control (u16): written by the master, read by the PDI (the read clears the AL control event).
    pub const AL_CONTROL: u16 = 0x0120;
    /// AL status (u16): written by the PDI, read-only for the master.
    pub const AL_STATUS: u16 = 0x0130;
    /// AL status code (u16): written by the PDI, read-only for the master.
    pub const AL_STATUS_CODE: u16 = 0x0134;
    /// PDI control (u8), loaded from SII word 0 low byte.
    pub const PDI_CONTROL: u16 = 0x0140;
    /// ESC configuration (u8), loaded from SII word 0 high byte.
    pub const ESC_CONFIG: u16 = 0x0141;
    /// PDI configuration (u16), loaded from SII word 1; 0x0151 bit 3 maps SYNC0 to AL event bit 2.
    pub const PDI_CONFIG: u16 = 0x0150;
    /// Extended PDI configuration (u16), loaded from SII word 3.
    pub const PDI_CONFIG_EXT: u16 = 0x0152;
    /// ECAT event mask (u16), ECAT read/write.
    pub const ECAT_EVENT_MASK: u16 = 0x0200;
    /// AL event mask (u32), PDI read/write.
    pub const AL_EVENT_MASK: u16 = 0x0204;
    /// ECAT event request (u16), read-only; OR-ed (masked) into each datagram's IRQ field.
    pub const ECAT_EVENT_REQUEST: u16 = 0x0210;
    /// AL event request (u32), read-only; the PDI's interrupt sources (see [`al_event`](super::al_event)).
    pub const AL_EVENT_REQUEST: u16 = 0x0220;
    /// RX error counters (0x0300..=0x030B); any write clears them. 0x0300 = invalid frame counter port 0.
    pub const RX_ERROR_COUNTER: u16 = 0x0300;
    /// RX error counter port 0 (u8) (physical layer errors inside a frame).
    pub const RX_ERROR_PORT0: u16 = 0x0301;
    /// Watchdog divider (u16): watchdog tick = (divider + 2) x 40 ns.
    pub const WATCHDOG_DIVIDER: u16 = 0x0400;
    /// PDI watchdog time (u16) in watchdog ticks.
    pub const WATCHDOG_TIME_PDI: u16 = 0x0410;
    /// Process data watchdog time (u16) in watchdog ticks.
    pub const WATCHDOG_TIME_PD: u16 = 0x0420;
    /// Process data watchdog status (u16): bit 0 = 1 active (triggered in time), 0 = expired or never
    /// triggered. A PDI read clears the AL event request bit 6.
    pub const WATCHDOG_STATUS_PD: u16 = 0x0440;
    /// Process data watchdog expiry counter (u8, saturating; any write clears it).
    pub const WATCHDOG_COUNTER_PD: u16 = 0x0442;
    /// PDI watchdog expiry counter (u8, saturating; any write clears it).
    pub const WATCHDOG_COUNTER_PDI: u16 = 0x0443;
    /// SII EEPROM configuration (u8): bit 0 = EEPROM assigned to the PDI.
    pub const SII_CONFIG: u16 = 0x0500;
    /// SII EEPROM PDI access state (u8).
    pub const SII_PDI_ACCESS: u16 = 0x0501;
    /// SII EEPROM control/status (u16).
    pub const SII_CONTROL: u16 = 0x0502;
    /// SII EEPROM word address (u32).
    pub const SII_ADDRESS: u16 = 0x0504;
    /// SII EEPROM data (8 bytes read, 2 bytes written).
    pub const SII_DATA: u16 = 0x0508;
    /// First FMMU (16 bytes each).
    pub const FMMU0: u16 = 0x0600;
    /// First sync manager (8 bytes each).
    pub const SM0: u16 = 0x0800;
    /// DC receive time port 0 (u32); a write of any byte of 0x0900..=0x0903 latches the receive times.
    pub const DC_RECEIVE_TIME_PORT0: u16 = 0x0900;
    /// DC receive time port 1 (u32).
    pub const DC_RECEIVE_TIME_PORT1: u16 = 0x0904;
    /// DC system time (u64): read = local time + offset; write = input of the time control loop.
    pub const DC_SYSTEM_TIME: u16 = 0x0910;
    /// DC local time of the frame that latched the receive times, at the processing unit (u64).
    pub const DC_RECEIVE_TIME_PU: u16 = 0x0918;
    /// DC system time offset (u64).
    pub const DC_SYSTEM_TIME_OFFSET: u16 = 0x0920;
    /// DC system time delay (u32).
    pub const DC_SYSTEM_TIME_DELAY: u16 = 0x0928;
    /// DC system time difference (u32): bit 31 = local copy smaller than received, bits 30..0 magnitude.
    pub const DC_SYSTEM_TIME_DIFF: u16 = 0x092C;
    /// DC speed counter start (u16).
    pub const DC_SPEED_COUNTER_START: u16 = 0x0930;
    /// DC speed counter difference (u16).
    pub const DC_SPEED_COUNTER_DIFF: u16 = 0x0932;
    /// DC system time difference filter depth (u8).
    pub const DC_TIME_FILTER_DEPTH: u16 = 0x0934;
    /// DC speed counter filter depth (u8).
    pub const DC_SPEED_FILTER_DEPTH: u16 = 0x0935;
    /// DC cyclic unit control (u8): bit 0 = SYNC out unit assigned to the PDI.
    pub const DC_CYCLIC_UNIT_CONTROL: u16 = 0x0980;
    /// DC activation (u8): bit 0 cyclic operation, bit 1 SYNC0, bit 2 SYNC1.
    pub const DC_ACTIVATION: u16 = 0x0981;
    /// DC SYNC pulse length (u16) in 10 ns, loaded from SII word 2.
    pub const DC_PULSE_LENGTH: u16 = 0x0982;
    /// DC activation status (u8): bit 0 first SYNC0 pulse pending.
    pub const DC_ACTIVATION_STATUS: u16 = 0x0984;
    /// DC SYNC0 status (u8): bit 0 set by a SYNC0 pulse, cleared by a PDI read.
    pub const DC_SYNC0_STATUS: u16 = 0x098E;
    /// DC SYNC1 status (u8).
    pub const DC_SYNC1_STATUS: u16 = 0x098F;
    /// DC start time of cyclic operation (u64): write = start time; read = system time of the next SYNC0 pulse.
    pub const DC_START_TIME: u16 = 0x0990;
    /// DC next SYNC1 pulse (u64).
    pub const DC_NEXT_SYNC1: u16 = 0x0998;
    /// DC SYNC0 cycle time (u32) in ns; 0 = single shot.
    pub const DC_SYNC0_CYCLE: u16 = 0x09A0;
    /// DC SYNC1 cycle time (u32) in ns.
    pub const DC_SYNC1_CYCLE: u16 = 0x09A4;
    /// First byte of the process RAM.
    pub const RAM_START: u16 = 0x1000;
}

/// Bits of the AL event request register 0x0220 (ESC datasheet section II, register 0x0220).
pub mod al_event {
    /// AL control register written by the master; cleared by a PDI read of 0x0120.
    pub const AL_CONTROL: u32 = 1 << 0;
    /// DC latch event.
    pub const DC_LATCH: u32 = 1 << 1;
    /// SYNC0 (mirror of 0x098E bit 0 when 0x0151 bit 3 maps it); cleared by a PDI read of 0x098E.
    pub const SYNC0: u32 = 1 << 2;
    /// SYNC1.
    pub const SYNC1: u32 = 1 << 3;
    /// An SM activation register (0x0806 + 8n) changed; cleared by a PDI read of an SM activation register.
    pub const SM_ACTIVATION: u32 = 1 << 4;
    /// EEPROM emulation command pending (never set: the EEPROM is not emulated by the PDI).
    pub const EEPROM_EMULATION: u32 = 1 << 5;
    /// Process data watchdog expired; cleared by a PDI read of 0x0440.
    pub const WATCHDOG_PD: u32 = 1 << 6;

    /// Sync manager `n` interrupt (the master completed its buffer access); cleared when the PDI opens the
    /// buffer (accesses its first byte).
    pub const fn sm(n: usize) -> u32 {
        1 << (8 + (n & 0xF))
    }
}

/// Bits of the ECAT event request register 0x0210.
pub mod ecat_event {
    /// DC latch.
    pub const DC_LATCH: u16 = 1 << 0;
    /// DL status changed.
    pub const DL_STATUS: u16 = 1 << 2;
    /// AL status written by the PDI; cleared by an ECAT read of 0x0130.
    pub const AL_STATUS: u16 = 1 << 3;

    /// Sync manager `n` (0..8) interrupt: the PDI completed its buffer access.
    pub const fn sm(n: usize) -> u16 {
        1 << (4 + (n & 0x7))
    }
}

/// AL state values of the low nibble of 0x0120/0x0130 (ETG.1000.6 §6.4.1, Table 11).
pub mod al_state {
    /// INIT.
    pub const INIT: u16 = 0x01;
    /// PRE-OPERATIONAL.
    pub const PREOP: u16 = 0x02;
    /// BOOTSTRAP.
    pub const BOOT: u16 = 0x03;
    /// SAFE-OPERATIONAL.
    pub const SAFEOP: u16 = 0x04;
    /// OPERATIONAL.
    pub const OP: u16 = 0x08;
    /// AL status: error indicator; AL control: error acknowledge.
    pub const ERROR: u16 = 0x10;
    /// State mask of the low nibble.
    pub const MASK: u16 = 0x0F;
}

/// Number of FMMUs the emulated ESC implements (0x0004).
pub const FMMU_COUNT: usize = 8;
/// Number of sync managers the emulated ESC implements (0x0005).
pub const SM_COUNT: usize = 8;
/// Process RAM size in bytes (0x1000..=0x2FFF).
pub const RAM_BYTES: usize = 8 * 1024;
/// Size of the register file.
pub const REGISTER_BYTES: usize = 0x1000;

/// ESC type reported in 0x0000 (spec file: 0x04).
pub const ESC_TYPE: u8 = 0x04;
/// Port descriptor 0x0007: ports 0 and 1 MII, ports 2 and 3 not implemented (spec file: 0x0F).
pub const PORT_DESCRIPTOR: u8 = 0x0F;
/// Features 0x0008: bit 2 DC, bit 3 64-bit DC; bit 0 = 0 means FMMUs are bit-oriented (spec file: 0x000C).
pub const FEATURES: u16 = 0x000C;
/// DL status 0x0110 (spec file: 0x5613): PDI operational (bit 0), PDI watchdog reloaded (bit 1), link on port
/// 0 (bit 4), communication on port 0 (bit 9), loops of ports 1, 2, 3 closed (bits 10, 12, 14). SOEM derives
/// the topology from bits 8..15.
pub const DL_STATUS: u16 = 0x5613;
/// DL status bit 1: PDI watchdog reloaded (0 = expired).
pub const DL_STATUS_PDI_WATCHDOG: u16 = 0x0002;
/// DL status 0x0110 bit 5: physical link on port 1.
pub const DL_STATUS_PORT1_LINK: u16 = 0x0020;
/// DL status 0x0110 bit 10: loop of port 1 closed.
pub const DL_STATUS_PORT1_LOOP_CLOSED: u16 = 0x0400;
/// DL status 0x0110 bit 11: communication established on port 1.
pub const DL_STATUS_PORT1_COMMUNICATION: u16 = 0x0800;
/// Watchdog divider reset value: 2498 = 100 us ticks ((2498 + 2) x 40 ns).
pub const WATCHDOG_DIVIDER_RESET: u16 = 0x09C2;
/// Watchdog time reset value (PDI and process data): 1000 ticks = 100 ms with the reset divider.
pub const WATCHDOG_TIME_RESET: u16 = 0x03E8;
/// AL event mask reset value (ESC datasheet: 0x00FF_FF0F).
pub const AL_EVENT_MASK_RESET: u32 = 0x00FF_FF0F;

/// The writable bits of the register byte at `addr` for the master (ECAT side). 0 = read-only or reserved:
/// the write is ignored (but still counts in the working counter, as on a real ESC).
pub fn ecat_write_mask(addr: u16) -> u8 {
    match addr {
        0x0010..=0x0011 => 0xFF,
        0x0020..=0x0031 => 0xFF, // register/ESC write enable and protection: stored, not enforced
        0x0100..=0x0103 => 0xFF,
        0x0108..=0x0109 => 0xFF,
        0x0120..=0x0121 => 0xFF,
        0x0138..=0x0139 => 0xFF,
        0x0200..=0x0201 => 0xFF,
        0x0300..=0x0313 => 0xFF, // write clears (handled by the engine)
        0x0400..=0x0401 | 0x0410..=0x0411 | 0x0420..=0x0421 => 0xFF,
        0x0442..=0x0443 => 0xFF, // write clears
        0x0500 => 0x03,
        0x0502 => 0x01,          // bit 0 write enable
        0x0503 => 0x07,          // bits 8..10 command
        0x0504..=0x050F => 0xFF, // address and data
        0x0510..=0x0517 => 0xFF, // MII management: stored, no PHY behind it
        0x0600..=0x067F => fmmu_byte_mask(addr),
        0x0800..=0x083F => sm_ecat_byte_mask(addr),
        0x0900..=0x0903 => 0xFF, // latch trigger (the engine replaces the bytes by the latched times)
        0x0910..=0x0917 => 0xFF, // system time write (the engine consumes it)
        0x0920..=0x092B => 0xFF,
        0x0930..=0x0931 | 0x0934..=0x0935 => 0xFF,
        0x0980..=0x0981 => 0xFF,
        0x0990..=0x0997 => 0xFF,
        0x09A0..=0x09A7 => 0xFF,
        0x09A8..=0x09A9 => 0xFF,
        0x0F00..=0x0F03 => 0xFF, // digital outputs
        0x0F80..=0x0FFF => 0xFF, // user RAM
        _ => 0,
    }
}

/// The writable bits of the register byte at `addr` for the PDI (the firmware).
pub fn pdi_write_mask(addr: u16) -> u8 {
    match addr {
        0x0012..=0x0013 => 0xFF,
        0x0130..=0x0131 => 0xFF,
        0x0134..=0x0135 => 0xFF,
        0x0204..=0x0207 => 0xFF,
        0x0800..=0x083F if addr & 7 == 7 => 0x03, // SM PDI control: deactivate, repeat ack
        0x0F80..=0x0FFF => 0xFF,
        _ => 0,
    }
}

fn fmmu_byte_mask(addr: u16) -> u8 {
    match addr & 0xF {
        0x0..=0x5 | 0x8..=0x9 => 0xFF,
        0x6 | 0x7 | 0xA => 0x07,
        0xB => 0x03,
        0xC => 0x01,
        _ => 0,
    }
}

fn sm_ecat_byte_mask(addr: u16) -> u8 {
    match addr & 7 {
        0..=3 => 0xFF,
        4 => 0x7F,
        6 => 0xC3, // enable, repeat request, latch ECAT/PDI
        _ => 0,    // 5 status, 7 PDI control: read-only
    }
}

/// Register reset values that are not zero, before the SII configuration area is loaded.
pub fn reset_registers(regs: &mut [u8; REGISTER_BYTES]) {
    regs.fill(0);
    regs[usize::from(reg::TYPE)] = ESC_TYPE;
    regs[usize::from(reg::REVISION)] = 0x01;
    regs[usize::from(reg::FMMU_COUNT)] = FMMU_COUNT as u8;
    regs[usize::from(reg::SM_COUNT)] = SM_COUNT as u8;
    regs[usize::from(reg::RAM_SIZE)] = (RAM_BYTES / 1024) as u8;
    regs[usize::from(reg::PORT_DESC)] = PORT_DESCRIPTOR;
    put_u16(regs, reg::FEATURES, FEATURES);
    regs[usize::from(reg::DL_CONTROL)] = 0x01; // forwarding rule: non-EtherCAT frames destroyed
    put_u16(regs, reg::DL_STATUS, DL_STATUS);
    put_u16(regs, reg::AL_CONTROL, al_state::INIT);
    put_u16(regs, reg::AL_STATUS, al_state::INIT);
    put_u32(regs, reg::AL_EVENT_MASK, AL_EVENT_MASK_RESET);
    put_u16(regs, reg::WATCHDOG_DIVIDER, WATCHDOG_DIVIDER_RESET);
    put_u16(regs, reg::WATCHDOG_TIME_PDI, WATCHDOG_TIME_RESET);
    put_u16(regs, reg::WATCHDOG_TIME_PD, WATCHDOG_TIME_RESET);
    regs[usize::from(reg::DC_TIME_FILTER_DEPTH)] = 0x04;
    regs[usize::from(reg::DC_SPEED_FILTER_DEPTH)] = 0x0C;
    put_u16(regs, reg::DC_SPEED_COUNTER_START, 0x1000);
}

/// Little-endian helpers on the register file; addresses past the end read as 0 and are not written.
pub fn get_u16(regs: &[u8], addr: u16) -> u16 {
    u16::from_le_bytes([byte(regs, addr, 0), byte(regs, addr, 1)])
}

/// Reads a little-endian u32 at `addr`.
pub fn get_u32(regs: &[u8], addr: u16) -> u32 {
    u32::from_le_bytes([byte(regs, addr, 0), byte(regs, addr, 1), byte(regs, addr, 2), byte(regs, addr, 3)])
}

/// Reads a little-endian u64 at `addr`.
pub fn get_u64(regs: &[u8], addr: u16) -> u64 {
    u64::from(get_u32(regs, addr)) | u64::from(get_u32(regs, addr.wrapping_add(4))) << 32
}

fn byte(regs: &[u8], addr: u16, k: u16) -> u8 {
    regs.get(usize::from(addr) + usize::from(k)).copied().unwrap_or(0)
}

/// Writes `v` little-endian at `addr`.
pub fn put_u16(regs: &mut [u8], addr: u16, v: u16) {
    put(regs, addr, &v.to_le_bytes());
}

/// Writes `v` little-endian at `addr`.
pub fn put_u32(regs: &mut [u8], addr: u16, v: u32) {
    put(regs, addr, &v.to_le_bytes());
}

/// Writes `v` little-endian at `addr`.
pub fn put_u64(regs: &mut [u8], addr: u16, v: u64) {
    put(regs, addr, &v.to_le_bytes());
}

fn put(regs: &mut [u8], addr: u16, bytes: &[u8]) {
    let a = usize::from(addr);
    if let Some(dst) = regs.get_mut(a..a + bytes.len()) {
        dst.copy_from_slice(bytes);
    }
}
