"""How well the shipped trajGAN predicts the braking event's car (section 2 of studies/braking/README.md, offline).

    python studies/braking/predictions.py [--seeds 0 1 2 3 4] [--episodes 200] [--out studies/braking/predictions.json]

IDM+MOBIL drives the ego (a policy that does not learn, so the traffic is the scenario's own) on braking's test
traffic of each seed, through the KDDRL stack's first two transforms (``make_kddrl_transforms(priors=False)``: the
IDM prior TC, Eq. 11-12, and trajGAN's TG, Eq. 13, the shipped weights, one noise draw). At every frame in which the
event's car is one of the ego's leaders (slot a, b or c) and the event has begun, the script keeps each predictor's
position of that car 1 s and 2 s ahead (steps 10 and 20, the key steps of Eq. 24), then reads where the car really
was 10 and 20 frames later (SUMO), while the ego's episode lasts. Predictors:

* ``trajgan``: TG; ``idm_prior``: TC (IDM behind the car's own leader at constant speed);
* ``const_velocity``: the car's current position and speed (``LEADERS_HISTORY``);
* ``const_accel``: the same with the acceleration of its last frame, the speed never below zero.

Absolute errors (m) per event phase (while the car brakes, stands, or after it drives on), per seed, and their mean
over seeds with the 95 % t interval. Prints a table and writes the readings as JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from torchrl.envs import TransformedEnv

from kddrl_trl import keys as K
from kddrl_trl.baselines.idm_mobil import IDMMobilPolicy
from kddrl_trl.envs import SumoHighwayEnv
from kddrl_trl.envs.observe import longitudinal
from kddrl_trl.protocol import test_seed
from kddrl_trl.reporting.stats import mean_ci
from kddrl_trl.transforms import make_kddrl_transforms

STEPS = (10, 20)  # the key steps of Eq. 24 (1 s and 2 s at 0.1 s a frame)
PREDICTORS = ("trajgan", "idm_prior", "const_velocity", "const_accel")
PHASES = {K.BRAKE_BRAKING: "braking", K.BRAKE_STANDING: "standing", K.BRAKE_RESUMED: "resumed"}


def _kinematic(history: np.ndarray, dt: float, steps: tuple[int, ...]) -> tuple[list[float], list[float]]:
    """(constant velocity, constant acceleration) positions ``steps`` frames ahead from a leader's history
    ``[H, 2]`` (y, v; last row now), the acceleration from its last two speeds, the speed never below zero."""
    y, v = float(history[-1, 0]), float(history[-1, 1])
    a = (float(history[-1, 1]) - float(history[-2, 1])) / dt
    cv, ca = [], []
    for k in steps:
        t = k * dt
        cv.append(y + v * t)
        stop = -v / a if a < 0 else np.inf  # the car stops, then stays
        tt = min(t, stop)
        ca.append(y + v * tt + 0.5 * a * tt * tt)
    return cv, ca


def _seed_errors(seed: int, episodes: int, roads: int) -> list[dict]:
    """One record per (frame, key step) at which the event's car was a leader: its predictions and where it was."""
    import libsumo as ls

    base = SumoHighwayEnv("braking", num_roads=roads, seed=test_seed(seed))
    env = TransformedEnv(base, make_kddrl_transforms(priors=False, seed=seed))
    sim, dt, policy = base.sim, base.config.step_length, IDMMobilPolicy()
    pending: list[dict] = []  # predictions waiting for their frame
    done_records: list[dict] = []
    finished, frame = 0, 0
    td = env.reset()
    try:
        while finished < episodes:
            # predictions of this frame's observation (td): the event car's row among leaders a, b, c
            for r, br in enumerate(sim.braking.state):
                vid, phase = br.get("vid"), br["phase"]
                if vid is None or phase not in PHASES or sim.ego[r] is None:
                    continue
                slots = sim.observer.slots[r][:3]
                if vid not in slots:
                    continue
                i = slots.index(vid)
                traj, prior = td[K.PRED_TRAJ][r, i].numpy(), td[K.PRED_PRIOR_TRAJ][r, i].numpy()
                cv, ca = _kinematic(td[K.LEADERS_HISTORY][r, i].numpy(), dt, STEPS)
                for j, k in enumerate(STEPS):
                    pending.append(
                        dict(
                            road=r,
                            vid=vid,
                            ego=sim.ego[r],
                            due=frame + k,
                            step=k,
                            phase=PHASES[phase],
                            trajgan=float(traj[k - 1]),
                            idm_prior=float(prior[k - 1]),
                            const_velocity=cv[j],
                            const_accel=ca[j],
                        )
                    )
            full, td = env.step_and_maybe_reset(policy(td))
            frame += 1
            finished += int(full["next", "done"].sum())
            keep = []
            for p in pending:
                if sim.ego[p["road"]] != p["ego"]:  # the episode ended: its road was reset
                    continue
                if p["due"] > frame:
                    keep.append(p)
                    continue
                try:
                    truth = longitudinal(p["vid"], base.config)
                except ls.TraCIException:  # the car left the simulation
                    continue
                done_records.append({**p, "truth": truth})
            pending = keep
    finally:
        env.close()
    return done_records


def summarise(per_seed: dict[int, list[dict]]) -> dict:
    out: dict = {}
    for phase in ("all", *PHASES.values()):
        out[phase] = {}
        for k in STEPS:
            entry = {"n": 0}
            for name in PREDICTORS:
                values = []
                for records in per_seed.values():
                    sel = [r for r in records if r["step"] == k and (phase == "all" or r["phase"] == phase)]
                    if sel:
                        values.append(float(np.mean([abs(r[name] - r["truth"]) for r in sel])))
                entry[name] = (
                    {"per_seed": values, **mean_ci(values, within=(0.0, np.inf))}
                    if len(values) > 1
                    else {"per_seed": values}
                )
            entry["n"] = sum(
                1
                for records in per_seed.values()
                for r in records
                if r["step"] == k and (phase == "all" or r["phase"] == phase)
            )
            out[phase][f"step{k}"] = entry
    return out


def table(result: dict) -> str:
    lines = ["| phase, key step | n | " + " | ".join(PREDICTORS) + " |", "|---|---|" + "---|" * len(PREDICTORS)]
    for phase, by_step in result.items():
        for step, entry in by_step.items():
            cells = []
            for name in PREDICTORS:
                e = entry[name]
                if "mean" in e and e.get("ci_low") is not None:
                    cells.append(f"{e['mean']:.2f} [{e['ci_low']:.2f}, {e['ci_high']:.2f}]")
                else:
                    cells.append(" / ".join(f"{v:.2f}" for v in e["per_seed"]) or "n/a")
            lines.append(f"| {phase}, {step} | {entry['n']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--episodes", type=int, default=200, help="finished episodes per seed")
    parser.add_argument("--roads", type=int, default=8)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "predictions.json")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    per_seed = {seed: _seed_errors(seed, args.episodes, args.roads) for seed in args.seeds}
    result = {"args": vars(args) | {"out": str(args.out)}, "mae_m": summarise(per_seed)}
    print(table(result["mae_m"]))
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
