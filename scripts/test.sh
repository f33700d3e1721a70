#!/usr/bin/env bash
# The whole test suite: lint, types, then pytest. Sets itself up first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check service schemas clients tests
.venv/bin/ruff format --check service schemas clients tests
.venv/bin/mypy service/simpletrack schemas/simpletrack clients/simpletrack
exec .venv/bin/python -m pytest "$@"
