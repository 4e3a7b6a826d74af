#!/bin/sh
# Install the third-party Node clients the tests connect with (tests/clients: Foxglove's
# @foxglove/ws-protocol and ws, versions pinned in package.json and package-lock.json) into
# tests/clients/node_modules (never committed). Idempotent: nothing to do when installed.
# Needs node and npm; without them it says so and fails (the tests then skip, naming this script).
set -eu
cd "$(dirname "$0")/../tests/clients"
if [ -d node_modules/@foxglove/ws-protocol ] && [ -d node_modules/ws ] && [ node_modules -nt package-lock.json ]; then
    exit 0
fi
if ! command -v npm >/dev/null 2>&1; then
    echo "install_node_clients.sh: npm not found (install nodejs and npm)" >&2
    exit 1
fi
echo "install_node_clients.sh: npm ci in tests/clients"
npm ci --no-audit --no-fund --loglevel=error
