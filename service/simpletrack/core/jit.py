"""The one way the core compiles kernels: numba ``njit(nogil=True, cache=True)``, on first use.

- ``import numba`` costs ~0.4 s, which ``import simpletrack.core`` (and every command) must not
  pay: ``@kernel`` returns a small wrapper that imports numba and compiles on its first call.
  ``preload()`` compiles (or loads from numba's on-disk cache) every kernel now, for a service
  whose first frame must not wait; ``cache_state()`` tells beforehand how many it will have
  to compile (a cold cache: the first start after an install or a change of the kernels).
- ``nogil``: a worker thread running a kernel lets the others run theirs on the other cores.
  ``cache``: compiled once per machine (numba's cache beside the source, or the user's cache
  when that is read-only), loaded in milliseconds afterwards. A kernel's cache entry is named
  for the sources of its module and of the project's modules it imports: numba alone would
  keep a kernel's machine code after a callee changed in another file.
- A kernel may call functions marked ``@helper`` (plain Python functions) and other kernels:
  they are compiled with the kernel, and stay plain Python (or their own kernel) when the
  kernel runs uncompiled.
- Without a working numba, or with ``SIMPLETRACK_JIT=0`` (tests compare both ways), a kernel
  runs its own Python function: the same arithmetic, slower. A missing or failing numba warns
  once. This is the only module of the core that reads the environment.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import importlib.util
import os
import re
import threading
import types
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, ParamSpec, TypeVar

import numpy as np

P = ParamSpec("P")
R = TypeVar("R")

__all__ = [
    "CacheState",
    "Kernel",
    "cache_state",
    "compiled",
    "helper",
    "inline",
    "kernel",
    "preload",
]

ENV_VAR = "SIMPLETRACK_JIT"
# Modules whose kernels preload() compiles: importing them registers their kernels.
_KERNEL_MODULES = (
    "simpletrack.core.overlap_kernels",
    "simpletrack.core.pair_kernels",
    "simpletrack.core.kalman_kernels",
    "simpletrack.core.motion_kernels",
    "simpletrack.core.revive_kernels",
    "simpletrack.core.assignment_kernels",
    "simpletrack.core.advance_kernels",
    "simpletrack.core.step_kernels",
    "simpletrack.core.calibration_kernels",
    "simpletrack.core.output_kernels",
    "simpletrack.core.packing_kernels",
    "simpletrack.core.input_kernels",
    "simpletrack.core.fused_kernels",
)
_HELPER_MARK = "__simpletrack_jit_helper__"
_PLAIN_MARK = "__simpletrack_jit_plain__"

_lock = threading.Lock()
_kernels: list[Kernel[Any, Any]] = []
_compiled_helpers: dict[Callable[..., Any], Any] = {}
_numba: Any = None  # the numba module once imported, False when unavailable or disabled


def helper(fn: Callable[P, R]) -> Callable[P, R]:
    """Mark ``fn`` as callable from kernels: it is compiled along with any kernel calling it."""
    setattr(fn, _HELPER_MARK, "never")
    return fn


def inline(fn: Callable[P, R]) -> Callable[P, R]:
    """A ``helper`` that numba inlines into its callers: for tiny functions called per element
    (a call costs more than their body; inlining big ones multiplies compile time)."""
    setattr(fn, _HELPER_MARK, "always")
    return fn


class Kernel(Generic[P, R]):
    """A function compiled by numba on first call; ``.py`` is the uncompiled function."""

    def __init__(self, fn: Callable[P, R], signature: str) -> None:
        self.py = fn
        self.signature = signature
        self.__name__ = fn.__name__
        self.__doc__ = fn.__doc__
        self._impl: Callable[P, R] | None = None

    def __call__(self, *args: P.args, **kwargs: P.kwargs) -> R:
        impl = self._impl or self.load()
        return impl(*args, **kwargs)

    @property
    def is_compiled(self) -> bool:
        return self._impl is not None and not getattr(self._impl, _PLAIN_MARK, False)

    def load(self) -> Callable[P, R]:
        """Compile now (or load the cached machine code); the Python function if no numba."""
        with _lock:
            if self._impl is None:
                numba = _numba_module()
                if numba is False:
                    self._impl = _quiet(self.py)
                else:
                    try:
                        linked = _linked(self.py)
                        self._impl = numba.njit(self.signature, **_OPTIONS)(linked)
                    except Exception as exc:  # a broken numba or llvmlite: still right, slower
                        _warn(f"compiling {self.py.__qualname__} failed ({exc!r})")
                        self._impl = _quiet(self.py)
                    else:
                        _forget_older(self.py, linked)
            return self._impl


# error_model="numpy": float division by zero gives inf/nan as in numpy instead of a check
# (and ZeroDivisionError) on every division; kernels guard their divisions themselves.
_OPTIONS: dict[str, Any] = {"nogil": True, "cache": True, "error_model": "numpy"}


def _quiet(fn: Callable[P, R]) -> Callable[P, R]:
    """``fn`` with numpy's floating-point warnings off, as compiled code has none: run as Python,
    the kernels' numpy scalars warn where IEEE arithmetic is intended (0 * inf in clipping)."""

    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        with np.errstate(all="ignore"):
            return fn(*args, **kwargs)

    setattr(run, _PLAIN_MARK, True)
    return run


