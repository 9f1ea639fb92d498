//! `drive-image`: pack and sign firmware images, generate keys, inspect images, write a board's factory HEX.
//! `drive-image --help` and `drive-image COMMAND --help` describe the commands.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, CommandFactory, Parser, Subcommand};
use firmware::boot::image::HARDWARE_ID;
use firmware::boot::keys::DEV_PUBLIC_KEY;
use image_tool::factory::{bootloader_blocks, check_image, factory_blocks, to_intel_hex};
use image_tool::{
    describe, elf_payload, os_random, pack, parse_key_hex, parse_u32, parse_version, public_of, rust_key_file, to_hex,
    PackOptions,
};

/// Packs and signs firmware images for the drive's update path, generates signing keys, inspects images and
/// writes the factory Intel HEX that puts bootloader and application on a board.
#[derive(Parser)]
#[command(name = "drive-image", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Prints a completion script for SHELL on stdout, e.g. `drive-image completions bash >
    /// ~/.local/share/bash-completion/completions/drive-image`.
    Completions {
        /// The shell the script is for.
        #[arg(value_name = "SHELL")]
        shell: clap_complete::Shell,
    },
    /// Generates an Ed25519 key pair: PREFIX.secret and PREFIX.pub (64 hex digits each).
    Keygen {
        /// Prefix of the two key files.
        #[arg(long, value_name = "PREFIX")]
        out: PathBuf,
        /// Also writes the firmware's key file (Rust source of firmware/src/boot/keys.rs) for the public key.
        #[arg(long, value_name = "FILE")]
        rust: Option<PathBuf>,
    },
    /// Packs an application (ELF or raw binary of slot A) into a signed update image (header, then payload).
    Pack {
        #[command(flatten)]
        input: PackInput,
        #[command(flatten)]
        sign: SignArgs,
        /// The image file to write.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
    },
    /// Prints an image's header and verifies it (header, CRC-32, Ed25519 signature); fails if it does not verify.
    Inspect {
        /// The image file.
        file: PathBuf,
        #[command(flatten)]
        trust: TrustArgs,
    },
    /// Writes one Intel HEX for a new board: the bootloader at 0x0800_0000, an erased update state and a signed
    /// application in slot A (payload at 0x0802_0000, header in the slot's last 128 bytes), for
    /// `probe-rs download --format hex` or any programmer.
    Factory {
        /// The bootloader ELF (`cargo build --release -p bootloader --target thumbv7em-none-eabihf`); all of its
        /// flash contents must lie in its 32 KiB region.
        #[arg(long, value_name = "ELF")]
        bootloader: PathBuf,
        #[command(flatten)]
        app: FactoryApp,
        /// With --elf: signing options as for `pack` (--key and --version then required); --hw-id is also the
        /// hardware id the image is checked for.
        #[command(flatten)]
        sign: FactorySignArgs,
        /// Public key file the application must verify with (default: the key compiled into the firmware and
        /// the bootloader, which the bootloader checks slot A with).
        #[arg(long = "pub", value_name = "PUBFILE")]
        public: Option<PathBuf>,
        /// The Intel HEX file to write.
        #[arg(long, value_name = "FILE.hex")]
        out: PathBuf,
    },
}

/// The application to pack: exactly one of --elf and --bin.
#[derive(Args)]
#[group(required = true, multiple = false)]
struct PackInput {
    /// The application ELF: its PT_LOAD segments inside slot A (0x0802_0000..).
    #[arg(long, value_name = "FILE")]
    elf: Option<PathBuf>,
    /// The raw bytes of slot A from its start.
    #[arg(long, value_name = "FILE")]
    bin: Option<PathBuf>,
}

/// The factory image's application: exactly one of --elf and --image.
#[derive(Args)]
#[group(required = true, multiple = false)]
struct FactoryApp {
    /// The application ELF, packed and signed on the fly (needs --key and --version).
    #[arg(long, value_name = "FILE", requires_all = ["key", "version"])]
    elf: Option<PathBuf>,
    /// An already signed image (from `pack`), verified as `inspect` does.
    #[arg(long, value_name = "FILE")]
    image: Option<PathBuf>,
}

