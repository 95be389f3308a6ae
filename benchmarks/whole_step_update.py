"""How far below the learner's update structure a TD3 update of KDDRL's shapes can go on a CPU, measured in one run.

The learner (:class:`kddrl_trl.training.HierarchicalLearner`) compiles its losses and runs the rest of an update
eagerly: ``backward``, the fused Adam steps and one ``torch._foreach_lerp_`` for the Polyak updates (Eq. 9-10).
Each of those is a separate call with its own Python and dispatch cost. This script times the TD3 update of the
paper (Eq. 6-10: the twin-critic step every update; the actor step and the Polyak updates every ``policy_delay``
updates) in plain PyTorch, structured two ways, on the same batches, from the same weights:

- ``split``: the learner's structure. The losses are ``torch.compile`` d; ``backward``, ``Adam(fused=True)`` and
  ``_foreach_lerp_`` run eagerly around them.
- ``whole_step``: one compiled graph per kind of step (the critic step; the critic step, the actor step and the
  Polyak updates). The gradients come from ``torch.func.grad_and_value`` and Adam is written out as ``_foreach``
  ops inside the graph, so a step is one call.

The networks have the shapes of ``conf/algo/kddrl.yaml`` (TD3 hidden layers, the car-following state with s_e)
and the batch is ``train.batch_size_cf`` of ``conf/config.yaml``. The shared embedding and its optimiser are left
out of both arms: this is the TD3 part of the update, not the learner's whole update. The target-smoothing noise
(Eq. 6) is drawn once per batch, outside both arms, so both compute the same update. ``equivalence`` says how
far apart the two arms' weights are after 1, 10 and 200 of the same updates from the same start: float rounding
(the graph orders the arithmetic its own way), which Adam's normalised steps then let drift apart. The floor is the
update's FLOPs (``torch.utils.flop_counter``) over the GEMM rate at its shapes (:func:`benchmarks.update_floor.gemm_rate`), as
``update_floor.py`` computes it for the learner.

(L) The same structure on the learner itself: the learner's critic step (the TD3 critics and the shared embedding,
Eq. 6-7 and 23-24, TorchRL's ``TD3Loss`` inside) as the learner runs it, against one compiled graph of it
(:func:`learner_whole_step`), taking turns on the same buffer-L samples of the fake env; with the largest difference
between that graph's gradients and ``backward`` 's on one batch. ``--skip-learner`` leaves it out.

    python -m benchmarks.whole_step_update [--updates 400] [--repeats 5] [--threads 2] [--skip-learner]

Prints a table and writes ``benchmarks/results/whole_step_update.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf
from torch.func import functional_call, grad_and_value
from torch.utils.flop_counter import FlopCounterMode

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.kddrl_parts import CONF, learner_kwargs, sample_batches
from benchmarks.update_floor import gemm_rate
from kddrl_trl.compiling import inductor_options
from kddrl_trl.modules import cf_obs_dim
from kddrl_trl.training import HierarchicalLearner

BOUND = 5.0  # m/s², the acceleration bound of the TD3 actor (TanhModule's low / high)


def shapes() -> dict:
    """Sizes and TD3 settings of ``conf/algo/kddrl.yaml`` and the TD3 minibatch of ``conf/config.yaml``."""
    learner = OmegaConf.to_container(OmegaConf.load(CONF), resolve=True)["learner"]
    td3 = learner["td3"]
    return {
        "state": cf_obs_dim(learner["embed_dim"]),
        "hidden": list(td3["hidden"]),
        "batch": int(OmegaConf.load(CONF.parents[1] / "config.yaml")["train"]["batch_size_cf"]),
        **{k: td3[k] for k in ("gamma", "tau", "actor_lr", "critic_lr", "policy_noise", "noise_clip", "policy_delay")},
    }


def init(cfg: dict, seed: int) -> dict:
    """Weights of the twin critics (stacked: ``[2, out, in]``, as TorchRL runs them batched), the actor and their
    targets."""
    g = torch.Generator().manual_seed(seed)
    sizes_c = [cfg["state"] + 1, *cfg["hidden"], 1]
    sizes_a = [cfg["state"], *cfg["hidden"], 1]

    def layers(sizes, lead):
        out = []
        for i, o in zip(sizes[:-1], sizes[1:], strict=True):
            out += [torch.randn(*lead, o, i, generator=g) / i**0.5, torch.zeros(*lead, *([1] if lead else []), o)]
        return out

    critic, actor = layers(sizes_c, (2,)), layers(sizes_a, ())
    return {
        "critic": critic,
        "actor": actor,
        "critic_t": [p.clone() for p in critic],
        "actor_t": [p.clone() for p in actor],
    }


def batches(cfg: dict, n: int, seed: int) -> list[tuple]:
    """``n`` TD3 minibatches (s, a, r, s', terminated, target-smoothing noise ε of Eq. 6, already clipped)."""
    g = torch.Generator().manual_seed(seed + 1)
    b, s = cfg["batch"], cfg["state"]
    out = []
    for _ in range(n):
        eps = (torch.randn(b, 1, generator=g) * cfg["policy_noise"]).clamp(-cfg["noise_clip"], cfg["noise_clip"])
        done = (torch.rand(b, 1, generator=g) < 0.01).float()
        out.append((torch.randn(b, s, generator=g), torch.randn(b, 1, generator=g), torch.randn(b, 1, generator=g),
                    torch.randn(b, s, generator=g), done, eps))  # fmt: skip
    return out


def critic(ps, s, a):
    """The twin critics Q_1, Q_2 of (s, a) as one batched MLP: ``[2, batch, 1]``."""
    x = torch.cat([s, a], -1).expand(2, -1, -1)
    for j in range(0, len(ps), 2):
        x = torch.baddbmm(ps[j + 1], x, ps[j].transpose(1, 2))
        x = torch.relu(x) if j < len(ps) - 2 else x
    return x


def actor(ps, s):
    """μ(s), bounded to ±``BOUND`` by a tanh."""
    x = s
    for j in range(0, len(ps), 2):
        x = torch.nn.functional.linear(x, ps[j], ps[j + 1])
        x = torch.relu(x) if j < len(ps) - 2 else x
    return BOUND * torch.tanh(x)


def make_losses(cfg: dict):
    """The critic loss (Eq. 6-7: clipped double-Q target with target smoothing) and the actor loss (Eq. 8)."""
    gamma = cfg["gamma"]

    def value_loss(cp, ctp, atp, s, a, r, s2, done, eps):
        with torch.no_grad():
            a2 = (actor(atp, s2) + eps).clamp(-BOUND, BOUND)
            y = r + gamma * (1 - done) * critic(ctp, s2, a2).min(0).values
        return ((critic(cp, s, a) - y) ** 2).mean(dim=(1, 2)).sum()

    def actor_loss(ap, cp, s):
        return -critic([p.detach() for p in cp], s, actor(ap, s))[0].mean()

    return value_loss, actor_loss


def split_arm(cfg: dict, w: dict):
    """The learner's structure: compiled losses; eager backward, fused Adam and ``_foreach_lerp_``."""
    value_loss, actor_loss = make_losses(cfg)
    cp = [p.clone().requires_grad_() for p in w["critic"]]
    ap = [p.clone().requires_grad_() for p in w["actor"]]
    ctp, atp = [p.clone() for p in w["critic_t"]], [p.clone() for p in w["actor_t"]]
    opt_c = torch.optim.Adam(cp, lr=cfg["critic_lr"], fused=True)
    opt_a = torch.optim.Adam(ap, lr=cfg["actor_lr"], fused=True)
    options = inductor_options("cpu")
    vl = torch.compile(value_loss, dynamic=False, options=options)
    al = torch.compile(actor_loss, dynamic=False, options=options)

    def step(k, b):
        s, a, r, s2, done, eps = b
        opt_c.zero_grad(set_to_none=True)
        vl(cp, ctp, atp, s, a, r, s2, done, eps).backward()
        opt_c.step()
        if (k + 1) % cfg["policy_delay"] == 0:
            opt_a.zero_grad(set_to_none=True)
            al(ap, cp, s).backward()
            opt_a.step()
            torch._foreach_lerp_(ctp + atp, cp + ap, cfg["tau"])

    return step, lambda: [p.detach() for p in cp + ap + ctp + atp]


def adam_(ps, grads, m, v, t, lr, b1=0.9, b2=0.999, eps=1e-8):
    """One Adam step (Kingma and Ba, torch.optim.Adam's defaults) in place, as ``_foreach`` ops a graph can hold."""
    t.add_(1)
    torch._foreach_lerp_(m, grads, 1 - b1)
    torch._foreach_mul_(v, b2)
    torch._foreach_addcmul_(v, grads, grads, 1 - b2)
    denom = torch._foreach_add(torch._foreach_div(torch._foreach_sqrt(v), (1 - b2**t).sqrt()), eps)
    torch._foreach_addcdiv_(ps, torch._foreach_div(m, (1 - b1**t) / -lr), denom)


def adam_state(params) -> tuple[list, list, torch.Tensor]:
    """Fresh state of :func:`adam_` for ``params``: the first and second moments (zeros) and the step count."""
    return [torch.zeros_like(p) for p in params], [torch.zeros_like(p) for p in params], torch.zeros(())


def whole_step_arm(cfg: dict, w: dict):
    """One compiled graph per kind of step: gradients by ``torch.func.grad_and_value``, Adam and Polyak inside."""
    value_loss, actor_loss = make_losses(cfg)
    cp, ap = [p.clone() for p in w["critic"]], [p.clone() for p in w["actor"]]
    ctp, atp = [p.clone() for p in w["critic_t"]], [p.clone() for p in w["actor_t"]]
    state_c, state_a = adam_state(cp), adam_state(ap)

    def critic_step(b):
        grads, loss = grad_and_value(value_loss)(cp, ctp, atp, *b)
        adam_(cp, grads, *state_c, lr=cfg["critic_lr"])
        return loss

    def full_step(b):
        loss = critic_step(b)
        grads, a_loss = grad_and_value(actor_loss)(ap, cp, b[0])
        adam_(ap, grads, *state_a, lr=cfg["actor_lr"])
        torch._foreach_lerp_(ctp + atp, cp + ap, cfg["tau"])
        return loss, a_loss

    options = inductor_options("cpu")
    critic_c = torch.compile(critic_step, dynamic=False, options=options)
    full_c = torch.compile(full_step, dynamic=False, options=options)

    def step(k, b):
        (full_c if (k + 1) % cfg["policy_delay"] == 0 else critic_c)(b)

    return step, lambda: cp + ap + ctp + atp


def flops_per_update(cfg: dict, w: dict, b: tuple) -> float:
    """FLOPs of one update: a critic step plus 1/``policy_delay`` of an actor step (forward and backward)."""
    value_loss, actor_loss = make_losses(cfg)
    cp = [p.clone().requires_grad_() for p in w["critic"]]
    ap = [p.clone().requires_grad_() for p in w["actor"]]
    with FlopCounterMode(display=False) as fc:
        value_loss(cp, w["critic_t"], w["actor_t"], *b).backward()
    critic_flops = fc.get_total_flops()
    with FlopCounterMode(display=False) as fc:
        actor_loss(ap, cp, b[0]).backward()
    return critic_flops + fc.get_total_flops() / cfg["policy_delay"]


def time_arms(arms: dict, data: list, updates: int, repeats: int) -> tuple[dict, dict]:
    """Seconds per call of each arm ``step(k, batch)`` over ``updates`` calls on ``data`` (cycled), the arms taking
    turns ``repeats`` times (a shared machine's drifts hit all alike): (per repeat, median over repeats)."""
    times = {n: [] for n in arms}
    for _ in range(repeats):
        for name, step in arms.items():
            t0 = time.perf_counter()
            for k in range(updates):
                step(k, data[k % len(data)])
            times[name].append((time.perf_counter() - t0) / updates)
    return times, {n: statistics.median(t) for n, t in times.items()}


class _CriticLoss(torch.nn.Module):
    """The learner's TD3 critic loss (Eq. 6-7, s_e inside) as a module call, what ``functional_call`` needs."""

    def __init__(self, learner: HierarchicalLearner):
        super().__init__()
        self.learner = learner

    def forward(self, batch):
        return self.learner.loss("cf_value", batch)[0]


def learner_whole_step(learner: HierarchicalLearner):
    """The learner's critic step (``update_functions()["cf_value"]``: the critics and the shared embedding, each
    with its own Adam) as one compiled graph: ``grad_and_value`` of the learner's own loss (TorchRL's ``TD3Loss``
    inside), with the critics' parameters handed to the loss as a plain TensorDict in place of its
    ``qvalue_network_params`` for the call, and the embedding's by ``functional_call``. Returns the compiled step,
    the uncompiled gradient function ``batch -> (critic gradients, embedding gradients, loss)`` (for the check
    against ``backward``) and the parameters it trains, in the order of those gradients."""
    loss_module, wrapper = learner.cf_loss, _CriticLoss(learner)
    critics = loss_module.qvalue_network_params
    keys = list(critics.keys(True, True))
    critic_live = [critics.get(k) for k in keys]
    named = dict(wrapper.named_parameters())
    names = [n for n in named if n.startswith("learner.embedding.") and named[n].requires_grad]
    embed_live = [named[n] for n in names]

    def value(critic_params, embed_params, batch):
        loss_module.__dict__["qvalue_network_params"] = critic_params
        try:
            return functional_call(wrapper, embed_params, (batch,), strict=False)
        finally:
            del loss_module.__dict__["qvalue_network_params"]

    def grads(batch):
        critic_params = critics.empty()
        for k, q in zip(keys, critic_live, strict=True):
            critic_params.set(k, q.detach())
        embed_params = {n: q.detach() for n, q in zip(names, embed_live, strict=True)}
        (gc, ge), loss = grad_and_value(value, argnums=(0, 1))(critic_params, embed_params, batch)
        return [gc.get(k) for k in keys], [ge[n] for n in names], loss

    state_c, state_e = adam_state(critic_live), adam_state(embed_live)

    def step(batch):
        gc, ge, loss = grads(batch)
        with torch.no_grad():
            adam_(critic_live, gc, *state_c, lr=learner.lr_critic)
            adam_(embed_live, ge, *state_e, lr=learner.opt_embed.param_groups[0]["lr"])
        return loss

    return torch.compile(step, dynamic=False, options=inductor_options("cpu")), grads, critic_live + embed_live


def measure_learner(seed: int, updates: int, repeats: int) -> dict:
    """(L) The learner's critic step as the learner runs it (compiled loss; eager backward, fused Adam) against
    :func:`learner_whole_step` on another learner of the same weights, on the same buffer-L samples of the fake
    env, taking turns; and the largest difference between the whole step's gradients and ``backward`` 's on one
    batch (same seed, so the same target-smoothing noise)."""
    torch.manual_seed(seed)
    ours = HierarchicalLearner(**learner_kwargs(True)[0])
    other = HierarchicalLearner(**learner_kwargs(False)[0])
    other.load_state_dict(ours.state_dict())
    rb_cf, _ = sample_batches(2000, seed, ours.buffer_keys())
    data = [rb_cf.sample() for _ in range(64)]
    step, grads, live = learner_whole_step(other)
    torch.manual_seed(seed)
    g_critic, g_embed, _ = grads(data[0])
    for q in other.parameters():
        q.grad = None
    torch.manual_seed(seed)
    other.loss("cf_value", data[0])[0].backward()
    gap = max(float((g - q.grad).abs().max()) for g, q in zip(g_critic + g_embed, live, strict=True))
    # the learner's update function itself (``_run`` would also write each batch's |δ| into it, a new key)
    update = ours.update_functions()["cf_value"]
    arms = {"learner": lambda k, b: update(b), "learner_whole_step": lambda k, b: step(b)}
    for fn in arms.values():
        for k, b in enumerate(data[:10]):
            fn(k, b)
    times, median = time_arms(arms, data, updates, repeats)
    return {
        "critic_step_s": median,
        "critic_step_s_per_repeat": times,
        "whole_step_over_learner": median["learner_whole_step"] / median["learner"],
        "gradient_max_abs_difference_vs_backward": gap,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--updates", type=int, default=400, help="updates timed per repeat and arm")
    p.add_argument("--repeats", type=int, default=5, help="turns of the two arms (medians over them)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--skip-learner", action="store_true", help="leave (L), the learner's own critic step, out")
    p.add_argument("--note", default="")
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "whole_step_update.json")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    cfg = shapes()
    w = init(cfg, args.seed)
    data = batches(cfg, 64, args.seed)
    arms = {"split": split_arm(cfg, w), "whole_step": whole_step_arm(cfg, w)}
    equivalence, done = {}, 0  # the same updates from the same start (the first ones compile)
    for upto in (1, 10, 200):
        for name, (step, _) in arms.items():
            for k in range(done, upto):
                step(k, data[k % len(data)])
        done = upto
        a, b = (arms[n][1]() for n in ("split", "whole_step"))
        equivalence[str(upto)] = max(float((x - y).abs().max()) for x, y in zip(a, b, strict=True))
    scale = max(float(x.abs().max()) for x in a)
    times, median = time_arms({n: step for n, (step, _) in arms.items()}, data, args.updates, args.repeats)
    flops = flops_per_update(cfg, w, data[0])
    floor = flops / gemm_rate(args.threads)
    result = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "machine": machine_info(),
        "shapes": cfg,
        "flops_per_update": flops,
        "floor_s": floor,
        "update_s": median,
        "update_s_per_repeat": times,
        "over_floor": {n: t / floor for n, t in median.items()},
        "whole_step_over_split": median["whole_step"] / median["split"],
        "equivalence": {"max_abs_weight_difference_after_updates": equivalence, "max_abs_weight": scale},
        "learner": None if args.skip_learner else measure_learner(args.seed, args.updates, args.repeats),
        **({"note": args.note} if args.note else {}),
    }
    print(f"\nTD3 update, {args.threads} threads, floor {floor * 1e3:.3f} ms ({flops / 1e6:.1f} MFLOP)")
    print(f"{'arm':<12}{'ms / update':>13}{'÷ floor':>9}{'÷ split':>9}")
    for n, t in median.items():
        print(f"{n:<12}{t * 1e3:>13.3f}{t / floor:>9.2f}{t / median['split']:>9.2f}")
    drift = ", ".join(f"{d:.1e} after {n}" for n, d in equivalence.items())
    print(f"max |weight difference| from the same start: {drift} updates (max |weight| {scale:.2f})")
    if result["learner"]:
        lr = result["learner"]
        print(f"\n(L) the learner's critic step (TD3 critics + shared embedding), {args.threads} threads")
        print(f"{'arm':<20}{'ms / step':>11}{'÷ learner':>11}")
        for n, t in lr["critic_step_s"].items():
            print(f"{n:<20}{t * 1e3:>11.3f}{t / lr['critic_step_s']['learner']:>11.2f}")
        print(f"gradients against backward: max |difference| {lr['gradient_max_abs_difference_vs_backward']:.1e}")
    write_json(args.out, result)
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
