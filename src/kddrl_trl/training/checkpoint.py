"""Training checkpoints of a run directory: written atomically, the latest one found by ``resume``.

Layout (:mod:`kddrl_trl.run_folder`): ``<run_dir>/checkpoints/ep<NNNNNN>.pt`` (one file: learner networks, targets,
optimisers, exploration schedules, counters, the training-episode history and — unless ``keep_buffers=false``
— the contents of both replay buffers; not the unfinished macro-transitions: the environments restart on
resume, so intervals open at the checkpoint are dropped) and ``<run_dir>/checkpoints/latest`` (the file name of
the newest complete checkpoint). A file is complete before ``latest`` names it, so a run killed at any moment
resumes from its last complete checkpoint. The newest two checkpoints are kept (older ones are deleted after the
pointer moves), so a checkpoint damaged after it was written (a truncated copy, a full disk, a bad sector) costs
``checkpoint_every`` episodes, not the run: :func:`load_latest_training_checkpoint` names the file and the cause,
warns, and falls back to the previous one; it fails only when none loads, listing each file and its error.
Temporary files left by a writer killed mid-write (``.ep*.pt.*.tmp``) are never read and are removed by the next
save.
``<run_dir>/checkpoints/best.pt``: the learner with the best validation score so far (periodic evaluation,
:class:`~kddrl_trl.training.Trainer`) and that evaluation's record.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from ..atomic_files import CheckpointError, remove_killed_writes, torch_save_atomic, write_text_atomic
from ..policies import POLICY_FORMAT
from ..run_folder import LATEST, best_checkpoint, checkpoint_candidates, checkpoint_dir

log = logging.getLogger(__name__)

FORMAT = "kddrl_trl.training/1"


def save_training_checkpoint(run_dir: str | Path, episodes: int, payload: dict, keep: int = 2) -> Path:
    """Write ``payload`` as the checkpoint after ``episodes`` training episodes; keep the newest ``keep``
    (default two: the previous one is the fallback of a damaged newest one)."""
    folder = checkpoint_dir(run_dir)
    remove_killed_writes(folder)  # of a checkpoint, `latest` or best.pt: never a checkpoint
    path = torch_save_atomic(folder / f"ep{episodes:06d}.pt", {"format": FORMAT, **payload})
    write_text_atomic(folder / LATEST, path.name + "\n")
    for old in sorted(folder.glob("ep*.pt"))[: -max(int(keep), 1)]:
        old.unlink(missing_ok=True)
    return path


def save_best_checkpoint(run_dir: str | Path, payload: dict) -> Path:
    """Write ``payload`` (``learner`` state and its ``validation`` record) as ``checkpoints/best.pt``."""
    return torch_save_atomic(best_checkpoint(run_dir), {"format": FORMAT, **payload})


def load_training_checkpoint(path: str | Path) -> dict:
    """Load a checkpoint written by :func:`save_training_checkpoint` (our own file: full unpickling). A file that
    does not load raises :class:`CheckpointError` naming it and the cause."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # torch/zip/pickle errors name no file: add it
        raise CheckpointError(f"{path}: cannot be loaded ({type(err).__name__}: {err})") from err
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a kddrl_trl training checkpoint (format {FORMAT!r})")
    return payload


def load_latest_training_checkpoint(run_dir: str | Path) -> tuple[Path, dict]:
    """(path, payload) of the newest checkpoint of ``run_dir`` that loads. Each newer one that does not is named
    in a warning with its cause; :class:`CheckpointError` lists every file and its error when none loads
    (:class:`FileNotFoundError` when there is none)."""
    candidates = checkpoint_candidates(run_dir)
    if not candidates:
        raise FileNotFoundError(f"no checkpoint in {checkpoint_dir(run_dir)}")
    errors = []
    for path in candidates:
        try:
            payload = load_training_checkpoint(path)
        except CheckpointError as err:
            errors.append(str(err))
            log.warning(
                "%s; %s", err, "trying the previous checkpoint" if path != candidates[-1] else "no older checkpoint"
            )
            continue
        if errors:
            log.warning("resuming from %s instead: the %d newer checkpoint(s) did not load", path, len(errors))
        return path, payload
    raise CheckpointError(f"no checkpoint of {checkpoint_dir(run_dir)} loads:\n  " + "\n  ".join(errors))


def save_policy(path: str | Path, modules: dict) -> Path:
    """A shipped policy's ``policy.pt``: the learner's network parameters (``modules`` of its full state dict), with
    the format tag :data:`~kddrl_trl.policies.POLICY_FORMAT`; written atomically."""
    torch_save_atomic(path, {"format": POLICY_FORMAT, "modules": modules})
    return Path(path)


def load_policy(path: str | Path) -> dict:
    """A ``policy.pt`` written by :func:`save_policy`; one that does not load, or of another format, raises
    :class:`CheckpointError` naming it."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:
        raise CheckpointError(f"{path}: cannot be loaded ({type(err).__name__}: {err})") from err
    if not isinstance(payload, dict) or payload.get("format") != POLICY_FORMAT:
        raise CheckpointError(f"{path}: not a kddrl_trl policy (format {POLICY_FORMAT!r})")
    return payload
