//! `drive-image`: pack and sign firmware images, generate keys, inspect images. Run without arguments for help.

use std::process::ExitCode;

use firmware::boot::image::HARDWARE_ID;
use firmware::boot::keys::DEV_PUBLIC_KEY;
use image_tool::{
    describe, elf_payload, os_random, pack, parse_key_hex, parse_u32, parse_version, public_of, rust_key_file, to_hex,
    PackOptions,
};

const USAGE: &str = "\
drive-image keygen --out PREFIX [--rust FILE]
    writes PREFIX.secret and PREFIX.pub (64 hex digits each); --rust also writes the firmware's key file
drive-image pack (--elf FILE | --bin FILE) --key SECRET --version X.Y.Z [--hw-id N] [--sw-id N]
                 [--version-string S] [--security-version N] --out FILE
    --elf: the PT_LOAD segments inside slot A (0x0802_0000..); --bin: the raw bytes of slot A from its start
    --security-version: anti-rollback level (default 0); a drive refuses images below the one it confirmed
drive-image inspect FILE [--pub PUBFILE] [--hw-id N]
    prints the header and verifies the image (default key: the one compiled into the firmware)";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(out) => {
            print!("{out}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("drive-image: {e}\n\n{USAGE}");
            ExitCode::FAILURE
        }
    }
}

fn opt<'a>(args: &'a [String], name: &str) -> Option<&'a str> {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).map(String::as_str)
}

fn read(path: &str) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("{path}: {e}"))
}

fn write(path: &str, data: &[u8]) -> Result<(), String> {
    std::fs::write(path, data).map_err(|e| format!("{path}: {e}"))
}

fn run(args: &[String]) -> Result<String, String> {
    let rest = args.get(1..).unwrap_or(&[]);
    match args.first().map(String::as_str) {
        Some("keygen") => {
            let prefix = opt(rest, "--out").ok_or("keygen needs --out PREFIX")?;
            let seed: [u8; 32] = os_random()?;
            let pk = public_of(&seed);
            write(&format!("{prefix}.secret"), format!("{}\n", to_hex(&seed)).as_bytes())?;
            write(&format!("{prefix}.pub"), format!("{}\n", to_hex(&pk)).as_bytes())?;
            if let Some(rust) = opt(rest, "--rust") {
                write(rust, rust_key_file(&pk).as_bytes())?;
            }
            Ok(format!("public key {}\n", to_hex(&pk)))
        }
        Some("pack") => {
            let payload = match (opt(rest, "--elf"), opt(rest, "--bin")) {
                (Some(elf), None) => elf_payload(&read(elf)?)?,
                (None, Some(bin)) => read(bin)?,
                _ => return Err("pack needs exactly one of --elf FILE and --bin FILE".into()),
            };
            let key_path = opt(rest, "--key").ok_or("pack needs --key SECRETFILE")?;
            let seed = parse_key_hex(&String::from_utf8_lossy(&read(key_path)?))?;
            let version_text = opt(rest, "--version").ok_or("pack needs --version")?;
            let firmware_version = parse_version(version_text)?;
            let options = PackOptions {
                hardware_id: opt(rest, "--hw-id").map_or(Ok(HARDWARE_ID), parse_u32)?,
                firmware_version,
                software_id: opt(rest, "--sw-id").map_or(Ok(firmware_version & 0xFFFF_0000), parse_u32)?,
                version_string: opt(rest, "--version-string").unwrap_or(version_text).to_string(),
                security_version: opt(rest, "--security-version").map_or(Ok(0), parse_u32)?,
            };
            let out = opt(rest, "--out").ok_or("pack needs --out FILE")?;
            let image = pack(&payload, &seed, &options, os_random()?)?;
            write(out, &image)?;
            Ok(format!("{out}: {} bytes, payload {} bytes\n", image.len(), image.len() - 128))
        }
        Some("inspect") => {
            let file = rest.first().ok_or("inspect needs FILE")?;
            let pk = match opt(rest, "--pub") {
                Some(p) => parse_key_hex(&String::from_utf8_lossy(&read(p)?))?,
                None => DEV_PUBLIC_KEY,
            };
            let hw = opt(rest, "--hw-id").map_or(Ok(HARDWARE_ID), parse_u32)?;
            let image = read(file)?;
            let text = describe(&image, &pk, hw);
            if text.contains("FAILED") {
                Err(text)
            } else {
                Ok(text)
            }
        }
        _ => Err("unknown or missing command".into()),
    }
}