/// Signing options of `pack`.
#[derive(Args)]
struct SignArgs {
    /// The secret key file (64 hex digits).
    #[arg(long, value_name = "SECRETFILE")]
    key: PathBuf,
    /// Firmware version: MAJOR.MINOR.PATCH or a number.
    #[arg(long, value_name = "X.Y.Z")]
    version: String,
    #[command(flatten)]
    fields: HeaderFields,
}

/// Signing options of `factory` (only with --elf).
#[derive(Args)]
struct FactorySignArgs {
    /// The secret key file (64 hex digits).
    #[arg(long, value_name = "SECRETFILE", requires = "elf")]
    key: Option<PathBuf>,
    /// Firmware version: MAJOR.MINOR.PATCH or a number.
    #[arg(long, value_name = "X.Y.Z", requires = "elf")]
    version: Option<String>,
    #[command(flatten)]
    fields: HeaderFields,
}

/// Header fields besides the version.
#[derive(Args)]
struct HeaderFields {
    /// Hardware id the image is built for (default: the reference drive's).
    #[arg(long = "hw-id", value_name = "N", value_parser = parse_u32)]
    hw_id: Option<u32>,
    /// Software identification (0x1F56:01; default: the version's upper 16 bits).
    #[arg(long = "sw-id", value_name = "N", value_parser = parse_u32)]
    sw_id: Option<u32>,
    /// Version string (at most 16 ASCII bytes; default: the --version text).
    #[arg(long = "version-string", value_name = "S")]
    version_string: Option<String>,
    /// Anti-rollback level (default 0): a drive refuses images below the one it confirmed.
    #[arg(long = "security-version", value_name = "N", value_parser = parse_u32)]
    security_version: Option<u32>,
}

/// The key and hardware id an image is checked against.
#[derive(Args)]
struct TrustArgs {
    /// Public key file to verify with (default: the key compiled into the firmware and the bootloader).
    #[arg(long = "pub", value_name = "PUBFILE")]
    public: Option<PathBuf>,
    /// Hardware id to check (default: the reference drive's).
    #[arg(long = "hw-id", value_name = "N", value_parser = parse_u32)]
    hw_id: Option<u32>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli.command) {
        Ok(out) => {
            print!("{out}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("drive-image: {e}");
            ExitCode::FAILURE
        }
    }
}

fn read(path: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))
}

fn write(path: &Path, data: &[u8]) -> Result<(), String> {
    std::fs::write(path, data).map_err(|e| format!("{}: {e}", path.display()))
}

fn read_key(path: &Path) -> Result<[u8; 32], String> {
    parse_key_hex(&String::from_utf8_lossy(&read(path)?)).map_err(|e| format!("{}: {e}", path.display()))
}

/// Packs `payload` with the signing options: the image bytes.
fn pack_signed(payload: &[u8], key: &Path, version_text: &str, fields: &HeaderFields) -> Result<Vec<u8>, String> {
    let seed = read_key(key)?;
    let firmware_version = parse_version(version_text).map_err(|e| format!("--version: {e}"))?;
    let options = PackOptions {
        hardware_id: fields.hw_id.unwrap_or(HARDWARE_ID),
        firmware_version,
        software_id: fields.sw_id.unwrap_or(firmware_version & 0xFFFF_0000),
        version_string: fields.version_string.clone().unwrap_or_else(|| version_text.to_string()),
        security_version: fields.security_version.unwrap_or(0),
    };
    pack(payload, &seed, &options, os_random()?)
}

fn trust_key(trust: &TrustArgs) -> Result<([u8; 32], u32), String> {
    let pk = match &trust.public {
        Some(p) => read_key(p)?,
        None => DEV_PUBLIC_KEY,
    };
    Ok((pk, trust.hw_id.unwrap_or(HARDWARE_ID)))
}

