"""Stable-Baselines3's PPO on the SUMO highway through the Gymnasium registration (the optional extra ``.[sb3]``).

``gym.make("kddrl_trl/SumoHighway-v0", flatten=True)`` is the form generic agents take: one ``float32`` observation
vector of what the driver senses, and the action ``Box(-1, 1, (2,))`` (lane command and acceleration, mapping in
``kddrl_trl.gym_env``). Two envs run side by side in one ``DummyVecEnv``: the second one's SUMO runs in a worker
process of its own, since libsumo allows one simulation per process.

    pip install -e ".[sb3]"
    python examples/sb3_ppo.py                          # 20,000 steps, then 10 greedy test episodes
    python examples/sb3_ppo.py --steps 200000 --scenario braking --out ppo.json
    python examples/sb3_ppo.py --load ppo_sumo.zip --steps 0   # evaluate a saved model again, no training

Trains with SB3's progress bar (tqdm and rich, where installed) and its logger (``--verbose 1``), saves the model
(``--save``, default ``ppo_sumo.zip``: SB3's own ``PPO.save``), loads it back with ``PPO.load`` and evaluates the loaded
model: what a user reuses is what was tested. Prints (and with ``--out``, writes as JSON) the greedy policy's mean
speed and collision rate on evaluation seeds that training never saw. This is a client's view of the env, not one of the paper's systems: PPO gets the sum of the two
agents' rewards (``reward="sum"``).
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

import kddrl_trl  # noqa: F401  (registers the id)
from kddrl_trl.gym_env import ENV_ID

EVAL_SEED = 1_000_000  # evaluation traffic: seeds far from the training ones


def _progress_bar_installed() -> bool:
    """SB3's progress bar needs tqdm and rich (``pip install "stable-baselines3[extra]"``)."""
    import importlib.util

    return all(importlib.util.find_spec(m) is not None for m in ("tqdm", "rich"))


def evaluate(model: PPO, scenario: str, episodes: int, seed: int) -> dict:
    """The greedy policy's metrics over ``episodes`` episodes of the evaluation traffic."""
    env = gym.make(ENV_ID, scenario=scenario, flatten=True)
    speeds, collisions = [], 0
    try:
        obs, _ = env.reset(seed=EVAL_SEED + seed)
        while len(speeds) < episodes:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                speeds.append(info["episode"]["mean_speed_kmh"])
                collisions += info["episode"]["collision"]
                obs, _ = env.reset()
    finally:
        env.close()
    return {"episodes": episodes, "mean_speed_kmh": sum(speeds) / episodes, "collision_rate": collisions / episodes}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=20_000, help="PPO training steps (frames of 0.1 s); 0 with --load")
    parser.add_argument("--scenario", default="baseline", choices=["baseline", "congested", "braking"])
    parser.add_argument("--envs", type=int, default=2, help="envs in the DummyVecEnv")
    parser.add_argument("--n-steps", type=int, default=512, help="PPO rollout length per env")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", help="write the result here as JSON")
    parser.add_argument("--save", default="ppo_sumo.zip", help="where the trained model is saved (PPO.save)")
    parser.add_argument("--load", help="a saved model (PPO.load) to start from instead of a new one")
    parser.add_argument("--verbose", type=int, default=0, choices=[0, 1], help="SB3's logger (1: its table)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    for name in ("envs", "n_steps", "eval_episodes"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.steps < (0 if args.load else 1):
        parser.error(f"--steps must be >= 1 (0 only with --load), got {args.steps}")

    env = make_vec_env(
        ENV_ID, n_envs=args.envs, seed=args.seed, env_kwargs={"scenario": args.scenario, "flatten": True}
    )
    try:
        if args.load:
            model = PPO.load(args.load, env=env, device="cpu")
        else:
            model = PPO("MlpPolicy", env, n_steps=args.n_steps, batch_size=64, seed=args.seed, device="cpu",
                        verbose=args.verbose)  # fmt: skip
        if args.steps:
            model.learn(total_timesteps=args.steps, progress_bar=not args.no_progress and _progress_bar_installed())
            model.save(args.save)
            print(f"model saved to {args.save}")
    finally:
        env.close()
    tested = PPO.load(args.save if args.steps else args.load, device="cpu")  # the saved model, loaded back
    result = {"args": vars(args), **evaluate(tested, args.scenario, args.eval_episodes, args.seed)}
    print(json.dumps(result, indent=2))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=2)
    return result


if __name__ == "__main__":
    main()
