//! `faults` and `fault reset`: the error history 0x1003 (CiA 301 §7.5.2.5: error code in bits 15..0, here the
//! error register in bits 23..16 and the running fault number in bits 31..24, as device.toml describes), the
//! error code 0x603F and register 0x1001, with the texts of the firmware's fault table.

use std::time::{Duration, Instant};

use firmware::fault::table::FaultId;
use serde_json::json;

use crate::cia402::{state_name, CW_FAULT_RESET, SW_FAULT};
use crate::context::Context;

/// The text of error code `code`: the fault table's name, or the CiA 301 class (Table 26) of a code the table
/// does not have.
pub fn code_text(code: u16) -> String {
    if code == 0 {
        return "no error".into();
    }
    if let Some(id) = FaultId::from_code(code) {
        return id.info().name.to_owned();
    }
    let class = match code >> 12 {
        0x1 => "generic error",
        0x2 => "current",
        0x3 => "voltage",
        0x4 => "temperature",
        0x5 => "device hardware",
        0x6 => "device software",
        0x7 => "additional modules",
        0x8 => "monitoring",
        0x9 => "external error",
        0xF if code >> 8 == 0xFF => "device specific",
        0xF => "additional functions",
        _ => "unknown class",
    };
    format!("not in the fault table ({class})")
}

/// `faults`.
pub fn faults(cx: &mut Context) -> Result<(), String> {
    let count = cx.read_int(0x1003, 0)?;
    let mut history = Vec::new();
    for sub in 1..=count.clamp(0, 254) as u8 {
        let raw = cx.read_int(0x1003, sub)? as u32;
        let code = raw as u16;
        history.push((sub, code, (raw >> 16) as u8, (raw >> 24) as u8, code_text(code)));
    }
    let error_code = cx.read_int(0x603F, 0)? as u16;
    let register = cx.read_int(0x1001, 0)? as u8;
    let sw = cx.statusword()?;
    if cx.json {
        let list: Vec<_> = history
            .iter()
            .map(|(sub, code, reg, number, text)| {
                json!({
                    "sub": sub, "code": code, "code_hex": format!("0x{code:04X}"), "text": text,
                    "register": reg, "number": number,
                })
            })
            .collect();
        cx.print_json(&json!({
            "node": cx.node,
            "history": list,
            "error_code": error_code,
            "error_code_hex": format!("0x{error_code:04X}"),
            "error_code_text": code_text(error_code),
            "error_register": register,
            "statusword": sw,
            "cia402": state_name(sw),
        }));
    } else {
        say!("node {}: error code 0x603F = 0x{error_code:04X} {}", cx.node, code_text(error_code));
        say!("error register 0x1001 = 0x{register:02X}; state {} (statusword 0x{sw:04X})", state_name(sw));
        if history.is_empty() {
            say!("error history 0x1003: empty");
        } else {
            say!("error history 0x1003 (newest first):");
            for (sub, code, reg, number, text) in &history {
                say!("  {sub:>2}: 0x{code:04X} {text} (register 0x{reg:02X}, fault #{number})");
            }
        }
    }
    Ok(())
}

/// `fault reset`: controlword bit 7 low, then high (the rising edge resets, CiA 402-2 §6.2 transition 15); the
/// state it leaves is reported, and the reset fails if the drive stays in Fault (the cause is still there).
pub fn reset(cx: &mut Context) -> Result<(), String> {
    cx.write_int(0x6040, 0, 0)?;
    cx.write_int(0x6040, 0, i128::from(CW_FAULT_RESET))?;
    let deadline = Instant::now() + Duration::from_secs(2);
    let mut sw = cx.statusword()?;
    while sw & SW_FAULT != 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(10));
        sw = cx.statusword()?;
    }
    let code = cx.read_int(0x603F, 0)? as u16;
    if cx.json {
        cx.print_json(&json!({
            "node": cx.node, "statusword": sw, "cia402": state_name(sw),
            "error_code": code, "error_code_text": code_text(code),
        }));
    } else {
        say!("node {}: {} (statusword 0x{sw:04X}); 0x603F = 0x{code:04X} {}", cx.node, state_name(sw), code_text(code));
    }
    if sw & SW_FAULT != 0 {
        return Err(format!("still in Fault after the reset: 0x{code:04X} {} is still present", code_text(code)));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_take_the_fault_tables_names() {
        let info = FaultId::OverCurrent.info();
        assert_eq!(code_text(info.code), info.name);
        assert_eq!(code_text(0), "no error");
        assert!(code_text(0x9001).contains("external error"));
    }
}
