#!/usr/bin/env bash
# The main job: the service and a simulated fleet on an embedded Zenoh peer. Sets itself up first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/simpletrack demo "$@"
