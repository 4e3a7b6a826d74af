#!/bin/sh
# apt_install.sh NAME PACKAGE...: install the Debian packages that are missing (the project's own
# scripts call it: install_toolchain.sh, install_browser.sh). Idempotent: does nothing (fast) when
# every package is installed. Needs root to install; when not root and something is missing it says
# what to run and fails.
set -eu

name="$1"
shift

missing=""
for p in "$@"; do
    # dpkg-query prints "install ok installed" for an installed package.
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing="$missing $p"
    fi
done

if [ -z "$missing" ]; then
    exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
    echo "$name: missing packages:$missing" >&2
    echo "run as root: apt-get update && apt-get install -y$missing" >&2
    exit 1
fi

echo "$name: installing$missing"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
# shellcheck disable=SC2086
apt-get install -y -qq --no-install-recommends $missing >/dev/null
echo "$name: done"
