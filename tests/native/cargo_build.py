"""Building the Rust client (clients/rust) from a test: where cargo is, where its build
cache lives (outside the checkout), and the skip rule (no cargo: skip, but fail under CI)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.service_helpers import ROOT

RUST_DIR = ROOT / "clients" / "rust"
# A cold build compiles ~340 crates (minutes on 2 cores); later ones reuse this cache.
BUILD_TIMEOUT_S = 1700


def target_dir() -> Path:
    default = Path.home() / ".cache" / "simpletrack" / "cargo-target"
    return Path(os.environ.get("SIMPLETRACK_CARGO_TARGET") or default)


def need_cargo() -> str:
    """The cargo executable; without one the test is skipped, except under CI (CI=true),
    which must run these tests and so fails."""
    cargo = shutil.which("cargo")
    rustup_default = Path.home() / ".cargo" / "bin" / "cargo"  # rustup's, when not on PATH
    if cargo is None and rustup_default.is_file():
        cargo = str(rustup_default)
    if cargo is None:
        message = "cargo is not installed: the Rust client cannot be built"
        if os.environ.get("CI") == "true":
            pytest.fail(message)
        pytest.skip(message)
    return cargo


def cargo(*args: str) -> subprocess.CompletedProcess[str]:
    """``cargo ARGS`` in clients/rust with the shared target dir, two jobs at most."""
    exe = need_cargo()
    env = {**os.environ, "CARGO_TARGET_DIR": str(target_dir()), "CARGO_TERM_COLOR": "never"}
    return subprocess.run(
        [exe, *args, "-j", "2", "--locked"],
        cwd=RUST_DIR,
        env=env,
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT_S,
        check=False,
    )


def example(name: str) -> Path:
    """The built example ``name`` (built now if needed)."""
    out = cargo("build", "--examples")
    assert out.returncode == 0, f"cargo build --examples failed:\n{out.stderr[-4000:]}"
    path = target_dir() / "debug" / "examples" / name
    assert path.is_file(), f"{path} was not built"
    return path
