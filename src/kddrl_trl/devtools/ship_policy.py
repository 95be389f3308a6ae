"""Ship a finished run's trained policy with the package (:mod:`kddrl_trl.policies`).

    python -m kddrl_trl.devtools.ship_policy <run dir> <name> [--checkpoint latest|best] [--why "how it was chosen"]
        [--dest src/kddrl_trl/policies]

Writes ``<dest>/<name>/``: the run's ``config.yaml``, ``policy.pt`` (the learner's networks of its latest or best
checkpoint, no optimiser or buffer) and ``card.json`` (the run, its commit, algo, scenario and seed, the
checkpoint, the episodes it trained, its final evaluation's mean speed and collision rate, and ``--why``). A user
then drives it with ``python -m kddrl_trl.evaluate run=shipped:<name>``.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.policies import CARD_FILE, POLICY_FILE, SHIPPED_DIR
from kddrl_trl.run_folder import RunFolder, best_checkpoint, trained_run
from kddrl_trl.training import load_latest_training_checkpoint, load_training_checkpoint, save_policy


def ship(run: Path, name: str, checkpoint: str = "latest", why: str = "", dest: Path = SHIPPED_DIR) -> Path:
    """The shipped-policy folder of ``run`` (module docstring); returns it."""
    folder = RunFolder(trained_run(run))
    if not folder.is_finished():
        raise SystemExit(f"ship_policy: {run}: not a finished run (no summary.json)")
    if not name or "/" in name or name.startswith("."):
        raise SystemExit(f"ship_policy: {name!r} is not a folder name")
    if checkpoint == "latest":
        path, payload = load_latest_training_checkpoint(run)
    elif checkpoint == "best":
        path = best_checkpoint(run)
        payload = load_training_checkpoint(path)
    else:
        raise SystemExit(f"ship_policy: --checkpoint must be latest or best, got {checkpoint!r}")
    summary = folder.read_summary()
    out = Path(dest) / name
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(folder.config, out / "config.yaml")
    save_policy(out / POLICY_FILE, payload["learner"]["modules"])
    card = {
        "name": name,
        "run": str(run),
        "commit": summary.get("commit"),
        "algo": summary.get("algo"),
        "scenario": summary.get("scenario"),
        "seed": summary.get("seed"),
        "checkpoint": path.name,
        "episodes_trained": (summary.get("training") or {}).get("episodes"),
        "final_evaluation": {
            k: summary.get(k) for k in ("episodes", "mean_speed_kmh", "collision_rate", "shield_rate")
        },
        "chosen": why,
    }
    write_json_atomic(out / CARD_FILE, card)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished training run folder")
    parser.add_argument("name", help="the shipped policy's name (run=shipped:<name>)")
    parser.add_argument("--checkpoint", default="latest", help="latest (default) | best")
    parser.add_argument("--why", default="", help="how it was chosen, for its card")
    parser.add_argument("--dest", type=Path, default=SHIPPED_DIR, help="where the policies' folders are")
    args = parser.parse_args(argv)
    out = ship(args.run, args.name, args.checkpoint, args.why, args.dest)
    print(f"shipped {out} ({', '.join(sorted(p.name for p in out.iterdir()))}): python -m kddrl_trl.evaluate "
          f"run=shipped:{args.name}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
