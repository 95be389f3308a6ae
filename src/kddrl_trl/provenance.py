"""What produced a result: the code's commit, the package versions and the machine.

Every run's ``summary.json`` records :func:`provenance` (``report`` in :mod:`kddrl_trl.factories`), and the
reproduction report's footer lists what its runs recorded beside what made the report, so a table built up over
several sessions (or machines) says which code and machine each of its runs came from.
"""

from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

#: the packages whose versions change a result
PACKAGES = ("kddrl_trl", "torch", "torchrl", "tensordict", "libsumo", "numpy", "scipy", "hydra-core")


def versions() -> dict[str, str]:
    """``{package: version}`` of :data:`PACKAGES` (``"not installed"`` where missing)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def commit(where: str | Path | None = None) -> str:
    """The git commit of the checkout holding ``where`` (default: the working directory, then this package's
    folder), ``+dirty`` when tracked files differ from it; ``"unknown"`` outside a checkout (an installed
    wheel run from elsewhere)."""
    for folder in [Path(where)] if where else [Path.cwd(), Path(__file__).parent]:
        try:
            head = subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10, cwd=folder
            )
            if head.returncode or not head.stdout.strip():
                continue
            dirty = subprocess.run(
                ["git", "status", "--porcelain", "--untracked-files=no", "--", "src"],
                capture_output=True,
                text=True,
                timeout=10,
                cwd=folder,
            )
            return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
        except (OSError, subprocess.SubprocessError):
            continue
    return "unknown"


_LOADED: dict[str, str] = {}


def code_commit() -> str:
    """:func:`commit` of the code this process runs: the checkout holding this package's files (not the working
    directory's, which may be another checkout: a job run from one worktree with another's ``src`` first on
    ``PYTHONPATH``), ``"unknown"`` for an installed package outside a checkout. Read once, at the first call: an entry
    point calls it as it starts, so a run records the commit its code was loaded from, not the one checked out when it
    ends (a campaign's runs last while later commits land in the same checkout)."""
    if "commit" not in _LOADED:
        _LOADED["commit"] = commit(Path(__file__).parent)
    return _LOADED["commit"]


def cpu_model(cpuinfo: str | None = None) -> str:
    """The processor's model name, with its x86 family, model and stepping and whether it has AVX-512, from
    ``/proc/cpuinfo`` on Linux (``cpuinfo``: its text), else :func:`platform.processor`: the same code, seed and
    packages give other float arithmetic on another CPU, and one model name ("AMD EPYC") covers generations whose
    vector units differ, so a run records which one it ran on. No comma: :func:`machine` joins its parts with one."""
    try:
        text = Path("/proc/cpuinfo").read_text() if cpuinfo is None else cpuinfo
    except OSError:
        text = ""
    first = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        first.setdefault(key.strip(), value.strip())
    name = first.get("model name") or platform.processor() or "CPU model unknown"
    ids = [f"{k} {first[k]}" for k in ("cpu family", "model", "stepping") if first.get(k)]
    if not ids:
        return name
    vector = "AVX-512" if "avx512f" in first.get("flags", "").split() else "no AVX-512"
    return f"{name} [{' '.join(ids)}; {vector}]"


def machine() -> str:
    """One line: platform, CPU model, Python and CPU count."""
    return f"{platform.platform()}, {cpu_model()}, Python {platform.python_version()}, {os.cpu_count()} CPUs"


def provenance() -> dict:
    """``{"commit", "machine", "packages"}``: what a run's ``summary.json`` records."""
    return {"commit": code_commit(), "machine": machine(), "packages": versions()}
