"""Trained policies that ship with the package: ``python -m kddrl_trl.evaluate run=shipped:<name>`` drives one without
training (``video=true`` films it, ``gui=true`` shows it live).

Each is a folder ``policies/<name>/`` that reads as a training run's: its ``config.yaml`` (the run's), ``policy.pt``
(the learner's network parameters, no optimiser or buffer: :data:`POLICY_FORMAT`) and ``card.json`` (where it came
from: the run, its commit, seed and scenario, the checkpoint, and how it was chosen). They are made by
``python -m kddrl_trl.devtools.ship_policy`` from a finished run; an evaluation of one is written under
``runs/shipped__<name>/``.
"""

from __future__ import annotations

from pathlib import Path

#: the folder holding the shipped policies
SHIPPED_DIR = Path(__file__).resolve().parent
#: the ``run=`` prefix that names a shipped policy
PREFIX = "shipped:"
#: ``policy.pt`` 's format tag
POLICY_FORMAT = "kddrl_trl.policy/1"
POLICY_FILE, CARD_FILE = "policy.pt", "card.json"


def shipped_names() -> list[str]:
    """The names of the policies shipped with this install."""
    return sorted(p.name for p in SHIPPED_DIR.iterdir() if (p / POLICY_FILE).is_file())


def is_shipped(run) -> bool:
    return str(run).startswith(PREFIX)


def shipped_policy(run) -> Path:
    """The folder of ``shipped:<name>``; an unknown name raises ``FileNotFoundError`` listing the shipped ones."""
    name = str(run)[len(PREFIX) :]
    folder = SHIPPED_DIR / name
    if not name or "/" in name or not (folder / POLICY_FILE).is_file():
        names = shipped_names()
        raise FileNotFoundError(
            f"run={run}: no such shipped policy; shipped: {', '.join(names) if names else 'none in this install'}"
        )
    return folder


def output_folder(run) -> str:
    """Where an evaluation of ``run`` is written: ``runs/shipped__<name>`` for a shipped policy (never inside the
    installed package), ``run`` itself otherwise."""
    return f"runs/shipped__{str(run)[len(PREFIX) :]}" if is_shipped(run) else str(run)
