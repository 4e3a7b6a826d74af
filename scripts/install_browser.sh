#!/bin/sh
# Install Debian's Chromium, the headless browser the HTML report tests (tests/report/test_browser.py)
# opens reports in. Idempotent: does nothing (fast) when it is installed.
# Needs root to install; when not root and it is missing it says what to run and fails.
set -eu

PKGS="chromium"

# shellcheck disable=SC2086
exec sh "$(dirname "$0")/apt_install.sh" install_browser.sh $PKGS
