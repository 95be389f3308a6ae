"""Brings the saved ``config.yaml`` of runs made by earlier versions up to the current schema, in place.

A run saves its resolved config; the schema (:mod:`kddrl_trl.conf.schema`) has since gained keys and lost the
per-algo compile options. Reading an old run therefore needs its config migrated once: every key the schema added
is written with the value that reproduces what the run computed (the default the key was introduced with), and the
keys the schema dropped are removed. A config that is current is left byte-for-byte as it is.

    python -m kddrl_trl.devtools.migrate_configs PATH [PATH ...]   # run folders, or folders holding them
    python -m kddrl_trl.devtools.migrate_configs --check PATH ...   # exit status 1 if any would change
"""

from __future__ import annotations

import argparse
from pathlib import Path

from omegaconf import OmegaConf

from ..run_folder import RunFolder

#: keys added to the schema after runs were saved without them, with the value an older run computed with:
#: (node, key, value), ``node`` a dotted path from the root of a run's config; a node a run lacks is left alone
ADDED = (
    ("train", "n_steps", 1),
    ("train", "prioritized", False),
    ("train", "priority_alpha", 0.6),
    ("train", "priority_beta", 0.4),
    ("algo.transforms", "mobil_criteria", False),
    ("algo.transforms", "weights", "auto"),
    ("algo.transforms", "event_oracle", False),
    ("algo.learner.d3qn", "semi_mdp", False),
    ("algo.learner", "cf_agent", "td3"),
    ("algo.learner", "mobil_criteria", False),
)
#: Not migrated: ``algo.learner.td3.exploration_clip`` (and DDPG's). The reproduction study's KDDRL runs predate the
#: clipped acting noise; written as ``null`` (what they ran), their report would call them "not in the paper" and
#: lose its comparison with the paper, which that study exists for (its README says which fixes they predate). The
#: schema reads a missing clip as ``null`` (:data:`kddrl_trl.conf.schema.TD3Config`).

#: keys the schema dropped (the per-algo compile options, replaced by the top-level ``compile``): they never changed
#: what a run learned
DROPPED = (("algo.transforms", "compile"), ("algo.transforms", "aot"), ("algo.learner", "compile"))


def _node(config: dict, dotted: str):
    node = config
    for part in dotted.split("."):
        node = node.get(part) if isinstance(node, dict) else None
    return node if isinstance(node, dict) else None


def migrate(config: dict) -> list[str]:
    """Migrates ``config`` (a run's resolved config as a dict) in place; returns what changed, as dotted keys."""
    changed = []
    hierarchical = (_node(config, "algo") or {}).get("kind") == "hierarchical"
    for parent, key, value in ADDED:
        node = _node(config, parent)
        if node is None or key in node:
            continue
        if parent == "algo.learner" and not hierarchical:  # the hierarchical learner's keys only
            continue
        node[key] = value
        changed.append(f"+{parent}.{key}")
    for parent, key in DROPPED:
        node = _node(config, parent)
        if node is not None and key in node:
            del node[key]
            changed.append(f"-{parent}.{key}")
    return changed


def migrate_file(path: Path, write: bool = True) -> list[str]:
    """Migrates the config file ``path``; writes it back only where something changed."""
    config = OmegaConf.to_container(OmegaConf.load(path))
    changed = migrate(config)
    if changed and write:
        path.write_text(OmegaConf.to_yaml(config))
    return changed


def run_configs(paths) -> list[Path]:
    """The ``config.yaml`` of every run folder at or under ``paths`` (not Hydra's own copies in ``.hydra/``)."""
    found = []
    for p in map(Path, paths):
        if not p.exists():
            raise SystemExit(f"migrate_configs: {p}: no such folder")
        found += [p / RunFolder.CONFIG] if (p / RunFolder.CONFIG).is_file() else []
        found += [c for c in sorted(p.rglob(RunFolder.CONFIG)) if c.parent.name != ".hydra" and c.parent != p]
    return found


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m kddrl_trl.devtools.migrate_configs", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--check", action="store_true", help="change nothing; exit status 1 if a config would change")
    args = ap.parse_args(argv)
    stale = 0
    for path in run_configs(args.paths):
        changed = migrate_file(path, write=not args.check)
        if changed:
            stale += 1
            print(f"{path}: {' '.join(changed)}")
    print(f"migrate_configs: {stale} config(s) {'to migrate' if args.check else 'migrated'}")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    raise SystemExit(main())
