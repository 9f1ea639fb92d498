//! The firmware's EtherCAT state machine (`firmware::ecat::esm`, ETG.1000.6 §6.4) on the emulated ESC, driven by
//! an in-process master through AL control 0x0120 and read back from AL status 0x0130 / AL status code 0x0134.

use drive_tests::ecat_master::{Bench, COE};
use firmware::ecat::esc::AlStatusCode;
use firmware::ecat::esm::AlState;
use firmware::ecat::mailbox::MailboxLayout;
use firmware::ecat::process_data::ProcessDataLayout;
use firmware::od::access::Table;
use firmware::od::generated;

const ERR: u16 = 0x10;

/// A sync manager's start, length, control and activate.
type SmRow = (u16, u16, u8, u8);

#[test]
fn the_slave_starts_in_init_without_error() {
    let mut b = Bench::new();
    assert_eq!(b.al_status(), (0x0001, 0x0000));
    assert_eq!(b.esm.state(), AlState::Init);
}

#[test]
fn init_to_preop_without_mailbox_sync_managers_is_refused_with_0x0016() {
    let mut b = Bench::new();
    assert_eq!(b.request(0x0002), (0x0001 | ERR, 0x0016));
    assert!(!b.mailbox.is_running());
}

#[test]
fn init_to_preop_with_the_sii_mailboxes_reaches_preop_and_starts_the_mailbox() {
    let mut b = Bench::new();
    b.to_preop();
    assert_eq!(b.esm.state(), AlState::PreOp);
    assert!(b.mailbox.is_running());
    // The mailbox answers now: an SDO upload of the device type.
    assert_eq!(b.sdo_upload(0x1000, 0).map(|(v, _)| v), Ok(0x0002_0192u32.to_le_bytes().to_vec()));
}

#[test]
fn mailboxes_that_differ_from_the_sii_are_refused_with_0x0016() {
    let l = MailboxLayout::DRIVE;
    let cases: [(&str, [SmRow; 2]); 5] = [
        ("SM0 shorter", [(l.out_start, 64, 0x26, 1), (l.in_start, l.in_size, 0x22, 1)]),
        ("SM1 elsewhere", [(l.out_start, l.out_size, 0x26, 1), (0x1100, l.in_size, 0x22, 1)]),
        ("SM0 buffered", [(l.out_start, l.out_size, 0x24, 1), (l.in_start, l.in_size, 0x22, 1)]),
        ("SM1 written by the master", [(l.out_start, l.out_size, 0x26, 1), (l.in_start, l.in_size, 0x26, 1)]),
        ("SM1 not enabled", [(l.out_start, l.out_size, 0x26, 1), (l.in_start, l.in_size, 0x22, 0)]),
    ];
    for (what, sms) in cases {
        let mut b = Bench::new();
        for (n, (start, len, control, activate)) in sms.into_iter().enumerate() {
            b.configure_sm(n as u16, start, len, control, activate);
        }
        assert_eq!(b.request(0x0002), (0x0001 | ERR, 0x0016), "{what}");
    }
}

#[test]
fn invalid_transitions_are_refused_with_0x0011_in_the_current_state() {
    // From INIT.
    for requested in [0x0004, 0x0008] {
        let mut b = Bench::new();
        b.configure_mailboxes();
        assert_eq!(b.request(requested), (0x0001 | ERR, 0x0011), "INIT -> {requested:#x}");
    }
    // From PRE-OP.
    for requested in [0x0003, 0x0008] {
        let mut b = Bench::new();
        b.to_preop();
        assert_eq!(b.request(requested), (0x0002 | ERR, 0x0011), "PRE-OP -> {requested:#x}");
        assert!(b.mailbox.is_running(), "the mailbox keeps running in PRE-OP + error");
    }
    // From BOOT.
    for requested in [0x0002, 0x0004, 0x0008] {
        let mut b = Bench::new();
        b.to_boot();
        assert_eq!(b.request(requested), (0x0003 | ERR, 0x0011), "BOOT -> {requested:#x}");
    }
}

