"""kddrl_trl's predictive-state transforms in a plain TorchRL TD3 loop (the style of TorchRL's sota-implementations).

Only TorchRL parts do the learning (TransformedEnv, CatTensors, TD3Loss, SoftUpdate, Collector, a replay buffer);
from kddrl_trl come the env writing the raw keys and ``make_kddrl_transforms()``. The agent controls the
acceleration; the lane is kept (a fixed lane policy), so one continuous agent is enough.

The reward is the paper's TD3 reward (Eq. 32) with the ``safe`` efficiency term (``HighwayConfig.reward``): no -1
per frame below 72 km/h. With the lane kept, the ego must follow whatever drives ahead, and under the paper's term
(``--reward paper``) following a leader slower than 72 km/h costs about as much as crashing into it
(``kddrl_trl/envs/rewards.py``), and HighwayEnv's traffic drives about 75-80 km/h. ``studies/reuse/README.md``
measures both rewards against HighwayEnv's IDM in its lane (``--reference``). The replay buffer (``--buffer``: 1M
frames, TorchRL's sota TD3) holds the whole of a default run (160-275k frames), and of each frame only the keys the
loss reads. The observation is divided by the fixed physical scales the package's own agents use (:data:`SCALES`;
``--no-obs-scale``: raw SI values): the raw one holds the ego's position along the road, hundreds of metres, and on
it this TD3 did not settle (``studies/reuse/README.md``).

    python examples/transforms_in_torchrl_td3.py                   # with the transforms (trajGAN key gaps, priors)
    python examples/transforms_in_torchrl_td3.py --no-transforms   # the control arm: raw observations only
    python examples/transforms_in_torchrl_td3.py --env highwayenv  # on HighwayEnv (the optional extra .[highway])

Trains for ``--episodes`` episodes, then prints (and with ``--out``, writes as JSON) the greedy policy's mean speed
and collision rate over ``--eval-episodes`` episodes on evaluation seeds that training never saw. Every
``--validate-every`` training episodes (100; 0: never) the greedy policy is validated on traffic of its own, and the
one of the highest mean return is kept and evaluated, the last one beside it (as the package's ``checkpoints/best.pt``).
"""

from __future__ import annotations

import argparse
import copy
import json
from functools import partial

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import Bounded, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import (
    CatTensors,
    ClipTransform,
    Compose,
    DTypeCastTransform,
    FlattenObservation,
    ObservationNorm,
    ParallelEnv,
    TransformedEnv,
)
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, AdditiveGaussianModule, TanhModule, ValueOperator
from torchrl.objectives import SoftUpdate, TD3Loss
from tqdm import tqdm

from kddrl_trl.modules.embedding import KEY_GAP_SCALE
from kddrl_trl.modules.state import StateScale
from kddrl_trl.transforms import make_kddrl_transforms

ACTION, LANE, REWARD = ("cf", "action"), ("lc", "action"), ("cf", "reward")
ACCEL_BOUND = 5.0  # m/s², the acceleration command's bound (the paper's Eq. 31)
RAW = [("ego", "state"), ("flat", "rel"), ("flat", "mask")]  # ego y, v_y, v_x; a..f relative states and presence
PREDICTIVE = [("flat", "key_gaps"), ("prior", "p_mobil"), ("prior", "p_lcgan")]  # what the transforms add
_S = StateScale()
#: SI units per unit of feature, per key (a pattern repeated over the key's features): the fixed scales of the
#: package's agent states (``kddrl_trl.modules.state``: positions 100 m, speeds 50 m/s, lateral 10 m and 5 m/s)
#: and key gaps (``KEY_GAP_SCALE``); flags and probabilities are left as they are
SCALES = {
    ("ego", "state"): _S.ego_units,  # y, v_y, v_x
    ("flat", "rel"): _S.rel_units,  # Δx, Δy, Δv_x, Δv_y per slot
    ("flat", "mask"): (1.0,),
    ("flat", "key_gaps"): (KEY_GAP_SCALE,),
    ("prior", "p_mobil"): (1.0,),
    ("prior", "p_lcgan"): (1.0,),
}


