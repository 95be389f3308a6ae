"""Atomic file writes: a result is either complete on disk or not there at all.

Everything is written to a temporary file in the target folder, flushed and fsynced, then moved into
place with ``os.replace`` (atomic on POSIX and Windows); on any error the temporary file is removed.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Callable, TextIO


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used, of a training run or of a generative model: damaged, of another kind,
    architecture, dataset or layout, or none that loads. The message names each file and what is wrong with it; an
    entry point ends with that one line (:func:`kddrl_trl.run_folder.no_folder_if_refused`)."""


def cache_dir() -> Path:
    """The package's cache folder: ``$KDDRL_TRL_CACHE``, default ``~/.cache/kddrl_trl`` (created)."""
    root = Path(os.environ.get("KDDRL_TRL_CACHE", Path.home() / ".cache" / "kddrl_trl"))
    root.mkdir(parents=True, exist_ok=True)
    return root


def _ordinary_permissions(tmp: str) -> None:
    """``mkstemp`` creates 0600 files; give results the permissions any new file would get (umask)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)


#: the suffix of :func:`write_atomic`'s temporary files (named ``.<target name>.<random><suffix>``)
_TMP_SUFFIX = ".tmp"


def remove_killed_writes(folder: str | os.PathLike) -> None:
    """Remove the temporary files that writes killed mid-way (``kill -9``: no ``except`` ran) left in ``folder``.
    Only for a folder no other process is writing to at the same time."""
    for stale in Path(folder).glob(f".*{_TMP_SUFFIX}"):
        stale.unlink(missing_ok=True)


def write_atomic(
    path: str | os.PathLike, write: Callable[[TextIO], Any], newline: str | None = None, binary: bool = False
) -> Path:
    """Call ``write(fh)`` on a temporary file (text, or bytes with ``binary=True``) beside ``path``, then move
    it onto ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=_TMP_SUFFIX)
    try:
        _ordinary_permissions(tmp)
        with os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", newline=newline) as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def torch_save_atomic(path: str | os.PathLike, obj: Any) -> Path:
    """``torch.save(obj)`` atomically (see :func:`write_atomic`)."""
    import torch

    return write_atomic(path, lambda fh: torch.save(obj, fh), binary=True)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    return write_atomic(path, lambda fh: fh.write(text))


def write_json_atomic(path: str | os.PathLike, data: Any) -> Path:
    return write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True, default=float) + "\n")
