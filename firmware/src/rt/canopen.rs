//! The CANopen node in the runtime (board image, not QEMU: QEMU's `netduinoplus2` has no bxCAN): the firmware's
//! [`CanopenNode`] on CAN1 ([`BxCan`]), polled by tier 3 with the parameter store (0x1010/0x1011) and program
//! control (0x1F50..0x1F57, [`Interface::Canopen`]).
//!
//! * **Start-up** ([`start`]): node-ID from 0x2000 and bit rate from 0x2001 as the parameter store restored them
//!   (IDX L3490-3556); a rate the controller cannot make from 42 MHz (800 kbit/s, `board::can`) falls back to
//!   the default 1 Mbit/s. No transceiver or no bus: `BxCan::init` times out and the drive runs without CAN.
//! * **Every tier-3 tick** (400 us, [`poll`]): [`CanopenNode::poll`] inside `tier2::with_drive` (receive up to
//!   `RX_PER_POLL` frames, SDO, NMT, SYNC, PDOs, EMCY, heartbeat, transmit), then program control's request
//!   (`super::program::follow`; for a reset, the SDO response leaves the mailboxes first, bounded wait) and the
//!   node's event: a reset node restarts the microcontroller (the node has
//!   put the power stage in a safe state; the bootloader runs and may activate a pending image, and the
//!   application comes back with the stored parameters, as `hal-sim`'s runner models it), a reset communication
//!   with a new 0x2001 reprograms the bit timing.
//!
//! **Open point (precise)**: the SYNC and the RPDOs are taken at this 400 us tick, not at their arrival as the
//! `canopen` module's design has it (the CAN1 RX0 interrupt at tier-2 priority running `handle_frame` for
//! [`CanopenNode::is_realtime`] frames). So a SYNC is served 0 to 400 us late and the synchronous TPDOs leave
//! that much later; CSP over CAN works, with that jitter on when a set-point is taken.

use core::cell::RefCell;

use super::app;
use super::program::BoardProgram;
use crate::board::can::BxCan;
use crate::boot::program::{Interface, SharedPort};
use crate::canopen::frame::{BitRate, CanBus};
use crate::canopen::nmt::ResetKind;
use crate::canopen::{ids, CanopenNode, NodeEvent};
use crate::drive::objects::DriveObjects;
use crate::drive::Drive;
use crate::od::access::{ApplicationObjects, NoApplicationObjects};

/// The node and its controller, owned by tier 3.
pub(crate) struct Canopen {
    bus: BxCan,
    node: CanopenNode,
    /// Until the first boot-up: the node's own power-on reset is not a request to restart.
    powering_up: bool,
}

/// Brings CAN1 up with the drive's 0x2000/0x2001 and creates the node (initialisation; it boots at the first
/// poll). `None` when the controller does not come up (no transceiver or bus).
pub(crate) fn start(drive: &Drive) -> Option<Canopen> {
    let dictionary = drive.dictionary();
    let node_id = ids::startup_node_id(dictionary).unwrap_or(ids::DEFAULT_NODE_ID);
    let rate = ids::read(dictionary, ids::BIT_RATE_OBJECT, 0)
        .and_then(|code| u8::try_from(code).ok())
        .and_then(BitRate::from_code)
        .unwrap_or_default();
    let bus = match BxCan::init(rate) {
        Ok(bus) => bus,
        Err(_e) => {
            crate::rt_error!(
                "CAN at {=u32} bit/s: {}; trying 1 Mbit/s",
                rate.bits_per_second(),
                defmt::Debug2Format(&_e)
            );
            match BxCan::init(BitRate::default()) {
                Ok(bus) => bus,
                Err(_e) => {
                    crate::rt_error!("CAN not started: {}", defmt::Debug2Format(&_e));
                    return None;
                }
            }
        }
    };
    Some(Canopen { bus, node: CanopenNode::new(node_id), powering_up: true })
}

/// Tier 3, every tick: see the module documentation. `now_us` is tier 3's microsecond clock.
pub(crate) fn poll(
    can: &mut Canopen,
    params: &mut Option<app::Params>,
    program: Option<&RefCell<BoardProgram>>,
    now_us: u64,
) {
    let event = super::tier2::with_drive(|drive| {
        let on = drive.power_stage_enabled();
        // One instance of the node's code for all three cases (`dyn`): the node and its SDO server are large, and
        // an instance per objects type would not fit slot A next to the EtherCAT slave.
        let (mut port, mut no_program, mut drive_objects, mut none);
        let objects: &mut dyn ApplicationObjects = match params.as_mut() {
            Some(store) => {
                // The program port as `dyn` too: one instance of the drive objects' code with or without it.
                let program_objects: &mut dyn ApplicationObjects = match program {
                    Some(program) => {
                        port = SharedPort::new(program, Interface::Canopen, on);
                        &mut port
                    }
                    None => {
                        no_program = NoApplicationObjects;
                        &mut no_program
                    }
                };
                drive_objects = DriveObjects::new(store, on).with_program_control(program_objects);
                &mut drive_objects
            }
            None => {
                none = NoApplicationObjects;
                &mut none
            }
        };
        let event = can.node.poll(&mut can.bus, drive, objects, now_us);
        let reset = program.is_some_and(|program| super::program::follow(program, drive));
        (event, reset)
    });
    let Some((event, reset)) = event else { return };
    if reset {
        // Program control asked for the reset (0x1F51 = 1 with a verified image, or 2): its SDO response first.
        flush(can);
        super::program::reset();
    }
    match event {
        Some(NodeEvent::Booted) => can.powering_up = false,
        Some(NodeEvent::Reset { kind: ResetKind::Node, .. }) if !can.powering_up => {
            // The microcontroller restarts: the bootloader, then this application with the stored parameters
            // (0x2000/0x2001 included), as after a power cycle.
            crate::board::safe_state();
            cortex_m::peripheral::SCB::sys_reset()
        }
        Some(NodeEvent::BitRateSwitched(rate)) if rate != can.bus.bit_rate() => {
            // LSS activate bit timing: the node is silent now and stays so for the switch delay after this.
            let _refused = can.bus.set_bit_rate(rate).is_err();
            crate::rt_info!("CAN: LSS bit rate {=u32}, refused {=bool}", rate.bits_per_second(), _refused);
        }
        Some(NodeEvent::Reset { bit_rate: Some(rate), .. }) if rate != can.bus.bit_rate() => {
            // A refused rate (800 kbit/s) keeps the controller as it was.
            let _refused = can.bus.set_bit_rate(rate).is_err();
            crate::rt_info!("CAN: bit rate {=u32}, refused {=bool}", rate.bits_per_second(), _refused);
        }
        _ => {}
    }
}

/// Polls of the transmit mailboxes while the last frames leave before a reset: far more than the few frames of an
/// SDO response need at 20 kbit/s (about 6 ms each); a bus without other nodes never acknowledges, so the wait is
/// bounded.
const FLUSH_POLLS: u32 = 2_000_000;

/// Hands the node's queued frames to the controller and waits (bounded) until its mailboxes are empty.
fn flush(can: &mut Canopen) {
    let mut pending = can.node.transmit();
    for _ in 0..FLUSH_POLLS {
        match pending {
            Some(frame) if can.bus.send(&frame).is_ok() => pending = can.node.transmit(),
            None if can.bus.tx_idle() => return,
            // Mailboxes full, or the last frames still on the bus.
            _ => {}
        }
        core::hint::spin_loop();
    }
}
