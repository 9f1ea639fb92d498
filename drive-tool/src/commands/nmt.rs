//! `nmt start|stop|preop|reset|reset-comm`: the drive's communication state (CiA 301 §7.2.8.3.1 node control);
//! after a reset, whether its boot-up came.

use std::time::Duration;

use serde_json::json;

use crate::context::Context;
use crate::link::StateCommand;

/// How long a reset may take until the boot-up.
const BOOT_UP_TIMEOUT: Duration = Duration::from_secs(10);

/// `nmt COMMAND` to `--node` (or every node with `all`).
pub fn nmt(cx: &mut Context, command: StateCommand, all: bool) -> Result<(), String> {
    let node = if all { 0 } else { cx.node };
    let booted = cx.link.command_state(node, command, BOOT_UP_TIMEOUT)?;
    let target = if all { "every node".to_owned() } else { format!("node {node}") };
    let reset = matches!(command, StateCommand::Reset | StateCommand::ResetComm);
    if cx.json {
        cx.print_json(&json!({ "node": node, "command": format!("{command:?}"), "boot_up": reset.then_some(booted) }));
    } else if reset {
        say!("{target}: {command:?} sent; {}", if booted { "boot-up received" } else { "no boot-up" });
    } else {
        say!("{target}: {command:?} sent");
    }
    if reset && !booted {
        return Err(format!("{target}: no boot-up within {BOOT_UP_TIMEOUT:?} after the reset"));
    }
    Ok(())
}