def kernel(signature: str) -> Callable[[Callable[P, R]], Kernel[P, R]]:
    """Compile the decorated function lazily, for numba's explicit ``signature`` (one type per
    argument, so that preload() can compile it without sample arguments)."""

    def wrap(fn: Callable[P, R]) -> Kernel[P, R]:
        k = Kernel(fn, signature)
        _kernels.append(k)
        return k

    return wrap


def preload() -> None:
    """Compile or load every kernel of the core now."""
    for k in _registered():
        k.load()


@dataclass(frozen=True, slots=True)
class CacheState:
    """What ``preload()`` will find: of ``kernels`` not loaded yet, ``cold`` are missing from
    numba's on-disk cache (compiled, seconds each); ``location`` is the cache's folder."""

    kernels: int
    cold: int
    location: str | None


def cache_state(kernels: Iterable[Kernel[Any, Any]] | None = None) -> CacheState:
    """Probe numba's on-disk cache for every kernel ``preload()`` would load (or these),
    compiling nothing: a kernel is warm when the cache's index (the numba version's, for the
    source file as it is now) holds its signature for this CPU. Without numba (or disabled)
    nothing compiles. Numba's cache layout is not public: if probing fails, a kernel counts
    as cold."""
    pending = [k for k in (_registered() if kernels is None else kernels) if k._impl is None]
    with _lock:
        numba = _numba_module()
    if numba is False or not pending:
        return CacheState(len(pending), 0, None)
    try:
        caching: Any = importlib.import_module("numba.core.caching")
        registry: Any = importlib.import_module("numba.core.registry")
        codegen = registry.cpu_target.target_context.codegen()
    except Exception:
        return CacheState(len(pending), len(pending), None)
    cold, location = 0, None
    for k in pending:
        try:
            cache = caching.FunctionCache(_cached_as(k.py, k.py.__globals__))
            location = location or str(cache.cache_path)
            warm = cache._index_key(k.signature, codegen) in cache._cache_file._load_index()
        except Exception:
            warm = False
        cold += not warm
    return CacheState(len(pending), cold, location)


def _registered() -> list[Kernel[Any, Any]]:
    """Every kernel of the core (importing their modules registers them)."""
    for name in _KERNEL_MODULES:
        importlib.import_module(name)
    return list(_kernels)


def compiled() -> bool:
    """Whether kernels run compiled (numba importable and not disabled)."""
    with _lock:
        return _numba_module() is not False


def _numba_module() -> Any:
    """numba, imported once; False when disabled or unavailable. Call with _lock held."""
    global _numba
    if _numba is None:
        if os.environ.get(ENV_VAR, "1").strip() == "0":
            _numba = False
        else:
            try:
                import numba

                _numba = numba
            except Exception as exc:  # absent, or broken (e.g. numpy newer than it supports)
                _warn(f"numba is unavailable ({exc!r})")
                _numba = False
    return _numba


def _warn(why: str) -> None:
    warnings.warn(
        f"simpletrack.core: {why}; kernels run as plain Python (same results, much slower)",
        RuntimeWarning,
        stacklevel=4,
    )