def make_env(name: str, roads: int, seed: int, transforms: bool, reward="safe", driver="agent", norm=None, scale=False):
    """The env (raw keys; ``reward``: the rewards' variant, ``HighwayConfig.reward``) -> the KDDRL stack (optional;
    its GANs trained on the traffic of the env's simulator) -> the features flattened and concatenated into
    ``"observation"`` -> standardised by ``norm`` = (loc, scale) (optional), or with ``scale`` divided by the fixed
    scales of :data:`SCALES` and clipped to ±``StateScale.clip``, as the package's agents read their states.
    ``driver="highwayenv_idm"``: HighwayEnv's IDM drives the ego in its lane (the reference)."""
    if name == "sumo":
        from kddrl_trl.envs import HighwayConfig, SumoHighwayEnv

        base = SumoHighwayEnv(HighwayConfig(reward=reward), num_roads=roads, seed=seed)
    else:
        from kddrl_trl.envs.highwayenv import HighwayEnvAdapter

        base = HighwayEnvAdapter(num_roads=roads, seed=seed, options={"ego_driver": driver}, reward=reward)
    flat = [
        FlattenObservation(
            -2, -1, in_keys=[("neighbors", "rel")], out_keys=[("flat", "rel")], allow_positive_dim=False
        ),
        DTypeCastTransform(torch.bool, torch.float32, in_keys=[("neighbors", "mask")], out_keys=[("flat", "mask")]),
    ]
    if transforms:
        flat.append(FlattenObservation(-2, -1, in_keys=[("pred", "key_gaps")], out_keys=[("flat", "key_gaps")]))
    keys = RAW + (PREDICTIVE if transforms else [])
    stack = [make_kddrl_transforms(seed=seed, weights=name)] if transforms else []
    tail = [ObservationNorm(*(t.clone() for t in norm), in_keys=["observation"], standard_normal=True)] if norm else []
    cat = CatTensors(keys, "observation", del_keys=False)
    env = TransformedEnv(base, Compose(*stack, *flat, cat, *tail))
    if scale:  # in the order CatTensors concatenates (its in_keys, sorted)
        units = [
            torch.tensor(SCALES[k]).repeat(env.observation_spec[k].shape[-1] // len(SCALES[k])) for k in cat.in_keys
        ]
        units = torch.cat(units)
        env.append_transform(ObservationNorm(torch.zeros_like(units), units, ["observation"], standard_normal=True))
        env.append_transform(ClipTransform(["observation"], low=-_S.clip, high=_S.clip))
    return env


def observation_statistics(env, frames: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(loc, scale) of ``"observation"`` over ``frames`` random steps of ``env`` (all roads together): its mean, and
    its standard deviation but at least 1 per feature, so that positions (up to hundreds of metres) and speeds come
    to unit scale while a feature that varies less (a presence flag, a probability) is only centred, never blown
    up. ``make_env(norm=...)`` standardises with them: training's statistics, in evaluation too."""
    steps = max(1, -(-frames // env.batch_size.numel()))
    obs = env.rollout(steps, break_when_any_done=False)["next", "observation"]
    obs = obs.reshape(-1, obs.shape[-1])
    return obs.mean(0), obs.std(0).clamp_min(1.0)


def keep_lane() -> TensorDictModule:
    """The fixed lane policy: the one-hot (left, keep, right) command of keeping the lane, every frame."""
    return TensorDictModule(
        lambda obs: torch.tensor([0.0, 1.0, 0.0]).expand(*obs.shape[:-1], 3), ["observation"], [LANE]
    )


def make_agent(obs_dim: int, hidden: int = 256):
    """TD3's actor (tanh-bounded to [-5, 5] m/s², as the paper's Eq. 31), twin critics, and the fixed lane policy."""
    spec = Bounded(-ACCEL_BOUND, ACCEL_BOUND, (1,))
    actor = TensorDictSequential(
        TensorDictModule(MLP(obs_dim, 1, num_cells=[hidden, hidden]), ["observation"], ["param"]),
        TanhModule(["param"], [ACTION], spec=spec),
    )
    keep = keep_lane()
    critic = ValueOperator(
        MLP(obs_dim + 1, 1, num_cells=[hidden, hidden]),
        in_keys=["observation", ACTION],
        out_keys=["state_action_value"],
    )
    return actor, keep, critic, spec


def evaluate(
    policy, env_name, roads, seed, transforms, episodes, driver="agent", reward="safe", isolated=False, **view
) -> dict:
    """Greedy episodes until ``episodes`` have ended: the mean over episodes of each episode's mean speed, the
    share of episodes that ended in a collision (as ``python -m kddrl_trl.train`` evaluates) and the mean episode
    return of the TD3 reward (Eq. 32, variant ``reward``), and the share of frames whose commanded acceleration
    lies at the bound (within 1 % of ±5 m/s²: a saturated tanh, whose gradient has vanished). ``view``:
    :func:`make_env`'s ``norm`` and ``scale`` as in training (``norm``: training's (loc, scale) of
    :func:`observation_statistics`, not new ones).
    ``isolated``: the env runs in a process of its own (TorchRL's ``ParallelEnv``), beside a training env that is
    still open (libsumo runs one simulation per process); the policy stays in this one."""
    make = partial(make_env, env_name, roads, seed, transforms, reward, driver=driver, **view)
    env = ParallelEnv(1, make, mp_start_method="spawn", metadata_from_workers=True) if isolated else make()
    speed_sum, frames, returns = torch.zeros(roads), torch.zeros(roads), torch.zeros(roads)
    speeds, ended_returns, collisions, at_bound, steps = [], [], 0, 0, 0
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset()
        while len(speeds) < episodes:
            td, root = env.step_and_maybe_reset(policy(td))
            at_bound += int((td[ACTION].abs() >= 0.99 * ACCEL_BOUND).sum())
            steps += roads
            speed_sum += td["next", "ego", "state"][..., 1].reshape(roads)
            returns += td["next", *REWARD].reshape(roads)
            frames += 1
            done = td["next", "done"].reshape(roads)
            speeds += (3.6 * speed_sum[done] / frames[done]).tolist()
            ended_returns += returns[done].tolist()
            collisions += int(td["next", "collision"].reshape(roads)[done].sum())
            speed_sum[done], frames[done], returns[done], td = 0.0, 0.0, 0.0, root
    env.close()
    return {
        "mean_speed_kmh": sum(speeds) / len(speeds),
        "collision_rate": collisions / len(speeds),
        "mean_return": sum(ended_returns) / len(ended_returns),
        "accel_at_bound": at_bound / steps,
        "episodes": len(speeds),
    }


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    p.add_argument("--env", choices=["sumo", "highwayenv"], default="sumo")
    p.add_argument("--no-transforms", dest="transforms", action="store_false")
    p.add_argument("--episodes", type=int, default=1000, help="training episodes (all roads together)")
    p.add_argument("--roads", type=int, default=8, help="egos simulated side by side (the env's batch)")
    p.add_argument("--warmup", type=int, default=2_000, help="frames collected before the first update")
    p.add_argument("--buffer", type=int, default=1_000_000, help="replay buffer capacity, frames (TorchRL's sota TD3)")
    p.add_argument("--eval-episodes", type=int, default=100)
    p.add_argument("--validate-every", type=int, default=100, help="training episodes between validations (0: none)")
    p.add_argument("--validate-episodes", type=int, default=24, help="greedy episodes per validation")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--reward", choices=["paper", "safe"], default="safe", help="the rewards' variant (HighwayConfig)")
    p.add_argument("--obs-norm", action="store_true", help="standardise the observation (observation_statistics)")
    p.add_argument("--norm-frames", type=int, default=2_000, help="random frames the normalisation is measured on")
    p.add_argument(
        "--obs-scale",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="divide the observation by fixed physical scales and clip it (SCALES), as the package's agents",
    )
    p.add_argument("--reference", action="store_true", help="no training: HighwayEnv's IDM drives, its lane kept")
    p.add_argument("--out", help="also write the result as JSON to this file")
    args = p.parse_args(argv)
    if args.reference and args.env != "highwayenv":
        p.error("--reference drives with HighwayEnv's IDM: it needs --env highwayenv")
    if args.obs_norm and args.obs_scale:
        p.error("--obs-norm standardises the observation instead of its fixed scales (--obs-scale): add --no-obs-scale")
    if args.buffer < args.warmup:
        p.error(f"--buffer {args.buffer} is below --warmup {args.warmup}: the buffer would never hold enough to update")
    torch.manual_seed(args.seed)
    if args.reference:
        return report(args, reference(args))

    norm = None
    if args.obs_norm:  # measured on traffic of a seed of their own, neither training's nor evaluation's
        stats_env = make_env(args.env, args.roads, args.seed + 2_000_000, args.transforms, args.reward)
        norm = observation_statistics(stats_env, args.norm_frames)
        stats_env.close()
    view = {"norm": norm, "scale": args.obs_scale}  # how the observation reaches the networks, the same everywhere
    env = make_env(args.env, args.roads, args.seed, args.transforms, args.reward, **view)
    actor, keep, critic, spec = make_agent(env.observation_spec["observation"].shape[-1])
    explore = TensorDictSequential(
        actor, AdditiveGaussianModule(spec, sigma_init=0.5, sigma_end=0.5, action_key=ACTION)
    )
    policy = TensorDictSequential(keep, explore)

    loss = TD3Loss(actor, critic, action_spec=spec, num_qvalue_nets=2, policy_noise=1.0, noise_clip=2.5)
    loss.set_keys(action=ACTION, reward=REWARD)
    loss.make_value_estimator(gamma=0.99)
    target = SoftUpdate(loss, tau=0.005)
    opt_actor = torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), lr=3e-4)
    opt_critic = torch.optim.Adam(loss.qvalue_network_params.flatten_keys().values(), lr=3e-4)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(args.buffer), batch_size=128)

    collector, episodes, frames = Collector(env, policy, frames_per_batch=20 * args.roads, total_frames=-1), 0, 0
    bar, crashes = tqdm(total=args.episodes, desc="training episodes", unit="ep"), []
    validations, best = [], None
    for batch in collector:
        buffer.extend(batch.reshape(-1).select(*loss.in_keys))  # what the loss reads, no more
        done = batch["next", "done"].reshape(-1)
        crashes += batch["next", "collision"].reshape(-1)[done].tolist()
        episodes, frames = episodes + int(done.sum()), frames + batch.numel()
        bar.update(min(int(done.sum()), args.episodes - bar.n))
        bar.set_postfix(collisions_last_50=f"{sum(crashes[-50:]) / max(len(crashes[-50:]), 1):.0%}", refresh=False)
        if args.validate_every and episodes // args.validate_every > len(validations):
            validations.append({"episode": episodes, "frames": frames, **validate(actor, keep, args, view)})
            bar.write(f"validation at episode {episodes}: {validations[-1]}")
            if best is None or validations[-1]["mean_return"] > best[0]["mean_return"]:
                best = validations[-1], copy.deepcopy(actor)
        if episodes >= args.episodes:
            break
        if len(buffer) < args.warmup:
            continue
        for step in range(batch.numel()):  # one update per collected frame, the actor every second one
            sample = buffer.sample()
            opt_critic.zero_grad()
            loss.value_loss(sample)[0].backward()
            opt_critic.step()
            if step % 2:
                opt_actor.zero_grad()
                loss.actor_loss(sample)[0].backward()
                opt_actor.step()
                target.step()
        collector.update_policy_weights_()
    bar.close()
    collector.shutdown()
    env.close()

    tested = (args.env, args.roads, args.seed + 1_000_000, args.transforms)  # evaluation traffic training never saw
    last = evaluate(TensorDictSequential(keep, actor), *tested, args.eval_episodes, reward=args.reward, **view)
    result = {**last, "train_episodes": episodes, "train_frames": frames}  # episodes: evaluated
    if best is not None:  # the kept policy is the result; the last one is reported beside it
        kept = (
            last
            if best[0]["episode"] == episodes
            else evaluate(TensorDictSequential(keep, best[1]), *tested, args.eval_episodes, reward=args.reward, **view)
        )
        result = {**result, **kept, "kept_episode": best[0]["episode"], "last": last, "validations": validations}
    return report(args, result)


def validate(actor, keep, args, view: dict) -> dict:
    """The greedy policy of ``actor`` as it is now, ``args.validate_episodes`` episodes on validation traffic
    (seed + 500,000: neither training's nor the evaluation's, as ``kddrl_trl.protocol``), in an env of its
    own process beside the training env. The kept policy is the one of the highest mean return, the reward it is
    trained on (as the package's ``train.best_metric``)."""
    seed = args.seed + 500_000
    greedy = TensorDictSequential(keep, actor)
    return evaluate(
        greedy,
        args.env,
        args.roads,
        seed,
        args.transforms,
        args.validate_episodes,
        reward=args.reward,
        isolated=True,
        **view,
    )


def reference(args) -> dict:
    """HighwayEnv's IDM driving the ego with its lane kept, on the evaluation traffic of ``args.seed`` (the commands
    of the policy given are ignored): what the example's agent, which only accelerates, is measured against."""
    zero = TensorDictModule(lambda obs: torch.zeros(*obs.shape[:-1], 1), ["observation"], [ACTION])
    policy = TensorDictSequential(keep_lane(), zero)  # its observation unread: the raw keys (no transforms) do
    return evaluate(policy, args.env, args.roads, args.seed + 1_000_000, False, args.eval_episodes, "highwayenv_idm")


def report(args, result: dict) -> dict:
    """Prints ``result`` with the arm's name, and writes it with the arguments to ``args.out`` (JSON)."""
    result = {**result, "args": vars(args)}
    if args.reference:
        arm = "HighwayEnv's IDM, lane kept (reference)"
    else:
        arm = "with the KDDRL transforms" if args.transforms else "raw observations only"
    print(f"{args.env}, {arm}, seed {args.seed}: {result}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    main()
