"""Shared embedding s_e = embedding(P_lc, y_lv^pre) read by both agents — paper Eq. 24 (§III.G, Fig. 5).

Which losses train it, and how one instance is shared by the two TorchRL losses, is decided in
:mod:`kddrl_trl.modules.sharing`.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from tensordict.utils import NestedKey
from torch import nn
from torchrl.modules import MLP

from .. import keys as K
from .fusion import PriorFusion

#: Fixed scale of the key-step gaps y_lv^pre (m): 100 m maps the usual ±200 m sensing window to ±2.
KEY_GAP_SCALE = 100.0
#: Scaled gaps are clipped to ±KEY_GAP_CLIP, so a sentinel written for an absent leader cannot dominate.
KEY_GAP_CLIP = 5.0


class _EmbeddingNet(nn.Module):
    def __init__(
        self,
        prior_dim: int,
        key_gaps: bool,
        out_features: int,
        hidden: int,
        depth: int,
        gap_scale: float,
        gap_clip: float,
    ):
        super().__init__()
        self.prior_dim, self.key_gaps = prior_dim, key_gaps
        self.gap_scale, self.gap_clip = float(gap_scale), float(gap_clip)
        in_features = prior_dim + (6 if key_gaps else 0)
        self.mlp = MLP(
            in_features=in_features, out_features=out_features, num_cells=[hidden] * depth, activation_class=nn.ELU
        )
        self.out = nn.Tanh()

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        parts = list(inputs)
        if self.key_gaps:
            gaps = parts[-1].flatten(-2) / self.gap_scale  # [*B, 3, 2] -> [*B, 6], ~unit range
            parts[-1] = gaps.clamp(-self.gap_clip, self.gap_clip)
        return self.out(self.mlp(torch.cat(parts, dim=-1)))


class SharedEmbedding(TensorDictModule):
    """The shared embedding layer of the vehicle-control module — paper Eq. 24.

    ``s_e = embedding(P_lc, y_lv^pre)`` with ``y_lv,i^pre = [TG_i^{t10} - y_AV, TG_i^{t20} - y_AV]`` for the
    leaders i = a, b, c (``keys.PRED_KEY_GAPS``, ``[*B, 3, 2]`` in metres). The gaps are flattened to 6
    features, divided by :data:`KEY_GAP_SCALE` (100 m) and clipped to ±:data:`KEY_GAP_CLIP`; ``P_lc``
    (Eq. 23, already in [-1, 1]) is concatenated unscaled; a small MLP (ELU hidden layers, tanh output)
    maps the result to ``s_e`` ``[*B, d]``. Any batch shape works.

    Either input can be switched off for the ablations: ``prior_dim=None`` reads only the key gaps
    ("without LG"), ``key_gaps=False`` reads only ``P_lc`` (``d3qn_td3_lg``).

    Args:
        out_features (int): ``d``, the size of ``s_e``. Defaults to 16.
        hidden (int): width of the hidden layers. Defaults to 64.

    Keyword Args:
        prior_dim (int or None): size of ``P_lc``; ``None`` = no prior input. Defaults to 16.
        key_gaps (bool): read ``keys.PRED_KEY_GAPS``. Defaults to ``True``.
        depth (int): number of hidden layers. Defaults to 1.
        gap_scale (float): metres per unit for the key gaps. Defaults to :data:`KEY_GAP_SCALE`.
        gap_clip (float): clip of the scaled key gaps. Defaults to :data:`KEY_GAP_CLIP`.
        prior_key, gaps_key, out_key (NestedKey): default to ``keys.PRIOR_P_LC``, ``keys.PRED_KEY_GAPS``,
            ``keys.EMBED_S_E``.
    """

    def __init__(
        self,
        out_features: int = 16,
        hidden: int = 64,
        *,
        prior_dim: int | None = 16,
        key_gaps: bool = True,
        depth: int = 1,
        gap_scale: float = KEY_GAP_SCALE,
        gap_clip: float = KEY_GAP_CLIP,
        prior_key: NestedKey = K.PRIOR_P_LC,
        gaps_key: NestedKey = K.PRED_KEY_GAPS,
        out_key: NestedKey = K.EMBED_S_E,
    ):
        if prior_dim is None and not key_gaps:
            raise ValueError("SharedEmbedding needs P_lc, the key gaps, or both (use no embedding instead)")
        in_keys = ([prior_key] if prior_dim is not None else []) + ([gaps_key] if key_gaps else [])
        net = _EmbeddingNet(prior_dim or 0, key_gaps, out_features, hidden, depth, gap_scale, gap_clip)
        super().__init__(net, in_keys=in_keys, out_keys=[out_key])
        self.out_features = out_features


def make_shared_embedding(
    d: int = 16,
    hidden: int = 64,
    priors: bool = True,
    key_gaps: bool = True,
    *,
    prior_dim: int | None = None,
    depth: int = 1,
) -> TensorDictSequential | None:
    """Builds the whole embedding path of Fig. 5: Eq. 23 fusion followed by the Eq. 24 shared embedding.

    One instance is built per run and shared by both agents (see :mod:`kddrl_trl.modules.sharing`).

    - ``priors=True, key_gaps=True`` (``kddrl``): ``TensorDictSequential(PriorFusion, SharedEmbedding)``.
    - ``priors=True, key_gaps=False`` (``d3qn_td3_lg``): the same, ``SharedEmbedding`` reads ``P_lc`` only.
    - ``priors=False, key_gaps=True`` ("without LG"): ``TensorDictSequential(SharedEmbedding)`` on the gaps.
    - ``priors=False, key_gaps=False`` (``d3qn_td3``): ``None`` — no ``s_e``; build the agent states with
      ``lc_state(embed=False)`` / ``cf_state(embed=False)``.

    Reads ``keys.PRIOR_P_LCGAN``, ``keys.PRIOR_P_MOBIL`` ``[*B, 3]`` (when ``priors``) and
    ``keys.PRED_KEY_GAPS`` ``[*B, 3, 2]`` (when ``key_gaps``); writes ``keys.PRIOR_P_LC`` ``[*B, prior_dim]``
    (when ``priors``) and ``keys.EMBED_S_E`` ``[*B, d]``.

    Args:
        d (int): size of ``s_e``. Defaults to 16.
        hidden (int): hidden width of both MLPs. Defaults to 64.
        priors (bool): fuse and read the lcGAN/MOBIL priors. Defaults to ``True``.
        key_gaps (bool): read the trajGAN key-step gaps. Defaults to ``True``.

    Keyword Args:
        prior_dim (int, optional): size of ``P_lc``. Defaults to ``d``.
        depth (int): hidden layers per MLP. Defaults to 1.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from kddrl_trl import keys as K
        >>> from kddrl_trl.modules import make_shared_embedding
        >>> td = TensorDict({K.PRIOR_P_LCGAN: torch.full((4, 7, 3), 1 / 3),
        ...                  K.PRIOR_P_MOBIL: torch.full((4, 7, 3), 1 / 3),
        ...                  K.PRED_KEY_GAPS: torch.randn(4, 7, 3, 2) * 50}, [4, 7])
        >>> make_shared_embedding(d=16)(td)[K.EMBED_S_E].shape
        torch.Size([4, 7, 16])
    """
    if not priors and not key_gaps:
        return None
    prior_dim = d if prior_dim is None else prior_dim
    modules = [PriorFusion(prior_dim, hidden, depth=depth)] if priors else []
    modules.append(SharedEmbedding(d, hidden, prior_dim=prior_dim if priors else None, key_gaps=key_gaps, depth=depth))
    return TensorDictSequential(*modules)
