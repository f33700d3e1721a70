"""jit.cache_state(): what preload() will have to compile, told from numba's on-disk cache
without compiling (the service logs a cold cache's compile: tens of seconds at a first start)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from simpletrack.core import jit


def _double(x: float) -> float:
    return 2.0 * x


@pytest.fixture
def cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty numba cache (NUMBA_CACHE_DIR, read by numba when it locates a cache)."""
    if not jit.compiled():
        pytest.skip("numba unavailable or SIMPLETRACK_JIT=0")
    import numba

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    return tmp_path


def test_a_kernel_is_cold_until_compiled_once_then_warm_for_a_new_process(
    cache_dir: Path,
) -> None:
    cold = jit.cache_state([jit.Kernel(_double, "float64(float64)")])
    assert (cold.kernels, cold.cold) == (1, 1)
    assert cold.location is not None and Path(cold.location).is_relative_to(cache_dir)

    compiled = jit.Kernel(_double, "float64(float64)")
    assert compiled(2.0) == 4.0 and compiled.is_compiled  # compiled, and saved in the cache
    assert jit.cache_state([compiled]).kernels == 0  # loaded: nothing left for preload()

    # A new Kernel stands for the next process: its code is in the cache now.
    assert jit.cache_state([jit.Kernel(_double, "float64(float64)")]) == jit.CacheState(
        1, 0, cold.location
    )
    # Another signature is another compile.
    assert jit.cache_state([jit.Kernel(_double, "float32(float32)")]).cold == 1


def test_a_fresh_process_with_an_empty_cache_finds_every_kernel_of_the_core_cold(
    cache_dir: Path,
) -> None:
    """What a first ``serve`` after an install sees (a process: this one loaded kernels)."""
    probe = "from simpletrack.core import jit; s = jit.cache_state(); print(s.kernels, s.cold)"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    out = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
    )
    kernels, cold = map(int, out.stdout.split())
    assert kernels == cold >= len(jit._KERNEL_MODULES)  # each module has a kernel at least


CALLEE = """
from simpletrack.core.jit import kernel
STEP = {step}
@kernel("float64(float64)")
def g(x):
    return x + STEP
"""
CALLER = """
from simpletrack.core.jit import kernel
from {pkg}.callee import g
@kernel("float64(float64)")
def f(x):
    return g(x) * 10.0
"""
RUN = """
from simpletrack.core import jit
from {pkg}.caller import f
print(jit.cache_state([f]).cold, f(1.0))
"""


def test_a_callee_changed_in_another_file_is_compiled_again_not_loaded_stale(
    cache_dir: Path, tmp_path: Path
) -> None:
    """Numba's own cache checks only a kernel's file: after a ``git pull`` that changed a
    callee's module (here a constant in it) and not the caller's, the caller's cached machine
    code ran the old callee (20.0 here instead of 30.0)."""
    pkg = f"jitprobe_{os.getpid()}"
    root = tmp_path / "src"
    (root / pkg).mkdir(parents=True)
    (root / pkg / "__init__.py").write_text("")
    (root / pkg / "caller.py").write_text(CALLER.format(pkg=pkg))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(root)}

    def run() -> tuple[int, float]:
        out = subprocess.run(
            [sys.executable, "-c", RUN.format(pkg=pkg)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
        cold, value = out.stdout.split()
        return int(cold), float(value)

    (root / pkg / "callee.py").write_text(CALLEE.format(step=1.0))
    assert run() == (1, 20.0)  # compiled
    assert run() == (0, 20.0)  # loaded from the cache
    folder = next(cache_dir.rglob("caller.f__*.nbi")).parent
    legacy = folder / "caller.f-5.py311.nbi"  # as named before the digest
    neighbour = folder / "caller.f_x__0123456789ab-9.py311.nbi"  # another kernel's
    for planted in (legacy, neighbour):
        planted.write_bytes(b"")
    (root / pkg / "callee.py").write_text(CALLEE.format(step=2.0))
    assert run() == (1, 30.0)  # the caller's file is unchanged: compiled again all the same
    assert run() == (0, 30.0)
    # The entries of the old sources are gone, the other kernel's kept.
    names = sorted(p.name.split("-")[0] for p in folder.glob("*.nbi"))
    assert len(names) == 3 and names[0].startswith("callee.g__"), names
    assert not legacy.exists() and neighbour.exists()
