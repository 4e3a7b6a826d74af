#!/bin/sh
# Install Debian's Chromium, the headless browser the HTML report test (tests/cli/test_report_browser.py)
# opens reports in. Idempotent: does nothing (fast) when it is installed.
# Needs root to install; when not root and it is missing it says what to run and fails.
set -eu

PKGS="chromium"

missing=""
for p in $PKGS; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing="$missing $p"
    fi
done

if [ -z "$missing" ]; then
    exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
    echo "install_browser.sh: missing packages:$missing" >&2
    echo "run as root: apt-get update && apt-get install -y$missing" >&2
    exit 1
fi

echo "install_browser.sh: installing$missing"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
# shellcheck disable=SC2086
apt-get install -y -qq --no-install-recommends $missing >/dev/null
echo "install_browser.sh: done"
