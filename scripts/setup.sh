#!/usr/bin/env bash
# Idempotent set-up: a virtual environment in .venv with the package and its test tools.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
extras="service,plot,test,foxglove"
if [ "${CI:-}" = "true" ]; then extras="$extras,deploy-lint"; fi
stamp=.venv/.installed-${extras//,/-}
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  # pip and setuptools are chatty (build warnings); show their output only when they fail.
  log=$(mktemp)
  if ! { .venv/bin/python -m pip install --quiet --upgrade pip &&
         .venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[$extras]"; } >"$log" 2>&1; then
    cat "$log" >&2
    echo "setup: installing the package failed (output above)" >&2
    exit 1
  fi
  rm -f "$log"
  touch "$stamp"
fi
# Compile the tracker's kernels now (numba caches them beside the source): the first demo,
# service or test then loads them in under a second instead of compiling for ~20 s.
.venv/bin/python -c "from simpletrack.core import jit; jit.preload()" \
  || echo "setup: compiling the kernels failed; they compile on first use (or run uncompiled)" >&2
# System services used by the end-to-end tests (Prometheus); optional outside CI.
if [ "${CI:-}" = "true" ] && ! command -v prometheus >/dev/null 2>&1 && [ "$(id -u)" = "0" ]; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq prometheus >/dev/null) \
    || echo "setup: prometheus could not be installed; its tests will skip" >&2
fi
# Headers the C++ client builds and tests with (tests/native); optional outside CI.
if [ "${CI:-}" = "true" ] && [ "$(id -u)" = "0" ] &&
   { [ ! -f /usr/include/msgpack.hpp ] || [ ! -f /usr/include/nlohmann/json.hpp ]; }; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
     libmsgpack-cxx-dev nlohmann-json3-dev >/dev/null 2>&1) \
    || echo "setup: msgpack-c++/nlohmann-json headers could not be installed; tests/native will fail" >&2
fi
# The browser the view's page is drawn with (tests/view/test_page.py); optional outside CI.
if [ "${CI:-}" = "true" ] && ! command -v chromium >/dev/null 2>&1 && [ "$(id -u)" = "0" ]; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
    || echo "setup: chromium could not be installed; tests/view/test_page.py will fail" >&2
fi
