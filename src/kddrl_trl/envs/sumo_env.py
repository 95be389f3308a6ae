"""``SumoHighwayEnv``: the batched TorchRL environment over libsumo (paper §III.G, §IV.A-D, Table A.1).

K independent copies of the 3-lane study road live in one SUMO simulation (one per process, a libsumo
rule), so the environment has ``batch_size=[K]`` with one ego per road and TorchRL's per-call overhead is
paid once per K frames. Partial resets (``"_reset"``) designate a new ego on the selected roads only.

Example:
    >>> from kddrl_trl.envs import SumoHighwayEnv
    >>> env = SumoHighwayEnv(scenario="braking", num_roads=8, seed=0)
    >>> td = env.rollout(50, break_when_any_done=False)
    >>> td["next", "lc", "reward"].shape
    torch.Size([8, 50, 1])
    >>> from kddrl_trl.baselines import IDMMobilPolicy
    >>> from kddrl_trl.eval import evaluate_policy
    >>> episodes = evaluate_policy(env, IDMMobilPolicy(), episodes=8, seed=0)  # per-episode metrics
    >>> episodes[0]["outcome"]
    'left_section'
    >>> env.close()
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from .. import keys as K
from .observe import FiniteCheck
from .sim import HighwaySim
from .specs import HighwayEnvBase, lc_command


class SumoHighwayEnv(HighwayEnvBase):
    """The KDDRL highway: K roads x one ego, raw keys of ``kddrl_trl.keys``, two per-agent rewards.

    Args:
        scenario: ``"baseline"``, ``"congested"``, ``"congested_text"`` or ``"braking"`` (``highway_config.SCENARIOS``).
        num_roads: K >= 1, the batch size.
        seed: seeds SUMO and the env's own generator; same seed -> identical rollouts.
        device: torch device of the output tensors (the simulator itself is CPU).
        gui: drive ``sumo-gui`` (a live view of road 0's ego, in real time; needs a display, e.g. ``xvfb-run``).
        road_seeds: the seed whose traffic each of the K roads carries (None: ``seed`` for all;
            :class:`~kddrl_trl.envs.sim.HighwaySim`): the roads of seed ``s`` carry the traffic of an env of their
            own with ``seed=s``.
        **overrides: any field of :class:`~kddrl_trl.highway_config.HighwayConfig` (e.g. ``flow_vph=2658``,
            ``braking={"stand_time": 5}``); unknown keys or bad values raise ``ValueError`` naming the key
            before SUMO starts.

    Actions: ``("lc","action")`` one-hot (left, keep, right); ``("cf","action")`` acceleration in
    [-5, 5] m/s². A lane-change command is executed only where ``("lc","action_mask")`` allows it (no
    manoeuvre in progress and the target lane exists); otherwise the lane is kept.

    Besides the observation, every frame carries the episode events of ``kddrl_trl.keys`` (outcome, collision
    kind and slot, braking phase and distance), from which :class:`~kddrl_trl.eval.EpisodeTracker` computes the
    per-episode metrics.

    Faults: a SUMO error on one road (a ``TraCIException`` while it is commanded or observed) truncates that
    road's episode as ``lost`` (counted in ``stats["sumo_errors"]``), the other roads go on; a NaN or infinity in
    an output raises :class:`~kddrl_trl.envs.observe.NonFiniteObservation` naming the key and the roads.

    Attributes:
        stats: counters (episodes, collisions, SUMO errors, braking events, ...).
        vehicle_params: driver class and drawn IDM parameters of every background vehicle in the simulation
            (those of vehicles that left are dropped every 200 steps).
    """

    def __init__(
        self,
        scenario: str = "baseline",
        num_roads: int = 1,
        seed: int = 0,
        device=None,
        gui: bool = False,
        road_seeds=None,
        **overrides,
    ):
        super().__init__(scenario, num_roads, seed, device, **overrides)
        self.sim = HighwaySim(self.config, num_roads, seed=seed, gui=gui, road_seeds=road_seeds)
        self._seed = seed
        self._bind()

    # ------------------------------------------------------------------------------------- views
    @property
    def stats(self) -> dict:
        return self.sim.stats

    @property
    def vehicle_params(self) -> dict:
        return self.sim.vehicle_params

    # ------------------------------------------------------------------------------------ TorchRL
    def _bind(self) -> None:
        """Wrap the simulator's numpy arrays (no copy) in two nested TensorDicts, for reset and for step
        outputs. The arrays are overwritten every frame, so outputs are clones of these views: one
        ``TensorDict.clone`` is several times cheaper than building a TensorDict leaf by leaf."""
        sim, batch = self.sim, self.batch_size
        self._done = np.zeros_like(sim.terminated)

        def view(with_reward: bool) -> TensorDict:
            leaves = {key: torch.from_numpy(arr) for key, arr in sim.outputs(with_reward).items()}
            return TensorDict({**leaves, "done": torch.from_numpy(self._done)}, batch_size=batch)

        self._reset_view, self._step_view = view(False), view(True)
        self._check_finite = FiniteCheck(sim.outputs(True))
        self._bound = sim.obs  # the arrays of a reseeded simulation are new: rebind then

    def _output(self, with_reward: bool) -> TensorDictBase:
        """A fresh TensorDict holding a copy of the simulator's current arrays."""
        if self._bound is not self.sim.obs:
            self._bind()
        np.logical_or(self.sim.terminated, self.sim.truncated, out=self._done)
        self._check_finite()  # NonFiniteObservation naming the key: a NaN never reaches a transform or network
        out = (self._step_view if with_reward else self._reset_view).clone()
        return out if self.device is None or self.device == torch.device("cpu") else out.to(self.device)

    def _check_open(self) -> None:
        if self.sim.closed:
            raise RuntimeError(
                "this SumoHighwayEnv is closed (close() was called, e.g. by a collector's shutdown): create a new one"
            )

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        self._check_open()
        if tensordict is not None and "_reset" in tensordict.keys():
            roads = tensordict.get("_reset").reshape(self.num_roads).nonzero().flatten().tolist()
        else:
            roads = list(range(self.num_roads))
        self.sim.reset_roads(roads)
        return self._output(with_reward=False)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._check_open()
        lc = lc_command(tensordict.get(K.LC_ACTION)).reshape(-1).cpu().numpy()
        acc = tensordict.get(K.CF_ACTION).reshape(-1).detach().cpu().numpy()
        self.sim.step(lc, acc)
        return self._output(with_reward=True)

    def _set_seed(self, seed: int | None) -> None:
        seed = 0 if seed is None else int(seed)
        self._seed = seed
        if hasattr(self, "sim") and not self.sim.closed:
            self.sim.reseed(seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        if hasattr(self, "sim"):
            self.sim.close()
        super().close(raise_if_closed=False)
