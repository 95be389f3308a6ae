"""Knowledge-data prior fusion P_lc = embedding(P_lcGAN, P_MOBIL) — paper Eq. 23 (§III.C.3, Fig. 4)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import nn
from torchrl.modules import MLP

from .. import keys as K


class _ConcatMLP(nn.Module):
    """Concatenates its inputs on the last dimension and runs an MLP with a tanh output (values in [-1, 1])."""

    def __init__(self, in_features: int, out_features: int, hidden: int, depth: int = 1):
        super().__init__()
        self.mlp = MLP(
            in_features=in_features, out_features=out_features, num_cells=[hidden] * depth, activation_class=nn.ELU
        )
        self.out = nn.Tanh()

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        return self.out(self.mlp(torch.cat(inputs, dim=-1)))


class PriorFusion(TensorDictModule):
    """Fuses the data-driven and the knowledge-driven lane-change priors — paper Eq. 23.

    ``P_lc = embedding(P_lcGAN, P_MOBIL)``: the two distributions over (left, keep, right) are concatenated
    (6 features, already in [0, 1], no scaling needed) and mapped by a small MLP (ELU hidden layers, tanh
    output) to a compact ``d``-dimensional vector. Works for any batch shape (``[]``, ``[B]``, ``[B, T]``...).

    The fusion has no loss of its own: it is trained end to end, as part of the shared embedding, by the
    value losses named in :mod:`kddrl_trl.modules.sharing`.

    Args:
        out_features (int): ``d``, the size of ``P_lc``. Defaults to 16.
        hidden (int): width of the hidden layers. Defaults to 64.

    Keyword Args:
        depth (int): number of hidden layers. Defaults to 1.
        in_keys (pair of NestedKey): ``(P_lcGAN, P_MOBIL)`` keys, each ``[*B, 3]``.
            Defaults to ``(keys.PRIOR_P_LCGAN, keys.PRIOR_P_MOBIL)``.
        out_key (NestedKey): where ``P_lc`` ``[*B, d]`` is written. Defaults to ``keys.PRIOR_P_LC``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from kddrl_trl import keys as K
        >>> from kddrl_trl.modules import PriorFusion
        >>> td = TensorDict({K.PRIOR_P_LCGAN: torch.full((4, 3), 1 / 3),
        ...                  K.PRIOR_P_MOBIL: torch.tensor([0.0, 1.0, 0.0]).expand(4, 3)}, [4])
        >>> PriorFusion(out_features=8)(td)[K.PRIOR_P_LC].shape
        torch.Size([4, 8])
    """

    def __init__(
        self,
        out_features: int = 16,
        hidden: int = 64,
        *,
        depth: int = 1,
        in_keys: Sequence[NestedKey] = (K.PRIOR_P_LCGAN, K.PRIOR_P_MOBIL),
        out_key: NestedKey = K.PRIOR_P_LC,
    ):
        in_keys = list(in_keys)
        if len(in_keys) != 2:
            raise ValueError(f"PriorFusion reads exactly two priors (P_lcGAN, P_MOBIL), got {in_keys}")
        super().__init__(_ConcatMLP(6, out_features, hidden, depth), in_keys=in_keys, out_keys=[out_key])
        self.out_features = out_features
