#!/usr/bin/env bash
# Runs every check and test of the project: the README's test command, and what .ci/run calls.
# Works on a fresh machine of the project's kind: scripts/setup.sh installs what the tests need.
# Prints each step's wall time and, at the end, a table of them and the tests skipped for a missing prerequisite
# (none under CI=true, where such a test fails instead: tests/src/prerequisite.rs).
set -euo pipefail
cd "$(dirname "$0")/.."

target_dir=${CARGO_TARGET_DIR:-target}
timings=()
step_name=""
step_start=0
finish_step() {
  if [ -n "$step_name" ]; then
    timings+=("$(printf '%6d s  %s' $(($(date +%s) - step_start)) "$step_name")")
  fi
}
step() {
  finish_step
  step_name="$*"
  step_start=$(date +%s)
  printf '\n==> %s\n' "$*"
}
run_start=$(date +%s)

step "setup (toolchain target and components, QEMU, tshark, Python packages)"
scripts/setup.sh

step "format"
cargo fmt --all -- --check

step "clippy (host, all targets, warnings denied)"
cargo clippy --workspace --all-targets -- -D warnings

step "clippy (thumbv7em-none-eabihf: drive and bootloader, with defmt, QEMU image, EtherCAT on SPI)"
cargo clippy -p firmware -p drive-control -p bootloader --target thumbv7em-none-eabihf --lib --bins -- -D warnings
cargo clippy -p firmware -p bootloader --target thumbv7em-none-eabihf --lib --bins --features defmt -- -D warnings
cargo clippy -p firmware -p bootloader --target thumbv7em-none-eabihf --lib --bins --features qemu -- -D warnings
cargo clippy -p firmware --target thumbv7em-none-eabihf --lib --bins --features ethercat -- -D warnings

step "target build (release, LTO): the plain build of both images, then with defmt and with the EtherCAT slave on SPI"
# What a newcomer types first: the workspace's default members are the drive and the bootloader (size-optimised
# by its per-package profile override); the bootloader's linker script refuses an image over its 32 KiB.
cargo build --release --target thumbv7em-none-eabihf
cargo build --release -p firmware --target thumbv7em-none-eabihf
cargo build --release -p firmware -p bootloader --target thumbv7em-none-eabihf --features defmt
cargo build --release -p firmware --target thumbv7em-none-eabihf --bin drive --features "ethercat defmt"

step "docs (warnings denied)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps

step "tests (host unit, property, scenario, generated-file, Python-master and QEMU tests)"
skip_report="$target_dir/skipped-tests.txt"
rm -f "$skip_report"
cargo test --workspace
finish_step

printf '\n==> step times (total %d s)\n' $(($(date +%s) - run_start))
printf '%s\n' "${timings[@]}"
if [ -s "$skip_report" ]; then
  printf '\n==> %d tests skipped for a missing prerequisite (scripts/setup.sh installs them; under CI=true they fail):\n' \
    "$(wc -l <"$skip_report")"
  sed 's/^/  /' "$skip_report"
else
  printf '\n==> no test skipped for a missing prerequisite\n'
fi
