"""``make_kddrl_transforms``: the predictive-state stack of KDDRL and its ablations (Algorithm 1 lines 15-20)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch

from ..generative import default_checkpoint
from ..physics import IDMParams, MOBILParams
from .event_oracle import EventOracleKeyGaps
from .idm_prior import IDMPrior, as_idm_params
from .key_gaps import KeyGapsFromPrior
from .lcgan import LCGANPrior
from .leader_history import LeaderHistory
from .mobil_prior import MOBILPrior, as_mobil_params
from .stack import PredictiveStack
from .trajgan import TrajGANPrediction

REDUCTIONS = ("sample", "mean")


def make_kddrl_transforms(
    trajgan: bool = True,
    priors: bool = True,
    *,
    trajgan_checkpoint: str | Path | None = None,
    lcgan_checkpoint: str | Path | None = None,
    weights: str = "sumo",
    num_samples: int = 1,
    reduce: str = "sample",
    seed: int = 0,
    idm: IDMParams | Mapping | None = None,
    mobil: MOBILParams | Mapping | None = None,
    num_lanes: int = 3,
    device: str | torch.device = "cpu",
    compile: bool = False,
    event_oracle: bool = False,
) -> PredictiveStack:
    """The KDDRL predictive-state transforms, in the order of Algorithm 1 (paper §III.B-C).

    ============================  ===========================================================================
    ``trajgan=True, priors=True``  ``IDMPrior -> TrajGANPrediction -> MOBILPrior -> LCGANPrior`` (KDDRL)
    ``trajgan=False, priors=True`` ``IDMPrior -> KeyGapsFromPrior -> MOBILPrior -> LCGANPrior`` ("without
                                   TG": key gaps from the IDM prior; the paper's D3QN+TD3+LG row)
    ``trajgan=True, priors=False`` ``IDMPrior -> TrajGANPrediction`` ("without LG": no prior keys)
    ``trajgan=False, priors=False`` ``IDMPrior -> KeyGapsFromPrior``
    ============================  ===========================================================================

    With trajGAN, the stack also carries a :class:`LeaderHistory` (:attr:`PredictiveStack.history`, not a member):
    on an env that does not write ``("leaders", "history")`` it keeps that window itself (and declares it in the
    specs); on one that does, it does nothing.

    Keys written: ``("pred", "prior_traj")`` always, ``("pred", "traj")`` with trajGAN, ``("pred", "key_gaps")``
    always, ``("prior", "p_mobil")`` and ``("prior", "p_lcgan")`` with priors. Algorithm 1 evaluates lcGAN
    (line 18) before MOBIL (lines 19-20); the two are independent, so the order here (MOBIL first) changes
    nothing. The stack only reads the raw keys of ``kddrl_trl.keys``: it works on any TorchRL env writing them.
    Attach it *outside* a batched env (``TransformedEnv(ParallelEnv(...), stack)``) so that the generators run
    once for all environments and draw one noise stream; inside the workers it also works, but every worker
    then holds a copy of the generator with the same seed.

    Args:
        trajgan: use trajGAN (``False``: key gaps from the IDM prior, see :class:`KeyGapsFromPrior`).
        priors: add the MOBIL and lcGAN lane-change priors.
        trajgan_checkpoint, lcgan_checkpoint: checkpoint paths (default: the weights shipped with the package for
            the traffic ``weights``).
        weights: the traffic the shipped weights used without a checkpoint path were trained on: ``"sumo"`` (our
            SUMO highway) or ``"highwayenv"`` (HighwayEnv's own traffic);
            :data:`kddrl_trl.generative.SHIPPED_TRAFFIC`.
        num_samples, reduce: ``reduce="sample"``: one noise draw; ``"mean"``: mean of ``num_samples`` draws —
            for trajGAN and, as averaged draws, for lcGAN.
        seed: seed of both generators' noise streams.
        idm, mobil: physics parameters (default Table A.1); dataclasses or mappings of their fields.
        num_lanes: lanes of the road (MOBIL and lcGAN lane availability).
        device: device of the generative networks.
        event_oracle: after trajGAN (or the prior's key gaps), :class:`EventOracleKeyGaps`: the braking event car's
            key gaps from its script (the braking study's oracle; not the paper's method).
        compile: ``torch.compile`` the whole stack (physics priors and GAN inference) as ONE function per
            frame (:func:`~kddrl_trl.transforms.stack.compiled_frames`, where the measured gain is stated),
            after a one-off compile per process (a bool: a config's ``auto`` is resolved once, by ``make_job``).
            Off by default.

    A Hydra / plain-dict config maps onto the keyword arguments: ``make_kddrl_transforms(**cfg)``.

    Examples:
        >>> from torchrl.envs import TransformedEnv
        >>> from kddrl_trl.envs import FakeHighwayEnv
        >>> env = TransformedEnv(FakeHighwayEnv(num_roads=2), make_kddrl_transforms())
        >>> env.reset()["prior", "p_mobil"].shape
        torch.Size([2, 3])
    """
    if reduce not in REDUCTIONS:
        raise ValueError(f"reduce must be one of {REDUCTIONS}, got {reduce!r}")
    if int(num_samples) < 1:
        raise ValueError(f"num_samples must be >= 1, got {num_samples!r}")
    if weights == "auto":
        raise ValueError(
            "make_kddrl_transforms(weights='auto'): 'auto' (the env simulator's traffic) is resolved by a training "
            "config (kddrl_trl.generative.shipped_traffic); here name the traffic: 'sumo' or 'highwayenv'"
        )
    idm_p, mobil_p = as_idm_params(idm), as_mobil_params(mobil)
    trajgan_checkpoint = trajgan_checkpoint or default_checkpoint("trajgan", weights)
    lcgan_checkpoint = lcgan_checkpoint or default_checkpoint("lcgan", weights)
    seed, num_lanes = int(seed), int(num_lanes)
    stack = [IDMPrior(idm_p)]
    if trajgan:
        stack.append(
            TrajGANPrediction(
                checkpoint=trajgan_checkpoint, num_samples=int(num_samples), reduce=reduce, seed=seed, device=device
            )
        )
    else:
        stack.append(KeyGapsFromPrior())
    if event_oracle:
        stack.append(EventOracleKeyGaps())
    if priors:
        stack.append(MOBILPrior(mobil_p, idm_p, num_lanes=num_lanes))
        draws = int(num_samples) if reduce == "mean" else 1
        stack.append(
            LCGANPrior(checkpoint=lcgan_checkpoint, num_lanes=num_lanes, draws=draws, seed=seed, device=device)
        )
    history = None
    if trajgan:  # trajGAN reads ("leaders","history"): built by LeaderHistory where the env does not write it
        history = LeaderHistory(history_len=int(getattr(stack[1].predictor, "history_len", 10)))
    return PredictiveStack(*stack, history=history, compile=compile)