fn run(command: Command) -> Result<String, String> {
    match command {
        Command::Completions { shell } => {
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "drive-image", &mut script);
            String::from_utf8(script).map_err(|e| format!("completions: {e}"))
        }
        Command::Keygen { out, rust } => {
            let seed: [u8; 32] = os_random()?;
            let pk = public_of(&seed);
            let prefix = out.display();
            write(Path::new(&format!("{prefix}.secret")), format!("{}\n", to_hex(&seed)).as_bytes())?;
            write(Path::new(&format!("{prefix}.pub")), format!("{}\n", to_hex(&pk)).as_bytes())?;
            if let Some(rust) = rust {
                write(&rust, rust_key_file(&pk).as_bytes())?;
            }
            Ok(format!("public key {}\n", to_hex(&pk)))
        }
        Command::Pack { input, sign, out } => {
            let payload = match (&input.elf, &input.bin) {
                (Some(elf), _) => elf_payload(&read(elf)?).map_err(|e| format!("{}: {e}", elf.display()))?,
                (None, Some(bin)) => read(bin)?,
                (None, None) => return Err("pack needs one of --elf FILE and --bin FILE".into()),
            };
            let image = pack_signed(&payload, &sign.key, &sign.version, &sign.fields)?;
            write(&out, &image)?;
            Ok(format!("{}: {} bytes, payload {} bytes\n", out.display(), image.len(), image.len() - 128))
        }
        Command::Inspect { file, trust } => {
            let (pk, hw) = trust_key(&trust)?;
            let image = read(&file)?;
            let text = describe(&image, &pk, hw);
            if text.contains("FAILED") {
                Err(text)
            } else {
                Ok(text)
            }
        }
        Command::Factory { bootloader, app, sign, public, out } => {
            let image = match (&app.elf, &app.image, &sign.key, &sign.version) {
                (Some(elf), _, Some(key), Some(version)) => {
                    let payload = elf_payload(&read(elf)?).map_err(|e| format!("--elf {}: {e}", elf.display()))?;
                    pack_signed(&payload, key, version, &sign.fields)?
                }
                (None, Some(image), None, None) => {
                    // The header of a signed image cannot change: a field for it would be ignored, so refuse it.
                    let f = &sign.fields;
                    let ignored = [
                        (f.sw_id.is_some(), "--sw-id"),
                        (f.version_string.is_some(), "--version-string"),
                        (f.security_version.is_some(), "--security-version"),
                    ];
                    if let Some((_, name)) = ignored.iter().find(|(given, _)| *given) {
                        return Err(format!(
                            "{name} applies only with --elf: the image given by --image is already signed (pack it again)"
                        ));
                    }
                    read(image)?
                }
                _ => return Err("factory needs --elf FILE with --key and --version, or --image FILE".into()),
            };
            // The image must pass the bootloader's own check, or the board would stay in the fallback.
            let (pk, hw) = trust_key(&TrustArgs { public, hw_id: sign.fields.hw_id })?;
            let header = check_image(&image, &pk, hw)?;
            let boot_elf = read(&bootloader)?;
            bootloader_blocks(&boot_elf).map_err(|e| format!("--bootloader {}: {e}", bootloader.display()))?;
            let blocks = factory_blocks(&boot_elf, &image)?;
            let text = to_intel_hex(&blocks)?;
            write(&out, text.as_bytes())?;
            let v = header.firmware_version;
            Ok(format!(
                "{}: {} bytes of Intel HEX; bootloader {} bytes, application {}.{}.{} with a payload of {} bytes\n",
                out.display(),
                text.len(),
                blocks
                    .iter()
                    .filter(|b| b.address < image_tool::factory::BOOTLOADER_END)
                    .map(|b| b.data.len())
                    .sum::<usize>(),
                v >> 24,
                (v >> 16) & 0xFF,
                v & 0xFFFF,
                header.payload_len
            ))
        }
    }
}
