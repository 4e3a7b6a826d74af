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

# shellcheck disable=SC2086
exec sh "$(dirname "$0")/apt_install.sh" install_toolchain.sh $PKGS
