#!/bin/sh
# Install the AVR toolchain and simavr (Debian packages) needed to build the firmware and the
# simavr harness. Idempotent: does nothing (fast) when every package is already installed.
# Needs root to install; when not root and something is missing it says what to run and fails.
set -eu

# gcc, libc6-dev and make build the simavr harness (a fresh Debian image may lack them).
# arduino-core-avr also carries optiboot's source (bootloaders/optiboot/optiboot.c), which
# firmware/Makefile builds into the Uno bootloader the simavr harness loads (its prebuilt .hex
# overflows the 512-byte boot section).
PKGS="gcc-avr avr-libc arduino-core-avr avrdude simavr libsimavr-dev libelf-dev pkg-config gcc libc6-dev make"

missing=""
for p in $PKGS; do
    # dpkg-query prints "install ok installed" for an installed package.
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing="$missing $p"
    fi
done

if [ -z "$missing" ]; then
    exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
    echo "install_toolchain.sh: missing packages:$missing" >&2
    echo "run as root: apt-get update && apt-get install -y$missing" >&2
    exit 1
fi

echo "install_toolchain.sh: installing$missing"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
# shellcheck disable=SC2086
apt-get install -y -qq --no-install-recommends $missing >/dev/null
echo "install_toolchain.sh: done"
