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
