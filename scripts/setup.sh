#!/usr/bin/env bash
# Installs what the tests need on a fresh machine of the project's kind (Debian, root, registries reachable):
# the pinned toolchain's thumbv7em target and components, QEMU and tshark, the Python packages of the real-master
# tests. Idempotent: a second run finds everything in place, says so, and changes nothing.
#
# rust-toolchain.toml names the target and components, but rustup acts on those lists only when it installs the
# toolchain itself; where the pinned toolchain is already present nothing adds them, so this script does.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf 'setup: %s\n' "$*"; }
fail() {
  printf 'setup: FAILED: %s\n' "$*" >&2
  exit 1
}

# --- Rust: the pinned toolchain, the target and the components the build, lints and tools call.
toolchain=$(sed -n 's/^channel *= *"\(.*\)"/\1/p' rust-toolchain.toml)
[ -n "$toolchain" ] || fail "rust-toolchain.toml names no channel"
command -v rustup >/dev/null 2>&1 || fail "rustup is not installed (the project pins Rust $toolchain through rustup)"
if ! rustup toolchain list | grep -q "^$toolchain"; then
  say "installing Rust $toolchain"
  rustup toolchain install "$toolchain" --profile minimal || fail "rustup cannot install Rust $toolchain"
fi
# The thumbv7em target: the firmware images, their clippy runs and the QEMU tests.
target=thumbv7em-none-eabihf
if rustup target list --toolchain "$toolchain" --installed | grep -qx "$target"; then
  say "target $target: installed"
else
  say "adding target $target to Rust $toolchain"
  rustup target add --toolchain "$toolchain" "$target" || fail "rustup cannot add the target $target"
fi
# rustfmt and clippy (format and lint steps), llvm-tools (llvm-size: the image sizes of qemu-bench and the QEMU
# tests).
installed_components=$(rustup component list --toolchain "$toolchain" --installed)
for component in rustfmt clippy llvm-tools; do
  if grep -q "^$component" <<<"$installed_components"; then
    say "component $component: installed"
  else
    say "adding component $component to Rust $toolchain"
    rustup component add --toolchain "$toolchain" "$component" || fail "rustup cannot add the component $component"
  fi
done

# --- Debian packages.
need_apt=()
# qemu-system-arm: the QEMU image tests and qemu-bench (netduinoplus2).
command -v qemu-system-arm >/dev/null 2>&1 || need_apt+=(qemu-system-arm)
# tshark: the EtherCAT dissectors check the capture of a real-master run (tests/tests/ecat_real_masters.rs).
command -v tshark >/dev/null 2>&1 || need_apt+=(tshark)
# unshare (util-linux) and ip (iproute2): the private network namespaces of the real-master tests.
command -v unshare >/dev/null 2>&1 || need_apt+=(util-linux)
command -v ip >/dev/null 2>&1 || need_apt+=(iproute2)
if [ ${#need_apt[@]} -gt 0 ]; then
  say "installing Debian packages: ${need_apt[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq || fail "apt-get update failed"
  apt-get install -y -qq "${need_apt[@]}" >/dev/null || fail "apt-get cannot install ${need_apt[*]}"
else
  say "Debian packages (qemu-system-arm, tshark, util-linux, iproute2): installed"
fi

# --- Python packages of the real-master and EDS tests, at the versions pinned in the requirements file.
requirements=tests/python/requirements.txt
if python3 - "$requirements" <<'PY'
import sys
from importlib.metadata import version, PackageNotFoundError
missing = []
for line in open(sys.argv[1]):
    line = line.split("#")[0].strip()
    if not line:
        continue
    name, _, wanted = line.partition("==")
    try:
        if wanted and version(name) != wanted:
            missing.append(line)
    except PackageNotFoundError:
        missing.append(line)
sys.exit(1 if missing else 0)
PY
then
  say "Python packages of $requirements: installed"
else
  say "installing the Python packages of $requirements"
  python3 -m pip install -q --disable-pip-version-check --root-user-action=ignore -r "$requirements" ||
    fail "pip cannot install $requirements"
fi

# --- The real-master tests run in private user and network namespaces.
if unshare -Urn true 2>/dev/null; then
  say "user and network namespaces: available"
else
  say "warning: 'unshare -Urn true' fails here: the real-master tests cannot run (under CI=true they fail)"
fi
say "done"
