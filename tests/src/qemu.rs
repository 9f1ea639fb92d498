//! Boots the target image in QEMU and collects what it reports.
//!
//! # How the image boots
//! The application links at `ORIGIN(FLASH)` = 0x0802_0000 (slot A in the root `memory.x`, the single source of
//! the flash map), behind the future bootloader. QEMU's `netduinoplus2` resets like the silicon: the Cortex-M4
//! reads its initial stack pointer and reset vector from address 0, which aliases flash 0x0800_0000, where no
//! bootloader exists yet. So the runner plays the bootloader's part without repeating any address:
//!
//! 1. it reads the first two words of the ELF's `.vector_table` section (initial SP, reset vector) — wherever
//!    the linker put the table;
//! 2. it writes them to an 8-byte file next to the ELF and hands QEMU
//!    `-device loader,file=<that>,addr=0x08000000,force-raw=on` (the boot alias is a property of the MCU, not of
//!    our map). A file loader registers a ROM blob, which the CPU's reset sees; a `data=` loader is applied after
//!    the CPU reset has already fetched zeros;
//! 3. `-kernel <elf>` loads the image itself at its link addresses;
//! 4. cortex-m-rt's `set-vtor` feature makes the reset handler point VTOR at the image's own table, so every
//!    exception and interrupt after reset uses slot A's vectors (on the board the bootloader jumps the same way).
//!
//! The image is built with the `qemu` feature: no clock or peripheral set-up (QEMU models neither the RCC nor
//! TIM1/ADC), tier 1 fed from a built-in plant, TIM2 as instruction counter under `-icount shift=0` (one count per
//! executed instruction, exact and repeatable), results as `key=value` lines on semihosting stdout, and the
//! semihosting exit status as QEMU's exit status (0 ok, 1 failed check, 101 panic, 102 HardFault, 103
//! unexpected interrupt).

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The target the image is built for.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// The firmware binary that is the QEMU image (the drive application with the `qemu` feature).
pub const IMAGE_BIN: &str = "drive";
/// How long one QEMU run may take before it is killed (a hung image: panic-halt, lockup, endless loop).
pub const RUN_TIMEOUT: Duration = Duration::from_secs(60);
/// QEMU boot alias of flash on the STM32F405: where the core fetches SP and reset vector at reset.
const BOOT_ALIAS: u32 = 0x0800_0000;

/// What went wrong before the image could report.
#[derive(Debug)]
pub enum Error {
    /// `qemu-system-arm` is not installed.
    QemuMissing,
    /// The image did not build.
    Build(String),
    /// The ELF could not be read or has no vector table.
    Elf(String),
    /// QEMU could not be started or did not finish in time.
    Run(String),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::QemuMissing => {
                write!(f, "qemu-system-arm not found: run scripts/setup.sh (installs Debian's qemu-system-arm)")
            }
            Error::Build(e) => write!(f, "building the QEMU image failed:\n{e}"),
            Error::Elf(e) => write!(f, "reading the image: {e}"),
            Error::Run(e) => write!(f, "running QEMU: {e}"),
        }
    }
}

impl std::error::Error for Error {}

/// Flash and RAM use of an image (Berkeley format, as `size` prints it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageSize {
    /// Code, read-only data and vector table (flash).
    pub text: u64,
    /// Initialised data (flash and RAM).
    pub data: u64,
    /// Zero-initialised and uninitialised RAM.
    pub bss: u64,
}

/// One finished QEMU run.
#[derive(Clone, Debug)]
pub struct Run {
    /// QEMU's exit status (the image's semihosting exit code); `None` if killed by a signal.
    pub status: Option<i32>,
    /// Every `key=value` line of the image's stdout, e.g. `insn.foc_step` -> `156`.
    pub values: BTreeMap<String, String>,
    /// Full stdout.
    pub stdout: String,
    /// Full stderr (panic messages, QEMU diagnostics).
    pub stderr: String,
}

impl Run {
    /// An instruction count the image reported as `insn.<name>=<count>`.
    pub fn insn(&self, name: &str) -> Option<u64> {
        self.values.get(&format!("insn.{name}")).and_then(|v| v.parse().ok())
    }

    /// All `insn.*` counts, by name without the prefix.
    pub fn insns(&self) -> BTreeMap<String, u64> {
        self.values.iter().filter_map(|(k, v)| Some((k.strip_prefix("insn.")?.to_owned(), v.parse().ok()?))).collect()
    }
}

