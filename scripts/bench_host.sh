#!/usr/bin/env bash
# "A host's worth of streams" measured on a bare many-core host in one run of fixed steps
# (docs/BENCHMARKS.md, "On a bare host, in one run"): the capacity of 1, 4 and 8 members with
# the load generator pinned to 4 CPUs and the members on the rest (each count over its own
# range of sensors), then a failover and a hand-off among 8 members holding 1,000 sensors. Each step has its own time limit, so the
# whole stays within about 8 minutes, and its output is kept even when a step fails.
#
#   bash scripts/bench_host.sh --fetch-wheels   # here: the wheels a bare host lacks, into .whl/
#   bash scripts/bench_host.sh OUT              # there: everything, figures under OUT/
#   bash scripts/bench_host.sh OUT --quick      # any machine: the same steps, tiny (a rehearsal)
#
# A bare host has Python and the scientific stack but not Zenoh or pydantic: the wheels in
# .whl/ (git ignores it) go into a scratch folder there, and the project runs from its source
# folders (one namespace package over clients/, service/ and schemas/), nothing installed.
set -uo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WHEELS="${WHEELS:-$ROOT/.whl}"
PY="${PYTHON:-python3}"
# What a bare host lacked (Python 3.12, numpy, scipy, numba, msgpack, prometheus-client, rich
# and pyyaml there; typing-extensions too, in case); the versions are this checkout's environment's.
MISSING=(eclipse-zenoh pydantic pydantic-core pydantic-settings annotated-types
  typing-inspection typing-extensions python-dotenv mcap backports.zstd)

if [[ "${1:-}" == "--fetch-wheels" ]]; then
  [[ -z "${PYTHON:-}" && -x "$ROOT/.venv/bin/python" ]] && PY="$ROOT/.venv/bin/python"
  pins=()
  for name in "${MISSING[@]}"; do
    version="$("$PY" -c "import importlib.metadata as m, sys; print(m.version(sys.argv[1]))" "$name")" ||
      { echo "bench_host: $name is not installed here (run scripts/setup.sh first)" >&2; exit 2; }
    pins+=("$name==$version")
  done
  "$PY" -m pip download --no-deps --only-binary=:all: --python-version "${HOST_PYTHON:-3.12}" \
    --implementation cp --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    --platform manylinux_2_28_x86_64 -d "$WHEELS" "${pins[@]}" || exit 1
  du -sh "$WHEELS"
  exit 0
fi

OUT="${1:?usage: bash scripts/bench_host.sh OUT [--quick] | --fetch-wheels}"
QUICK=0
[[ "${2:-}" == "--quick" ]] && QUICK=1
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
SCRATCH="$(mktemp -d)"
START=$(date +%s)
log() { echo "[bench_host +$(($(date +%s) - START))s] $*" | tee -a "$OUT/steps.log"; }

# ---------------------------------------------------------------- the Python environment
SITE=""
if ! "$PY" -c "import zenoh, pydantic_settings" 2>/dev/null; then
  compgen -G "$WHEELS/*.whl" >/dev/null ||
    { log "no zenoh here and no wheels in $WHEELS (bash scripts/bench_host.sh --fetch-wheels)"; exit 2; }
  SITE="$SCRATCH/site"
  "$PY" -m pip install --quiet --no-index --no-deps --target "$SITE" "$WHEELS"/*.whl ||
    { log "installing the wheels failed"; exit 2; }
fi
export PYTHONPATH="${SITE:+$SITE:}$ROOT/clients:$ROOT/service:$ROOT/schemas${PYTHONPATH:+:$PYTHONPATH}"
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$SCRATCH/numba}"
ST=("$PY" -m simpletrack.cli.main)

# The CPUs this process may use (a container's cpuset need not start at 0).
read -r -a CPU_LIST <<<"$("$PY" -c "import os; print(*sorted(os.sched_getaffinity(0)))")"
CPUS=${#CPU_LIST[@]}
{
  echo "commit: $(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)"
  echo "cpus: $CPUS ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //'))"
  echo "memory: $(awk '/MemTotal/ {printf "%.0f GiB", $2 / 1048576}' /proc/meminfo)"
  echo "python: $("$PY" --version 2>&1)"
  echo "load average at start: $(cut -d' ' -f1-3 /proc/loadavg)"
} | tee "$OUT/machine.txt"

log "compiling the kernels"
"$PY" -c "from simpletrack.core import jit; jit.preload()" >"$OUT/preload.txt" 2>&1 ||
  { log "the kernels did not compile"; tail -20 "$OUT/preload.txt"; exit 1; }
log "compiled"

# The generator's fixed budget: the first 4 CPUs (1 below 16); the members (and the bench) on
# the others.
join() { local IFS=,; echo "$*"; }
if ((CPUS >= 16)); then
  GEN="$(join "${CPU_LIST[@]:0:4}")" MEMBERS="$(join "${CPU_LIST[@]:4}")"
elif ((CPUS >= 2)); then
  GEN="${CPU_LIST[0]}" MEMBERS="$(join "${CPU_LIST[@]:1}")"
else
  log "needs 2 CPUs at least, found $CPUS"; exit 2
fi
log "generator on CPUs $GEN, members on $MEMBERS"
# Each member count searches its own range (a group of 8 starting at 80 sensors would spend
# its time below its capacity): the per-frame CPU at each count's largest passing step is the
# comparison must-have 1 asks for.
if ((QUICK)); then
  CAPACITY=("1:2,4" "2:2,4") DURATION=2 GENS=1 LIMIT=90
  FAULT_MEMBERS=2 FAULT_SENSORS=4 FAULT_DURATION=4 FAULT_LIMIT=120
else
  CAPACITY=("1:40,80,120,160" "4:160,320,480,640" "8:480,800,1000,1200,1400") DURATION=5 GENS=4
  LIMIT=95 FAULT_MEMBERS=8 FAULT_SENSORS=1000 FAULT_DURATION=10 FAULT_LIMIT=120
fi

step() {  # step NAME LIMIT_S ARGS...: one bench run, its output kept whatever happens
  local name="$1" limit="$2"
  shift 2
  log "$name: ${*}"
  timeout --signal=INT --kill-after=15 "$limit" taskset -c "$MEMBERS" "${ST[@]}" bench scale \
    --source synthetic --generator-processes "$GENS" --generator-cpus "$GEN" \
    --out "$OUT/$name" "$@" >"$OUT/$name.txt" 2>&1
  local rc=$?
  log "$name: exit $rc (124: past its ${limit} s limit)"
  tail -25 "$OUT/$name.txt"
}

for spec in "${CAPACITY[@]}"; do
  step "capacity-${spec%%:*}" "$LIMIT" --instances "${spec%%:*}" --sensors "${spec#*:}" \
    --duration "$DURATION" --warmup 2 --budget $((LIMIT - 25)) --fault-sensors 0
done
step faults "$FAULT_LIMIT" --instances "$FAULT_MEMBERS" --sensors 1 --duration "$FAULT_DURATION" \
  --warmup 3 --fault-sensors "$FAULT_SENSORS"
log "done; load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)"
rm -rf "$SCRATCH"