#[test]
fn unknown_requested_states_are_refused_with_0x0012() {
    for requested in [0x0000, 0x0005, 0x0006, 0x0007, 0x0009, 0x000F] {
        let mut b = Bench::new();
        assert_eq!(b.request(requested), (0x0001 | ERR, 0x0012), "INIT, request {requested:#x}");
        let mut b = Bench::new();
        b.to_preop();
        assert_eq!(b.request(requested), (0x0002 | ERR, 0x0012), "PRE-OP, request {requested:#x}");
    }
}

#[test]
fn an_error_indication_stays_until_acknowledged() {
    let mut b = Bench::new();
    b.to_preop();
    assert_eq!(b.request(0x0008), (0x0002 | ERR, 0x0011));
    // Requests without the acknowledge bit are ignored while the error is shown.
    assert_eq!(b.request(0x0002), (0x0002 | ERR, 0x0011));
    assert_eq!(b.request(0x0004), (0x0002 | ERR, 0x0011));
    // Acknowledged: the error indication and the code are cleared.
    assert_eq!(b.request(0x0002 | ERR), (0x0002, 0x0000));
}

#[test]
fn an_acknowledged_request_is_executed_and_can_fail_again() {
    let mut b = Bench::new();
    b.to_preop();
    assert_eq!(b.request(0x0008), (0x0002 | ERR, 0x0011));
    assert_eq!(b.request(0x0003 | ERR), (0x0002 | ERR, 0x0011), "PRE-OP -> BOOT acknowledged, still invalid");
    assert_eq!(b.request(0x0001 | ERR), (0x0001, 0x0000));
}

#[test]
fn a_request_for_init_clears_the_error_without_acknowledge() {
    let mut b = Bench::new();
    b.to_preop();
    assert_eq!(b.request(0x0008), (0x0002 | ERR, 0x0011));
    assert_eq!(b.request(0x0001), (0x0001, 0x0000));
    assert!(!b.mailbox.is_running());
}

#[test]
fn init_to_boot_and_back_is_allowed() {
    let mut b = Bench::new();
    b.to_boot();
    assert_eq!(b.esm.state(), AlState::Boot);
    assert!(b.mailbox.is_running());
    assert_eq!(b.request(0x0001), (0x0001, 0x0000));
    assert!(!b.mailbox.is_running());
}

#[test]
fn init_to_boot_without_the_bootstrap_mailbox_is_refused_with_0x0015() {
    let mut b = Bench::new();
    assert_eq!(b.request(0x0003), (0x0001 | ERR, 0x0015));
}

#[test]
fn going_back_to_init_throws_away_a_reply_the_master_never_read() {
    let mut b = Bench::new();
    b.to_preop();
    assert_eq!(b.send(COE, &[0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]), 1);
    b.poll();
    // The reply waits in SM1; the master goes to INIT instead of reading it.
    assert_eq!(b.request(0x0001), (0x0001, 0x0000));
    let (sm1_status, _) = b.fprd(0x080D, 1);
    assert_eq!(sm1_status[0] & 0x08, 0, "SM1 no longer holds a mailbox in INIT");
    assert_eq!(b.request(0x0002), (0x0002, 0x0000));
    assert_eq!(b.receive(), None, "nothing stale comes back in PRE-OP");
    // And the mailbox works again from a fresh counter.
    assert!(b.sdo_upload(0x1000, 0).is_ok());
}

#[test]
fn disabling_the_mailbox_in_preop_drops_the_slave_to_init_with_0x0016() {
    let mut b = Bench::new();
    b.to_preop();
    let l = b.layout;
    b.configure_sm(0, l.out_start, l.out_size, 0x26, 0x00);
    b.poll();
    assert_eq!(b.al_status(), (0x0001 | ERR, 0x0016));
    assert!(!b.mailbox.is_running());
}

#[test]
fn a_local_error_in_preop_shows_the_error_until_acknowledged() {
    let mut b = Bench::new();
    b.to_preop();
    let t = b.esm.local_error(&mut b.esc, AlStatusCode::SmWatchdog);
    assert_eq!((t.from, t.to), (AlState::PreOp, AlState::PreOp));
    assert_eq!(b.al_status(), (0x0002 | ERR, 0x001B));
    assert_eq!(b.request(0x0002 | ERR), (0x0002, 0x0000));
}