def _linked(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` with the helpers it names bound to their numba dispatchers (recursively), as a
    copy named for its sources (``_cached_as``): the module keeps the plain functions for
    uncompiled use. Call with _lock held."""
    named = {name: fn.__globals__.get(name) for name in fn.__code__.co_names}
    swaps: dict[str, Any] = {}
    for name, value in named.items():
        if isinstance(value, Kernel):  # a kernel called by another: compiled into it
            swaps[name] = _compiled_helper(value.py, "never")
        elif callable(value) and getattr(value, _HELPER_MARK, False):
            swaps[name] = _compiled_helper(value)
    return _cached_as(fn, {**fn.__globals__, **swaps})


def _cached_as(fn: Callable[..., Any], globals_: dict[str, Any]) -> Callable[..., Any]:
    """A copy of ``fn`` whose qualified name carries the digest of its module's sources.
    Numba's cache files are named by it, and numba checks only the function's own file: a
    kernel keeps the machine code of a callee (or a constant) changed in another file, as
    after a ``git pull`` that touches ``kalman_kernels.py`` but not ``step_kernels.py``. A
    new digest is a new cache entry, so such a kernel is compiled again."""
    copy = types.FunctionType(fn.__code__, globals_, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__qualname__ = f"{fn.__qualname__}__{sources_digest(fn.__module__)}"
    copy.__module__ = fn.__module__
    copy.__doc__ = fn.__doc__
    return copy


def _forget_older(fn: Callable[..., Any], current: Callable[..., Any]) -> None:
    """Delete the cache files of ``fn`` under other digests (its sources before an edit or
    an upgrade): nothing loads them again. Best effort: another process may be at it too."""
    try:
        caching: Any = importlib.import_module("numba.core.caching")
        folder = Path(caching.FunctionCache(current).cache_path)
        stem = Path(fn.__code__.co_filename).stem
        name = f"{stem}.{fn.__qualname__}".replace("<", "").replace(">", "")
        mine = f"{stem}.{current.__qualname__}-".replace("<", "").replace(">", "")
        # Named by a digest, or as before digests were: "<file>.<qualname>[__<digest>]-<line>.py<v>"
        ours = re.compile(re.escape(name) + r"(__[0-9a-f]{12})?-\d+\.py\d+.*\.nb[ic]")
        for path in folder.glob(f"{name}*"):
            if ours.fullmatch(path.name) and not path.name.startswith(mine):
                path.unlink(missing_ok=True)
    except Exception:  # numba's cache layout is not public: at worst the files stay
        return


@functools.cache
def sources_digest(module: str) -> str:
    """A digest of the module's source and, transitively, of every module of its package
    (``simpletrack``) it imports at its top level (where kernels get their callees and
    constants)."""
    root = module.partition(".")[0]
    sources: dict[str, bytes] = {}

    def visit(name: str) -> None:
        if name in sources:
            return
        try:
            spec = importlib.util.find_spec(name)
            origin = None if spec is None else spec.origin
            sources[name] = Path(origin).read_bytes() if origin else b""
            tree = ast.parse(sources[name])
        except (ImportError, OSError, SyntaxError, ValueError):
            sources.setdefault(name, b"")
            return
        for node in tree.body:
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found = [node.module]
            elif isinstance(node, ast.Import):
                found = [a.name for a in node.names]
            else:
                continue
            for imported in found:
                if imported.partition(".")[0] == root:
                    visit(imported)

    visit(module)
    digest = hashlib.blake2b(digest_size=6)
    for name in sorted(sources):
        digest.update(name.encode() + b"\0" + sources[name] + b"\0")
    return digest.hexdigest()


def _compiled_helper(fn: Callable[..., Any], how: str | None = None) -> Any:
    if fn not in _compiled_helpers:
        # Typed and compiled with the first kernel calling it (or inlined into it).
        inline = how or getattr(fn, _HELPER_MARK)
        linked = _linked(fn)
        _compiled_helpers[fn] = _numba.njit(inline=inline, **_OPTIONS)(linked)
        _forget_older(fn, linked)
    return _compiled_helpers[fn]
