"""How one shared embedding (paper Eq. 23-24, Fig. 5) is trained by the two agents' TorchRL losses.

Decision: which losses train the embedding
------------------------------------------
One instance of the embedding path (:func:`~kddrl_trl.modules.make_shared_embedding`: Eq. 23 fusion +
Eq. 24 shared embedding) feeds both agents. It is trained by **both critics' value losses and nothing
else**:

============================================  ==========================  ================================
loss                                          updates the embedding?      how
============================================  ==========================  ================================
D3QN TD loss (``DQNLoss``, double, buffer H)  yes                         ``s_e`` enters ``("lc","obs")``
TD3 critic loss (``TD3Loss.value_loss``, L)   yes                         ``s_e`` enters ``("cf","obs")``
TD3 actor loss (``TD3Loss.actor_loss``)       **no**                      call it on ``detach_embedding(batch)``
bootstrap targets (next states, both agents)  **no**                      next ``s_e`` from a frozen target copy
============================================  ==========================  ================================

Why:

1. *Shared means trained by both.* The paper builds s_e as the common "predictive-knowledge state basis"
   that keeps lateral and longitudinal control "mutually informed" (§I, §III.G.3). If only one agent
   trained it, the other would read a representation specialised to someone else's reward. The two value
   losses are the only losses grounded in the environment's rewards (Eq. 26-29 for D3QN, Eq. 32-33 for
   TD3): each tells the embedding which parts of P_lc and y_lv^pre matter for its own return.
2. *Not the actor loss.* ``-Q(s, mu(s))`` differentiated through s_e would move the *state
   representation* to raise the critic's estimate instead of describing the traffic better — a direction
   the critic never validated (TD3's actor loss already detaches the critic's parameters, but not its
   input). Updating a shared encoder only from the critic, with the actor reading detached features, is
   the established recipe for actor-critic with a shared encoder (SAC-AE, Yarats et al. 2019; DrQ, 2021),
   and it also keeps the TD3 actor's delayed update from touching what D3QN relies on.
   (TorchRL's own ``separate_losses=True`` option of ``TD3Loss``/``SACLoss`` does the opposite — shared
   parameters trained by the policy loss only — and only applies to parameters *inside* the networks the
   loss owns, which the embedding is not; see below.)
3. *Semi-gradient targets.* Bootstrap targets must not be differentiated (standard TD). Next-state s_e is
   computed without gradient by a frozen copy of the embedding (:func:`make_target_embedding`, soft-updated
   with :func:`soft_update_embedding_`), mirroring the target Q networks the losses keep themselves; with
   ``target_embedding=None`` the online embedding is used under ``torch.no_grad()``.

Clocks: D3QN updates every ``lc_period`` frames (20) and TD3's critic every frame, so the embedding sees
about 20 TD3-critic updates per D3QN update. That is the paper's schedule (Algorithm 1 lines 27-28, 38-39);
a learning loop wanting a balance can weight the D3QN loss, nothing here assumes a weight.

Why the embedding lives outside the TorchRL losses
--------------------------------------------------
``LossModule.convert_to_functional`` isolates the parameters of every network given to a loss:
``DQNLoss`` keeps the online parameters and clones a target copy; ``TD3Loss`` *expands* the critic to
``num_qvalue_nets`` copies and, for parameters not found in ``compare_against``, **re-samples** them into
new ``nn.Parameter`` s (``torchrl/objectives/common.py``). An embedding placed inside the TD3 critic would
thus become two fresh, independent embeddings, and one inside the D3QN network a third: one instance could
not be shared. So the losses only get *heads* on ``keys.LC_OBS`` / ``keys.CF_OBS``, and the learning loop
computes those states on each sampled batch with :func:`build_agent_states` before calling a loss. The
losses shallow-clone their input (``tensordict.clone(False)``) and keep its autograd graph, so the value
losses' gradients reach the embedding through the state tensors (tests/modules/test_modules.py proves the routing
with real ``DQNLoss`` and ``TD3Loss``).

What the learning loop must do
------------------------------
- Replay buffers store raw and transform keys (``pred``, ``prior`` ...), never ``s_e`` or the agent states:
  the embedding changes as it trains, so they are recomputed at update time by :func:`build_agent_states`.
- Optimiser: :func:`embedding_parameters` go into **one** optimiser of their own (or one param group),
  zeroed and stepped around every backward of either value loss. Do not add them to both agents'
  optimisers (two Adam states would step the same tensor twice per update).
- TD3: ``loss_td3.value_loss(states)`` for the critic; ``loss_td3.actor_loss(detach_embedding(states))``
  for the (delayed) actor. Do not use ``TD3Loss.forward`` (it sums both on the same batch). Call
  :func:`soft_update_embedding_` on the target embedding when the TorchRL ``SoftUpdate`` s run.
- Acting: ``TensorDictSequential(embedding, lc_state(), q_actor)`` and
  ``TensorDictSequential(embedding, cf_state(), actor)`` under ``torch.no_grad()``.
"""

from __future__ import annotations

import copy

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn

from .. import keys as K

#: Keys computed from the embedding's parameters: detached by :func:`detach_embedding` (at the root and
#: under ``"next"``).
EMBEDDING_KEYS: tuple[NestedKey, ...] = (K.PRIOR_P_LC, K.EMBED_S_E, K.LC_OBS, K.CF_OBS)


