"""The example's training curves (studies/reuse/README.md): the share of collisions over the last 50 training
episodes (exploration on), as the example's progress bar printed it, every ``--every`` episodes, per arm and seed.

    python studies/reuse/curves.py [studies/reuse/runs] [--out studies/reuse]

Reads the logs ``<folder>/<arm>__<seed>.log`` that ``study.sh`` writes beside each finished result
``<arm>__<seed>.json`` (or ``.log.xz``, as ``collect.sh`` copies them), for the folders of ``report.EXAMPLE_ARMS``,
and writes ``curves.json`` and ``curves.md``.
A log without its result (a run not finished) is named and left out; a finished run's log without a progress line
is an error. The bar prints the collisions of the last 50 episodes with its episode count; the value at episode E
is the last one printed at the first count >= E, which may lag by one collector batch (20 frames per road).
"""

from __future__ import annotations

import argparse
import importlib.util
import lzma
import re
import sys
from pathlib import Path

import numpy as np

from kddrl_trl.atomic_files import write_json_atomic, write_text_atomic

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("reuse_report", HERE / "report.py")  # the arms, named once
_report = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_report)
ARMS, EXAMPLE_ARMS = _report.ARMS, _report.EXAMPLE_ARMS
#: one progress line of the example's bar: "<count>/<total> [<times>, collisions_last_50=<p>%]"
PROGRESS = re.compile(r"(\d+)/(\d+) \[[^\]]*collisions_last_50=(\d+)%\]")


def read_curve(log: Path, every: int) -> dict[int, float]:
    """episode -> % of collisions over the last 50 training episodes, at every ``every`` episodes up to the total."""
    text = lzma.open(log, "rt", errors="replace").read() if log.suffix == ".xz" else log.read_text(errors="replace")
    lines = [(int(n), int(total), float(p)) for n, total, p in PROGRESS.findall(text)]
    if not lines:
        raise ValueError(f"{log}: no progress line ('<count>/<total> [..., collisions_last_50=<p>%]')")
    total = lines[-1][1]
    curve = {}
    for episode in range(every, total + 1, every):
        counts = [n for n, _, _ in lines if n >= episode]
        if not counts:
            raise ValueError(f"{log}: the bar never reached episode {episode} of {total}")
        first = min(counts)
        curve[episode] = [p for n, _, p in lines if n == first][-1]
    return curve


def read_curves(src: Path, every: int) -> dict[str, dict[int, dict[int, float]]]:
    """arm -> seed -> curve, for every finished learning run of the example under ``src``."""
    out: dict[str, dict[int, dict[int, float]]] = {}
    for folder, (with_, without, _) in EXAMPLE_ARMS.items():
        for name, arm in (("transforms", with_), ("no-transforms", without)):
            logs = sorted((src / folder).glob(f"{name}__*.log")) + sorted((src / folder).glob(f"{name}__*.log.xz"))
            for log in logs:
                stem = log.name.split(".")[0]  # <arm>__<seed>
                if not (log.parent / f"{stem}.json").exists():
                    print(f"{log}: no result beside it (a run not finished): left out", file=sys.stderr)
                    continue
                seed = int(stem.split("__")[1])
                if seed in out.get(arm, {}):
                    raise ValueError(f"{log}: a second log of {folder}/{stem}")
                out.setdefault(arm, {})[seed] = read_curve(log, every)
    return out


def markdown(curves: dict[str, dict[int, dict[int, float]]], every: int) -> str:
    lines = [
        "# The example's training curves",
        "",
        "Made by `python studies/reuse/curves.py` from the example's logs (`study.sh`): collisions over the last 50"
        f" training episodes (exploration on, %), every {every} episodes (at most ten columns an arm), per seed, and"
        " their mean over seeds.",
    ]
    for arm in sorted(curves):
        by_seed = curves[arm]
        episodes = sorted(next(iter(by_seed.values())))
        stride = -(-len(episodes) // 10)  # at most 10 columns; curves.json has every point
        episodes = episodes[stride - 1 :: stride]
        lines += ["", f"({arm}) {ARMS[arm]}", "", "| seed | " + " | ".join(map(str, episodes)) + " |"]
        lines.append("|---" * (len(episodes) + 1) + "|")
        for seed in sorted(by_seed):
            lines.append(
                f"| {seed} | " + " | ".join(f"{by_seed[seed].get(e, float('nan')):.0f}" for e in episodes) + " |"
            )
        means = [np.mean([c[e] for c in by_seed.values() if e in c]) for e in episodes]
        lines.append("| mean | " + " | ".join(f"{m:.1f}" for m in means) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "src", nargs="?", default=str(HERE / "runs"), help="the runs (collect.sh's copy, or study.sh's OUT_DIR)"
    )
    p.add_argument("--out", default=str(HERE))
    p.add_argument("--every", type=int, default=50, help="episodes between two points of a curve")
    args = p.parse_args(argv)
    curves = read_curves(Path(args.src), args.every)
    out = Path(args.out)
    write_json_atomic(out / "curves.json", {arm: {str(s): c for s, c in by.items()} for arm, by in curves.items()})
    text = markdown(curves, args.every)
    write_text_atomic(out / "curves.md", text)
    print(text)
    return curves


if __name__ == "__main__":
    main()