/// The workspace root (this package's parent directory).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or_default()
}

/// Target directory of the image build: `QEMU_IMAGE_TARGET_DIR`, else `target/qemu-image` under the workspace. A
/// directory of its own, so that the inner cargo never waits for the lock of the cargo that runs us.
pub fn image_target_dir() -> PathBuf {
    std::env::var_os("QEMU_IMAGE_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target").join("qemu-image"))
}

/// Whether `qemu-system-arm` can be started.
pub fn qemu_available() -> bool {
    Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Serialises the image builds of one test process and the copies made of their ELFs: cargo writes every feature
/// set of a binary to the same path, so a test that builds and then runs an image must not find it replaced by
/// another test's build with other features (the tests of a file run on parallel threads).
static BUILDS: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A copy of the ELF cargo just built at `built`, named after its feature set (`<bin>.<features>.elf` beside it),
/// which no later build with other features overwrites. Call with [`BUILDS`] held.
fn keep(built: &Path, features: &[&str]) -> Result<PathBuf, Error> {
    let name = built.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let key = if features.is_empty() { "plain".to_owned() } else { features.join("+") };
    let copy = built.with_file_name(format!("{name}.{key}.elf"));
    std::fs::copy(built, &copy)
        .map_err(|e| Error::Build(format!("cannot copy {} to {}: {e}", built.display(), copy.display())))?;
    Ok(copy)
}

/// Builds the release image with the `qemu` feature (plus `extra_features`) and returns the ELF's path (a copy
/// of its own for this feature set, see `keep`).
pub fn build_image(extra_features: &[&str]) -> Result<PathBuf, Error> {
    let _builds = BUILDS.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let target_dir = image_target_dir();
    let mut features = vec!["qemu"];
    features.extend_from_slice(extra_features);
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let output = Command::new(cargo)
        .current_dir(workspace_root())
        // The outer cargo's settings are for the host build; the image gets its own.
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .env_remove("CARGO_BUILD_RUSTFLAGS")
        .env_remove("CARGO_BUILD_TARGET")
        .env("CARGO_TARGET_DIR", &target_dir)
        .args(["build", "-p", "firmware", "--release", "--target", TARGET, "--bin", IMAGE_BIN, "--features"])
        .arg(features.join(","))
        .output()
        .map_err(|e| Error::Build(format!("cannot start cargo: {e}")))?;
    if !output.status.success() {
        return Err(Error::Build(String::from_utf8_lossy(&output.stderr).into_owned()));
    }
    keep(&target_dir.join(TARGET).join("release").join(IMAGE_BIN), &features)
}

fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// The contents of an ELF32 little-endian section, by name, with its address.
pub fn elf_section(elf: &[u8], name: &str) -> Option<(u32, Vec<u8>)> {
    if elf.get(0..6)? != b"\x7fELF\x01\x01" {
        return None; // not ELF32 little-endian
    }
    let shoff = u32_at(elf, 0x20)? as usize;
    let shentsize = usize::from(u16_at(elf, 0x2E)?);
    let shnum = usize::from(u16_at(elf, 0x30)?);
    let shstrndx = usize::from(u16_at(elf, 0x32)?);
    let header = |i: usize| shoff.checked_add(i.checked_mul(shentsize)?);
    let strtab = u32_at(elf, header(shstrndx)? + 16)? as usize;
    (0..shnum).find_map(|i| {
        let h = header(i)?;
        let name_at = strtab + u32_at(elf, h)? as usize;
        let end = elf.get(name_at..)?.iter().position(|&c| c == 0)?;
        if elf.get(name_at..name_at + end)? != name.as_bytes() {
            return None;
        }
        let (addr, offset, size) = (u32_at(elf, h + 12)?, u32_at(elf, h + 16)? as usize, u32_at(elf, h + 20)? as usize);
        Some((addr, elf.get(offset..offset + size)?.to_vec()))
    })
}

/// Initial stack pointer and reset vector: the first two words of the image's vector table.
pub fn boot_words(elf: &Path) -> Result<[u8; 8], Error> {
    let bytes = std::fs::read(elf).map_err(|e| Error::Elf(format!("{}: {e}", elf.display())))?;
    let (_, table) = elf_section(&bytes, ".vector_table")
        .ok_or_else(|| Error::Elf(format!("{}: no .vector_table section", elf.display())))?;
    table
        .get(0..8)
        .and_then(|w| w.try_into().ok())
        .ok_or_else(|| Error::Elf(format!("{}: vector table shorter than 8 bytes", elf.display())))
}

/// Runs the image once: `netduinoplus2`, semihosting, `-icount shift=0,align=off,sleep=off`, killed after
/// [`RUN_TIMEOUT`].
pub fn run_image(elf: &Path) -> Result<Run, Error> {
    if !qemu_available() {
        return Err(Error::QemuMissing);
    }
    let boot = elf.with_extension("boot.bin");
    std::fs::write(&boot, boot_words(elf)?).map_err(|e| Error::Run(format!("{}: {e}", boot.display())))?;
    run_qemu(Some(elf), &[(boot.as_path(), BOOT_ALIAS)])
}

/// Runs an Intel HEX file of the whole flash, e.g. `drive-image factory`'s, as a programmer leaves the board:
/// QEMU's generic loader reads the HEX records into flash at their addresses (no `-kernel`), and the core starts
/// from the bootloader at 0x0800_0000 as at a reset. Same QEMU settings as [`run_image`].
pub fn run_flash_hex(hex: &Path) -> Result<Run, Error> {
    if !qemu_available() {
        return Err(Error::QemuMissing);
    }
    let mut command = qemu_command();
    command.arg("-device").arg(format!("loader,file={}", hex.display()));
    finish_run(command)
}

/// `qemu-system-arm` with the settings every run uses: `netduinoplus2`, semihosting, exact instruction counting.
fn qemu_command() -> Command {
    let mut command = Command::new("qemu-system-arm");
    command
        .args(["-machine", "netduinoplus2", "-cpu", "cortex-m4", "-display", "none", "-monitor", "none"])
        .args(["-serial", "none", "-semihosting-config", "enable=on,target=native"])
        .args(["-icount", "shift=0,align=off,sleep=off"]);
    command
}

/// One QEMU run of `kernel` (loaded at its link addresses) with raw files loaded at flash addresses first.
fn run_qemu(kernel: Option<&Path>, raw_files: &[(&Path, u32)]) -> Result<Run, Error> {
    let mut command = qemu_command();
    for (file, addr) in raw_files {
        command.arg("-device").arg(format!("loader,file={},addr={addr:#010x},force-raw=on", file.display()));
    }
    if let Some(kernel) = kernel {
        command.arg("-kernel").arg(kernel);
    }
    finish_run(command)
}

/// Starts `command`, collects its output and exit status (killed after [`RUN_TIMEOUT`]).
fn finish_run(mut command: Command) -> Result<Run, Error> {
    let mut child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| Error::Run(format!("cannot start qemu-system-arm: {e}")))?;

    // Drain both pipes on threads so that a chatty image cannot block on a full pipe.
    let drain = |pipe: Option<Box<dyn std::io::Read + Send>>| {
        std::thread::spawn(move || {
            let mut text = String::new();
            if let Some(mut p) = pipe {
                let _ = p.read_to_string(&mut text);
            }
            text
        })
    };
    let out = drain(child.stdout.take().map(|p| Box::new(p) as Box<dyn std::io::Read + Send>));
    let err = drain(child.stderr.take().map(|p| Box::new(p) as Box<dyn std::io::Read + Send>));
    let deadline = Instant::now() + RUN_TIMEOUT;
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break status,
            Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(5)),
            Ok(None) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(Error::Run(format!("no exit within {RUN_TIMEOUT:?} (image hung)")));
            }
            Err(e) => return Err(Error::Run(e.to_string())),
        }
    };
    let stdout = out.join().unwrap_or_default();
    let stderr = err.join().unwrap_or_default();
    let values = stdout
        .lines()
        .filter_map(|l| l.split_once('='))
        .map(|(k, v)| (k.trim().to_owned(), v.trim().to_owned()))
        .collect();
    Ok(Run { status: status.code(), values, stdout, stderr })
}