def detach_embedding(td: TensorDictBase, keys: tuple[NestedKey, ...] = EMBEDDING_KEYS) -> TensorDictBase:
    """Shallow copy of ``td`` where every entry derived from the embedding is detached.

    Use it for the TD3 actor loss (``loss_td3.actor_loss(detach_embedding(states))``) so that the
    deterministic policy gradient (paper Eq. 8) does not reach the shared embedding (Eq. 23-24).
    ``td`` itself is left untouched.
    """
    out = td.clone(False)
    for prefix in ((), ("next",)):
        if prefix and out.get("next", None) is None:
            continue
        for key in keys:
            full = prefix + (key if isinstance(key, tuple) else (key,))
            value = out.get(full, None)
            if value is not None:
                out.set(full, value.detach())
    return out


def embedding_parameters(module: nn.Module | None) -> list[nn.Parameter]:
    """Trainable parameters of the embedding path (Eq. 23 fusion + Eq. 24 embedding), without duplicates;
    ``[]`` for ``None`` (no embedding). Put them in one optimiser of their own (see module docstring)."""
    if module is None:
        return []
    seen, out = set(), []
    for p in module.parameters():
        if p.requires_grad and id(p) not in seen:
            seen.add(id(p))
            out.append(p)
    return out


def make_target_embedding(embedding: nn.Module | None) -> nn.Module | None:
    """Frozen copy of the embedding (Eq. 23-24) that computes next-state ``s_e`` for bootstrap targets."""
    if embedding is None:
        return None
    target = copy.deepcopy(embedding)
    target.requires_grad_(False)
    return target


@torch.no_grad()
def soft_update_embedding_(target: nn.Module | None, source: nn.Module | None, tau: float) -> None:
    """Polyak update ``target <- (1 - tau) target + tau source`` of a target embedding, in place."""
    if target is None or source is None:
        return
    pairs = list(zip(target.parameters(), source.parameters(), strict=True))
    torch._foreach_lerp_([t for t, _ in pairs], [s for _, s in pairs], tau)
    for t, s in zip(target.buffers(), source.buffers(), strict=True):
        t.copy_(s)


def build_agent_states(
    td: TensorDictBase,
    embedding: TensorDictModuleBase | None,
    *builders: TensorDictModuleBase,
    target_embedding: TensorDictModuleBase | None = None,
    next_lc_policy: TensorDictModuleBase | None = None,
) -> TensorDictBase:
    """Computes ``s_e`` and the agent states (Eq. 24, Eq. 30) on a sampled batch, root and ``"next"``.

    At the root the online ``embedding`` runs with gradients (the value losses train it); under ``"next"``
    the ``target_embedding`` (or, if ``None``, the online one) runs under ``torch.no_grad()`` — bootstrap
    targets are never differentiated. ``builders`` are :func:`lc_state` / :func:`cf_state` modules.

    The lane-change action of the next state (Eq. 30's a_D3QN^{t+1}, when a builder needs ``keys.LC_ACTION``):
    TorchRL stores actions at the root only. Between decisions the action is held (§III.G.2), so the next
    state's is the root one. On a transition whose next frame is a decision frame (``("next", "lc", "decide")``),
    the action in force at t+1 is the *new* decision: ``next_lc_policy`` (the D3QN's greedy policy on the next
    state, masked by its ``("lc", "action_mask")``) gives it there, as the target actor gives TD3's own next
    action (Eq. 6). Without ``next_lc_policy`` the root action is copied on every row (wrong on the frame before
    each decision: the paper's Algorithm 1 read literally). A collector that writes ``("next", "lc", "action")``
    itself wins. With n-step returns (``train.n_steps``) the next state lies k frames ahead: the held action is then the
    batch's ``("next", "lc", "held")`` (the action in force at the window's last frame) instead of the root one.

    Returns a shallow copy of ``td``; ``td`` (e.g. a replay-buffer sample) is not modified.
    """
    out = td.clone(False)
    if embedding is not None:
        embedding(out)
    for b in builders:
        b(out)
    nxt = out.get("next", None)
    if nxt is not None:
        held = None
        if any(K.LC_ACTION in b.in_keys for b in builders) and nxt.get(K.LC_ACTION, None) is None:
            held = nxt.get(K.LC_HELD, None)  # n-step returns keep the action in force at the window's end
            held = (held if held is not None else out.get(K.LC_ACTION)).detach()
            nxt.set(K.LC_ACTION, held)
        with torch.no_grad():
            emb = target_embedding if target_embedding is not None else embedding
            if emb is not None:
                emb(nxt)
            if held is not None and next_lc_policy is not None:
                decide = nxt.get(K.LC_DECIDE, None)
                if decide is None:
                    raise KeyError(
                        f"build_agent_states: the batch has no ('next', {K.LC_DECIDE!r}) (the "
                        "DecisionClock's flag): the next lane-change action cannot be told from the held one"
                    )
                chosen = next_lc_policy(nxt.clone(False)).get(K.LC_ACTION).to(held.dtype)
                nxt.set(K.LC_ACTION, torch.where(decide.reshape(*held.shape[:-1], 1).bool(), chosen, held))
            for b in builders:
                b(nxt)
    return out
