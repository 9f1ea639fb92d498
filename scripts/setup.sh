#!/usr/bin/env bash
# Installs what the tests need on a fresh machine of the project's kind (Debian, root, registries reachable).
# Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."

# Rust toolchain, thumbv7em target and llvm-tools: rust-toolchain.toml names them; rustup fetches on first use.
rustup show active-toolchain >/dev/null

need_apt=()
command -v qemu-system-arm >/dev/null 2>&1 || need_apt+=(qemu-system-arm)
# tshark: the EtherCAT dissectors check the capture of a real-master run (tests/tests/ecat_real_masters.rs).
command -v tshark >/dev/null 2>&1 || need_apt+=(tshark)
if [ ${#need_apt[@]} -gt 0 ]; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

# Python packages for the real-master and EDS tests.
python3 -m pip install -q --disable-pip-version-check --root-user-action=ignore -r tests/python/requirements.txt