/// Builds and runs the QEMU image.
pub fn build_and_run() -> Result<(PathBuf, Run), Error> {
    if !qemu_available() {
        return Err(Error::QemuMissing);
    }
    let elf = build_image(&[])?;
    let run = run_image(&elf)?;
    Ok((elf, run))
}

/// `llvm-size` from the toolchain's llvm-tools component, else `arm-none-eabi-size`.
fn size_tool() -> Option<PathBuf> {
    let sysroot = Command::new("rustc").args(["--print", "sysroot"]).output().ok()?;
    let verbose = Command::new("rustc").arg("-vV").output().ok()?;
    let host =
        String::from_utf8_lossy(&verbose.stdout).lines().find_map(|l| l.strip_prefix("host: ").map(str::to_owned))?;
    let llvm = PathBuf::from(String::from_utf8_lossy(&sysroot.stdout).trim())
        .join("lib/rustlib")
        .join(host)
        .join("bin/llvm-size");
    if llvm.exists() {
        return Some(llvm);
    }
    Command::new("arm-none-eabi-size").arg("--version").output().ok().map(|_| "arm-none-eabi-size".into())
}

/// Text/data/bss of an ELF, or `None` if no size tool is installed.
pub fn image_size(elf: &Path) -> Option<ImageSize> {
    let output = Command::new(size_tool()?).arg(elf).output().ok()?;
    let text = String::from_utf8_lossy(&output.stdout);
    // Berkeley format: a header line, then "text data bss dec hex filename".
    let mut fields = text.lines().nth(1)?.split_whitespace().map(str::parse::<u64>);
    Some(ImageSize { text: fields.next()?.ok()?, data: fields.next()?.ok()?, bss: fields.next()?.ok()? })
}

