//! The `drive-image` command line: pack a binary with the development key, inspect it (verifies), refuse a
//! tampered image and one checked against another key, and keygen writes a consistent key pair.

use std::path::PathBuf;
use std::process::Command;

fn tool() -> Command {
    Command::new(env!("CARGO_BIN_EXE_drive-image"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("drive-image-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

const DEV_KEY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../keys/dev-signing-key.secret");

#[test]
fn pack_with_the_dev_key_then_inspect_verifies_and_tampering_is_refused() {
    let bin = tmp("app.bin");
    std::fs::write(&bin, (0..10_001u32).map(|i| (i * 7) as u8).collect::<Vec<_>>()).unwrap();
    let img = tmp("app.img");
    let out = tool()
        .args(["pack", "--bin", bin.to_str().unwrap(), "--key", DEV_KEY, "--version", "1.4.2", "--out"])
        .arg(&img)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&img).unwrap();
    assert_eq!(bytes.len(), 128 + 10_004, "payload padded to 4 bytes");

    let out = tool().arg("inspect").arg(&img).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("verification:     OK"), "{text}");
    assert!(text.contains("firmware version: 1.4.2"), "{text}");
    assert!(text.contains("security version: 0"), "default security version: {text}");
    assert_eq!(&bytes[48..52], &[0; 4], "security version field (header offset 48) zero by default");

    let mut tampered = bytes.clone();
    tampered[500] ^= 1;
    let bad = tmp("bad.img");
    std::fs::write(&bad, tampered).unwrap();
    let out = tool().arg("inspect").arg(&bad).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("Crc"));

    // keygen: a fresh pair; the dev-signed image does not verify with it.
    let prefix = tmp("other");
    let out = tool().args(["keygen", "--out", prefix.to_str().unwrap()]).output().unwrap();
    assert!(out.status.success());
    let other_pub = format!("{}.pub", prefix.display());
    let out = tool().arg("inspect").arg(&img).args(["--pub", &other_pub]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("BadSignature"));

    let out = tool().args(["pack", "--bin", "x", "--elf", "y"]).output().unwrap();
    assert!(!out.status.success(), "exactly one input");
}

/// `--security-version N` goes into the signed header (offset 48, little-endian) and `inspect` reports it; the
/// image verifies, so the field is covered by the signature as the rest of bytes 0..64.
#[test]
fn pack_with_a_security_version_puts_it_into_the_signed_header() {
    let bin = tmp("sec.bin");
    std::fs::write(&bin, [0x11u8; 64]).unwrap();
    let img = tmp("sec.img");
    let out = tool()
        .args(["pack", "--bin", bin.to_str().unwrap(), "--key", DEV_KEY, "--version", "2.0.0"])
        .args(["--security-version", "7", "--out"])
        .arg(&img)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&img).unwrap();
    assert_eq!(&bytes[48..52], &7u32.to_le_bytes());
    let out = tool().arg("inspect").arg(&img).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("security version: 7"), "{text}");
    // Changing the security version afterwards breaks the signature.
    let mut lowered = bytes.clone();
    lowered[48] = 6;
    let bad = tmp("sec-lowered.img");
    std::fs::write(&bad, lowered).unwrap();
    let out = tool().arg("inspect").arg(&bad).output().unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("BadSignature"));
}

/// `drive-image completions bash` prints a bash completion script that completes the subcommands (issue 22 item
/// 4: shell completions); an unknown shell is refused by name with clap's usage status 2.
#[test]
fn completions_for_bash_name_the_subcommands_and_an_unknown_shell_is_refused() {
    let out = tool().args(["completions", "bash"]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        text.lines().any(|l| l.trim_start().starts_with("complete -F") && l.trim_end().ends_with(" drive-image")),
        "a bash `complete` line for drive-image:\n{text}"
    );
    for command in ["keygen", "pack", "inspect", "factory", "completions"] {
        assert!(text.contains(command), "`{command}` among the completions");
    }
    let out = tool().args(["completions", "tcsh"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("tcsh") && err.contains("<SHELL>"), "the error names the value and the argument: {err}");
}