#[test]
fn preop_to_safeop_with_an_invalid_process_data_configuration_is_refused_in_preop() {
    // SM2/SM3 are not configured at all: whatever the layout, the outputs or inputs are refused.
    let mut b = Bench::new();
    b.to_preop();
    let (status, code) = b.request(0x0004);
    assert_eq!(status, 0x0002 | ERR);
    assert!([0x001D, 0x001E, 0x0024, 0x0025].contains(&code), "a process-data code, got {code:#06x}");
    assert!(b.mailbox.is_running());
}

#[test]
fn the_access_context_follows_the_state() {
    let mut b = Bench::new();
    assert_eq!(b.esm.comm_state(), firmware::od::access::CommState::Init);
    b.to_preop();
    assert_eq!(b.esm.comm_state(), firmware::od::access::CommState::PreOperational);
    assert!(!b.esm.inputs_enabled() && !b.esm.outputs_enabled());
}

// ---------------------------------------------------------------------------------------------------------
// SAFE-OP and OP (with the process-data layout of firmware::ecat::process_data)
// ---------------------------------------------------------------------------------------------------------

/// The default layout's image sizes (outputs, inputs).
fn image_sizes(b: &Bench) -> (u16, u16) {
    let layout = ProcessDataLayout::compile(&b.dict).expect("the default PDO configuration compiles");
    (layout.output_bytes, layout.input_bytes)
}

/// PRE-OP with SM2/SM3 configured as the SII describes them (0x1100 outputs, 0x1180 inputs) for the default
/// PDOs, plus `delta` bytes on SM2's length.
fn preop_with_process_data(delta_sm2: i16, delta_sm3: i16) -> Bench {
    let mut b = Bench::new();
    b.to_preop();
    let (outputs, inputs) = image_sizes(&b);
    b.configure_sm(2, generated::PROCESS_OUT_START, outputs.wrapping_add_signed(delta_sm2), 0x64, 0x01);
    b.configure_sm(3, generated::PROCESS_IN_START, inputs.wrapping_add_signed(delta_sm3), 0x20, 0x01);
    b
}

fn safeop() -> Bench {
    let mut b = preop_with_process_data(0, 0);
    assert_eq!(b.request(0x0004), (0x0004, 0x0000), "SAFE-OP reached");
    b
}

/// The master writes SM2 once (the whole output image).
fn write_outputs(b: &mut Bench) {
    let (outputs, _) = image_sizes(b);
    assert_eq!(b.fpwr(generated::PROCESS_OUT_START, &vec![0; usize::from(outputs)]), 1);
}

#[test]
fn preop_to_safeop_with_the_default_pdos_compiles_the_layout() {
    let b = safeop();
    assert_eq!(b.esm.state(), AlState::SafeOp);
    assert!(b.esm.layout().is_some() && b.esm.synchronisation().is_some());
    assert!(b.esm.inputs_enabled() && !b.esm.outputs_enabled());
}

#[test]
fn sync_managers_that_do_not_fit_the_layout_are_refused_with_0x001d_and_0x001e() {
    let mut b = preop_with_process_data(1, 0);
    assert_eq!(b.request(0x0004), (0x0002 | ERR, 0x001D), "SM2 one byte too long");
    let mut b = preop_with_process_data(0, -1);
    assert_eq!(b.request(0x0004), (0x0002 | ERR, 0x001E), "SM3 one byte too short");
}

#[test]
fn a_mapping_that_does_not_compile_is_refused_with_0x0025_or_0x0024() {
    for (assignment, wrong_pdo, code) in [(0x1C12u16, 0x1A00u16, 0x0025), (0x1C13, 0x1600, 0x0024)] {
        let mut b = preop_with_process_data(0, 0);
        // Stored behind the SDO checks' back (an old parameter image, say): the PDO of the other direction.
        let entry = Table::GENERATED.find(assignment, 1).expect("assignment entry");
        assert!(b.dict.values_mut().set_raw(entry, &wrong_pdo.to_le_bytes()));
        assert_eq!(b.request(0x0004), (0x0002 | ERR, code), "{assignment:#06x}:01 = {wrong_pdo:#06x}");
    }
}