/// The board's image variants whose size is gated (issue 17): name, and the features of `firmware` they are built
/// with (the board images, not the QEMU one: no `qemu` feature).
pub const IMAGE_VARIANTS: [(&str, &[&str]); 3] =
    [("can", &[]), ("ethercat", &["ethercat"]), ("ethercat_defmt", &["ethercat", "defmt"])];

/// Builds each of [`IMAGE_VARIANTS`] in the release profile and returns its name and text size (code, read-only
/// data, vector table), or `None` for the sizes if no size tool is installed.
pub fn variant_text_sizes() -> Result<Vec<(&'static str, Option<u64>)>, Error> {
    IMAGE_VARIANTS
        .iter()
        .map(|&(name, features)| {
            let elf = build_target_bins(&[IMAGE_BIN], features)?;
            Ok((name, elf.first().and_then(|e| image_size(e)).map(|s| s.text)))
        })
        .collect()
}

/// The bootloader binary (issue 7): links at 0x0800_0000, verifies slot A and starts it (package `bootloader`,
/// `bootloader/src/main.rs`).
pub const BOOTLOADER_BIN: &str = "bootloader";
/// Exit status of the bootloader image when it stays in its fallback (`board::semihosting::EXIT_NO_VALID_IMAGE`).
pub const EXIT_NO_VALID_IMAGE: i32 = 3;

/// The package a target binary belongs to: the bootloader is a package of its own (its size settings are a
/// per-package profile override in the root `Cargo.toml`), every other image is the firmware's.
pub fn package_of(bin: &str) -> &'static str {
    if bin == BOOTLOADER_BIN {
        "bootloader"
    } else {
        "firmware"
    }
}

/// Builds target binaries in the release profile, each in its package ([`package_of`]), with `--features`
/// `features` (e.g. `qemu`, which both packages define), and returns their ELF paths in the order given (copies
/// of their own for this feature set, see `keep`).
pub fn build_target_bins(bins: &[&str], features: &[&str]) -> Result<Vec<PathBuf>, Error> {
    let _builds = BUILDS.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let target_dir = image_target_dir();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut packages: Vec<&str> = bins.iter().map(|b| package_of(b)).collect();
    packages.sort_unstable();
    packages.dedup();
    for package in packages {
        let mut command = Command::new(&cargo);
        command
            .current_dir(workspace_root())
            .env_remove("RUSTFLAGS")
            .env_remove("CARGO_ENCODED_RUSTFLAGS")
            .env_remove("CARGO_BUILD_RUSTFLAGS")
            .env_remove("CARGO_BUILD_TARGET")
            .env("CARGO_TARGET_DIR", &target_dir)
            .args(["build", "-p", package, "--release", "--target", TARGET]);
        for bin in bins.iter().filter(|b| package_of(b) == package) {
            command.args(["--bin", bin]);
        }
        if !features.is_empty() {
            command.arg("--features").arg(features.join(","));
        }
        let output = command.output().map_err(|e| Error::Build(format!("cannot start cargo: {e}")))?;
        if !output.status.success() {
            return Err(Error::Build(String::from_utf8_lossy(&output.stderr).into_owned()));
        }
    }
    bins.iter().map(|b| keep(&target_dir.join(TARGET).join("release").join(b), features)).collect()
}

