#!/usr/bin/env bash
# Runs every check and test of the project: the README's test command, and what .ci/run calls.
# Works on a fresh machine of the project's kind: scripts/setup.sh installs what the tests need.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }

step "setup (toolchain, QEMU, Python packages)"
scripts/setup.sh

step "format"
cargo fmt --all -- --check

step "clippy (host, all targets, warnings denied)"
cargo clippy --workspace --all-targets -- -D warnings

step "clippy (thumbv7em-none-eabihf firmware, with and without defmt, QEMU image, EtherCAT on SPI)"
cargo clippy -p firmware --target thumbv7em-none-eabihf --lib --bins -- -D warnings
cargo clippy -p firmware --target thumbv7em-none-eabihf --lib --bins --features defmt -- -D warnings
cargo clippy -p firmware --target thumbv7em-none-eabihf --lib --bins --features qemu -- -D warnings
cargo clippy -p firmware --target thumbv7em-none-eabihf --lib --bins --features ethercat -- -D warnings

step "target build (release, LTO) with and without defmt, with the EtherCAT slave on SPI, and the bootloader"
cargo build -p firmware --release --target thumbv7em-none-eabihf --bin drive
cargo build -p firmware --release --target thumbv7em-none-eabihf --bin drive --features defmt
cargo build -p firmware --release --target thumbv7em-none-eabihf --bin drive --features "ethercat defmt"
# The bootloader has a size-optimised profile of its own (root Cargo.toml) to fit its 32 KiB.
cargo build -p firmware --profile bootloader --target thumbv7em-none-eabihf --bin bootloader
cargo build -p firmware --profile bootloader --target thumbv7em-none-eabihf --bin bootloader --features defmt

step "docs (warnings denied)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps

step "tests (host unit, property, scenario, generated-file, Python-master and QEMU tests)"
cargo test --workspace