#[test]
fn safeop_to_op_waits_for_the_first_outputs() {
    let mut b = safeop();
    assert_eq!(b.request(0x0008), (0x0004, 0x0000), "held in SAFE-OP without error");
    assert!(b.esm.op_pending());
    b.now_ms += 500;
    b.poll();
    assert_eq!(b.al_status(), (0x0004, 0x0000));
    write_outputs(&mut b);
    b.poll();
    assert_eq!(b.al_status(), (0x0008, 0x0000));
    assert!(b.esm.outputs_enabled());
}

#[test]
fn safeop_to_op_with_outputs_already_written_is_immediate() {
    let mut b = safeop();
    write_outputs(&mut b);
    assert_eq!(b.request(0x0008), (0x0008, 0x0000));
}

#[test]
fn safeop_to_op_without_outputs_is_refused_with_0x001b_after_the_timeout() {
    let mut b = safeop();
    b.request(0x0008);
    b.now_ms += firmware::ecat::esm::SAFEOP_OP_TIMEOUT_MS - 1;
    b.poll();
    assert_eq!(b.al_status(), (0x0004, 0x0000), "still waiting");
    b.now_ms += 1;
    b.poll();
    assert_eq!(b.al_status(), (0x0004 | ERR, 0x001B));
}

fn op() -> Bench {
    let mut b = safeop();
    write_outputs(&mut b);
    assert_eq!(b.request(0x0008), (0x0008, 0x0000), "OP reached");
    b
}

#[test]
fn refusals_in_op_fall_back_to_safeop_with_the_error() {
    let mut b = op();
    assert_eq!(b.request(0x0003), (0x0004 | ERR, 0x0011), "OP -> BOOT");
    assert!(!b.esm.outputs_enabled());
    let mut b = op();
    assert_eq!(b.request(0x0006), (0x0004 | ERR, 0x0012), "unknown state from OP");
}

#[test]
fn op_goes_down_to_safeop_preop_and_init_on_request() {
    let mut b = op();
    assert_eq!(b.request(0x0004), (0x0004, 0x0000));
    assert!(b.esm.inputs_enabled() && !b.esm.outputs_enabled());
    assert_eq!(b.request(0x0008), (0x0008, 0x0000), "SM2 kept its outputs: OP again at once");
    assert_eq!(b.request(0x0002), (0x0002, 0x0000));
    assert!(b.esm.layout().is_none() && !b.esm.inputs_enabled());
    let mut b = op();
    assert_eq!(b.request(0x0001), (0x0001, 0x0000));
    assert!(!b.mailbox.is_running());
}

#[test]
fn a_local_error_in_op_leaves_safeop_with_error_and_needs_fresh_outputs() {
    let mut b = op();
    let t = b.esm.local_error(&mut b.esc, AlStatusCode::SmWatchdog);
    assert_eq!((t.from, t.to, t.code), (AlState::Op, AlState::SafeOp, AlStatusCode::SmWatchdog));
    assert_eq!(b.al_status(), (0x0004 | ERR, 0x001B));
    // SM2 is disabled: the master's outputs no longer reach it (the working counter shows the error)... and
    // OP without acknowledge is ignored.
    assert_eq!(b.request(0x0008), (0x0004 | ERR, 0x001B));
    // Acknowledged: SAFE-OP again; OP waits for outputs written after the acknowledge.
    assert_eq!(b.request(0x0004 | ERR), (0x0004, 0x0000));
    assert_eq!(b.request(0x0008), (0x0004, 0x0000), "waits for new outputs");
    write_outputs(&mut b);
    b.poll();
    assert_eq!(b.al_status(), (0x0008, 0x0000));
}

#[test]
fn changing_sm2_in_safeop_drops_the_slave_to_preop_with_0x001d() {
    let mut b = safeop();
    let (outputs, _) = image_sizes(&b);
    // Disabled, given another length and enabled again (an ESC takes SM changes only while it is disabled).
    b.configure_sm(2, generated::PROCESS_OUT_START, outputs, 0x64, 0x00);
    b.configure_sm(2, generated::PROCESS_OUT_START, outputs + 2, 0x64, 0x01);
    b.poll();
    assert_eq!(b.al_status(), (0x0002 | ERR, 0x001D));
    assert!(b.mailbox.is_running());
}
