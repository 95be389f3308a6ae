"""Stable-Baselines3's PPO on the SUMO highway through the Gymnasium registration (the optional extra ``.[sb3]``).

``gym.make("kddrl_trl/SumoHighway-v0", flatten=True)`` is the form generic agents take: one ``float32`` observation
vector of what the driver senses, and the action ``Box(-1, 1, (2,))`` (lane command and acceleration, mapping in
``kddrl_trl.gym_env``). Two envs run side by side in one ``DummyVecEnv``: the second one's SUMO runs in a worker
process of its own, since libsumo allows one simulation per process.

    pip install -e ".[sb3]"
    python examples/sb3_ppo.py                          # 20,000 steps, then 10 greedy test episodes
    python examples/sb3_ppo.py --steps 200000 --scenario braking --out ppo.json

Prints (and with ``--out``, writes as JSON) the greedy policy's mean speed and collision rate on evaluation seeds that
training never saw. This is a client's view of the env, not one of the paper's systems: PPO gets the sum of the two
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
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20_000, help="PPO training steps (frames of 0.1 s)")
    parser.add_argument("--scenario", default="baseline", choices=["baseline", "congested", "braking"])
    parser.add_argument("--envs", type=int, default=2, help="envs in the DummyVecEnv")
    parser.add_argument("--n-steps", type=int, default=512, help="PPO rollout length per env")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", help="write the result here as JSON")
    args = parser.parse_args(argv)
    for name in ("steps", "envs", "n_steps", "eval_episodes"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")

    env = make_vec_env(
        ENV_ID, n_envs=args.envs, seed=args.seed, env_kwargs={"scenario": args.scenario, "flatten": True}
    )
    try:
        model = PPO("MlpPolicy", env, n_steps=args.n_steps, batch_size=64, seed=args.seed, device="cpu", verbose=0)
        model.learn(total_timesteps=args.steps, progress_bar=False)
    finally:
        env.close()
    result = {"args": vars(args), **evaluate(model, args.scenario, args.eval_episodes, args.seed)}
    print(json.dumps(result, indent=2))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=2)
    return result


if __name__ == "__main__":
    main()