/// Builds the host tool `drive-image` (image-tool) into the image target directory and returns its path.
pub fn build_image_tool() -> Result<PathBuf, Error> {
    let target_dir = image_target_dir();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let output = Command::new(cargo)
        .current_dir(workspace_root())
        .env_remove("CARGO_BUILD_TARGET")
        .env("CARGO_TARGET_DIR", &target_dir)
        .args(["build", "-p", "image-tool", "--bin", "drive-image"])
        .output()
        .map_err(|e| Error::Build(format!("cannot start cargo: {e}")))?;
    if !output.status.success() {
        return Err(Error::Build(String::from_utf8_lossy(&output.stderr).into_owned()));
    }
    Ok(target_dir.join("debug").join("drive-image"))
}

/// Packs `elf` into a signed image with `drive-image pack` and the development key (`keys/dev-signing-key.secret`);
/// returns the image bytes (header, then payload).
pub fn pack_image(tool: &Path, elf: &Path, version: &str) -> Result<Vec<u8>, Error> {
    let out = elf.with_extension("img");
    let key = workspace_root().join("keys").join("dev-signing-key.secret");
    let output = Command::new(tool)
        .arg("pack")
        .arg("--elf")
        .arg(elf)
        .arg("--key")
        .arg(&key)
        .args(["--version", version, "--out"])
        .arg(&out)
        .output()
        .map_err(|e| Error::Build(format!("cannot start {}: {e}", tool.display())))?;
    if !output.status.success() {
        return Err(Error::Build(String::from_utf8_lossy(&output.stderr).into_owned()));
    }
    std::fs::read(&out).map_err(|e| Error::Build(format!("{}: {e}", out.display())))
}

/// Slot A as a factory install leaves it: erased (0xFF), the image's payload from the slot start, its header in the
/// last 128 bytes of the image area (`firmware::boot::image`: `HEADER_OFFSET`).
pub fn slot_a_contents(image: &[u8]) -> Vec<u8> {
    use firmware::boot::image::{HEADER_LEN, HEADER_OFFSET, IMAGE_AREA_LEN};
    let (header, payload) = image.split_at(HEADER_LEN as usize);
    let mut slot = vec![0xFF; IMAGE_AREA_LEN as usize];
    slot[..payload.len()].copy_from_slice(payload);
    slot[HEADER_OFFSET as usize..].copy_from_slice(header);
    slot
}

/// Runs the bootloader ELF (loaded at 0x0800_0000, where the core fetches SP and reset vector) with `slot_a` loaded
/// at the start of slot A: what the board does at reset. Same QEMU settings as [`run_image`].
pub fn run_with_bootloader(bootloader: &Path, slot_a: &[u8], name: &str) -> Result<Run, Error> {
    if !qemu_available() {
        return Err(Error::QemuMissing);
    }
    let file = bootloader.with_extension(format!("{name}.slot-a.bin"));
    std::fs::write(&file, slot_a).map_err(|e| Error::Run(format!("{}: {e}", file.display())))?;
    run_qemu(Some(bootloader), &[(file.as_path(), firmware::flash_map::SLOT_A_START)])
}

/// Lowest and highest-plus-one load (physical) address of an ELF32's loadable contents in flash (PT_LOAD segments
/// with file contents below the SRAM at 0x2000_0000): where the image lies in flash, `.data`'s load copy included.
pub fn flash_extent(elf: &[u8]) -> Option<(u32, u32)> {
    if elf.get(0..6)? != b"\x7fELF\x01\x01" {
        return None;
    }
    let phoff = u32_at(elf, 0x1C)? as usize;
    let phentsize = usize::from(u16_at(elf, 0x2A)?);
    let phnum = usize::from(u16_at(elf, 0x2C)?);
    let mut extent: Option<(u32, u32)> = None;
    for i in 0..phnum {
        let ph = phoff.checked_add(i.checked_mul(phentsize)?)?;
        let (kind, paddr, filesz) = (u32_at(elf, ph)?, u32_at(elf, ph + 12)?, u32_at(elf, ph + 16)?);
        if kind != 1 || filesz == 0 || paddr >= 0x2000_0000 {
            continue;
        }
        let end = paddr.checked_add(filesz)?;
        extent = Some(extent.map_or((paddr, end), |(lo, hi)| (lo.min(paddr), hi.max(end))));
    }
    extent
}
