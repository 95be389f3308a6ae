"""How the braking car of Scenario 2 behaves once it is released, against the paper's text (§IV.D): "remain
stationary for 3s, and then gradually resume its normal speed".

    python studies/braking/released_car.py [--release sumo|programmed] [--seeds 0 1 2 3 4] [--episodes 200]

IDM+MOBIL drives the ego (a policy that does not learn, so the traffic is the scenario's own) on the test traffic
of each seed (``eval_seed`` = seed + 1,000,000). For every braking event, from the frame the car is released
until 15 s later or until it leaves the simulation: its acceleration (the largest, and the mean over the first
3 s), the time it takes to reach 90 % of the speed it had before it braked, and each lane change it makes, with
where the ego was at that moment (its lane, and how far behind the car). A lane change *into the ego's lane* with
the ego at most 60 m behind it (or alongside, up to 5 m ahead) is a cut-in. Prints a table and writes the events as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import torch

from kddrl_trl import keys as K
from kddrl_trl.baselines.idm_mobil import IDMMobilPolicy
from kddrl_trl.envs import SumoHighwayEnv
from kddrl_trl.envs.observe import longitudinal
from kddrl_trl.eval.rollout import evaluate_policy
from kddrl_trl.highway_config import RELEASES
from kddrl_trl.protocol import test_seed

WINDOW_S = 15.0
CUT_IN_RANGE_M = 60.0


def _events(seed: int, episodes: int, roads: int, release: str) -> list[dict]:
    import libsumo as ls

    env = SumoHighwayEnv("braking", num_roads=roads, seed=0, braking={"release": release})
    sim, cfg = env.sim, env.config
    window = round(WINDOW_S / sim.dt)
    watching: dict[int, dict] = {}  # road -> the event followed since its release
    done: list[dict] = []

    def follow(_td) -> None:  # after every frame of every road
        for r, br in enumerate(sim.braking.state):
            vid, ev = br.get("vid"), watching.get(r)
            if ev is None and br["phase"] == K.BRAKE_RESUMED and vid is not None and not br.get("followed"):
                br["followed"] = True
                ev = watching[r] = dict(
                    seed=seed,
                    vid=vid,
                    ego=sim.ego[r],
                    v_before=br.get("v_before", math.nan),
                    speeds=[],
                    lanes=[],
                    lane_changes=[],
                )
            if ev is None:
                continue
            vid, ids = ev["vid"], ls.vehicle.getIDList()  # followed past its episode's end: it drives on
            if vid not in ids or len(ev["speeds"]) >= window:
                done.append(_summary(watching.pop(r), sim.dt))
                continue
            lane, ego = ls.vehicle.getLaneIndex(vid), ev["ego"] if ev["ego"] in ids else None
            if ev["lanes"] and lane != ev["lanes"][-1]:
                ego_lane = ls.vehicle.getLaneIndex(ego) if ego is not None else None
                behind = longitudinal(vid, cfg) - longitudinal(ego, cfg) if ego is not None else None
                ev["lane_changes"].append(
                    dict(
                        t=len(ev["speeds"]) * sim.dt,
                        from_lane=ev["lanes"][-1],
                        to_lane=lane,
                        ego_lane=ego_lane,
                        ego_behind_m=behind,
                        cut_in=bool(ego is not None and lane == ego_lane and -5 <= behind <= CUT_IN_RANGE_M),
                    )
                )
            ev["speeds"].append(ls.vehicle.getSpeed(vid))
            ev["lanes"].append(lane)

    evaluate_policy(env, IDMMobilPolicy(), episodes, test_seed(seed), progress=False, trace=follow)
    env.close()
    return done


def _summary(ev: dict, dt: float) -> dict:
    v = np.asarray(ev.pop("speeds"), dtype=float)
    ev.pop("lanes"), ev.pop("ego")
    a = np.diff(v) / dt if v.size > 1 else np.zeros(0)
    first3 = a[: round(3.0 / dt)]
    reach = np.flatnonzero(v >= 0.9 * ev["v_before"]) if np.isfinite(ev["v_before"]) else np.zeros(0, int)
    return dict(
        ev,
        frames=int(v.size),
        max_accel=float(a.max()) if a.size else math.nan,
        mean_accel_3s=float(first3.mean()) if first3.size else math.nan,
        t_to_90pct_s=float(reach[0] * dt) if reach.size else None,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--release", choices=RELEASES, default="sumo", help="braking.release (highway_config.py)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--episodes", type=int, default=200, help="episodes per seed")
    ap.add_argument("--roads", type=int, default=8)
    ap.add_argument("--out", type=Path, default=None, help="default: released_car_<release>.json beside this file")
    args = ap.parse_args()
    args.out = args.out or Path(__file__).with_name(f"released_car_{args.release}.json")
    torch.set_num_threads(1)
    events = [e for s in args.seeds for e in _events(s, args.episodes, args.roads, args.release)]
    full = [e for e in events if e["frames"] >= round(WINDOW_S / 0.1)]
    changes = [c for e in events for c in e["lane_changes"]]
    reached = [e["t_to_90pct_s"] for e in events if e["t_to_90pct_s"] is not None]
    q = lambda x, p: float(np.nanpercentile(x, p)) if len(x) else math.nan  # noqa: E731
    table = {
        "events": len(events),
        "followed the whole 15 s": len(full),
        "max acceleration, m/s² (median, p90)": (
            q([e["max_accel"] for e in events], 50),
            q([e["max_accel"] for e in events], 90),
        ),
        "mean acceleration over the first 3 s, m/s² (median)": q([e["mean_accel_3s"] for e in events], 50),
        "time to 90 % of its speed before braking, s (median, p90)": (q(reached, 50), q(reached, 90)),
        "share reaching 90 % within 15 s": len(reached) / max(len(events), 1),
        "events with a lane change of the released car within 15 s": sum(bool(e["lane_changes"]) for e in events),
        "lane changes (first within, s: median)": (len(changes), q([c["t"] for c in changes], 50)),
        "cut-ins (into the ego's lane, the ego 5 m ahead to 60 m behind)": sum(c["cut_in"] for c in changes),
    }
    for k, v in table.items():
        print(f"{k:62s} {v}")
    lines = ",\n".join(json.dumps(e, sort_keys=True) for e in events)  # one event a line: small, and diffs well
    head = json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "table": table}, indent=1)[:-2]
    args.out.write_text(f'{head},\n "events": [\n{lines}\n]}}\n')


if __name__ == "__main__":
    main()
