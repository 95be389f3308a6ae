"""What the generative models read, written once for the three places that build it (paper §III.B-C).

The naturalistic samples of :mod:`kddrl_trl.data.extract` (training), the generative models of
:mod:`kddrl_trl.generative` and the transforms of :mod:`kddrl_trl.transforms` (RL time) all import these
facts from here. Only ``torch`` and :mod:`kddrl_trl.keys` are imported, so the RL runtime never loads
``kddrl_trl.data`` (pandas) to get them.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: the trajGAN key steps of Eq. 24, 1-based (step 10 = 1 s, step 20 = 2 s ahead at 10 Hz), paper §III.B
KEY_STEPS = (10, 20)
#: driver_type vocabulary of the samples; ``leader_driver`` / ``driver`` index into it ("" -> "unknown")
DRIVER_TYPES = ("unknown", "timid", "normal", "aggressive")


def lane_change_condition(
    speed: Tensor,
    lateral_speed: Tensor,
    lane: Tensor,
    lane_offset: Tensor,
    rel: Tensor,
    mask: Tensor,
    neighbor_lane_offset: Tensor,
    key_gaps: Tensor,
) -> dict[str, Tensor]:
    """The unnormalised lcGAN condition ``C = {S_AV, S_SV, y_pre}`` of Eq. 16, as the fields of the
    ``lane_changes`` samples; the training samples (numpy tracks of our recordings or of HighD files) and the
    RL-time predictor (env keys) both build it here.

    Args:
        speed: ``[*B]`` ego longitudinal speed (m/s).
        lateral_speed: ``[*B]`` ego lateral speed (m/s, + = left).
        lane: ``[*B]`` ego lane index (0 = rightmost).
        lane_offset: ``[*B]`` ego lateral offset from its lane's centre (m, + = left; ``keys.EGO_LANE_OFFSET``).
        rel: ``[*B, 6, 4]`` slots a..f as ``keys.NEIGHBORS_REL`` (any value where absent, even NaN).
        mask: ``[*B, 6]`` slot present (``keys.NEIGHBORS_MASK``).
        neighbor_lane_offset: ``[*B, 6]`` each neighbour's lateral offset from the centre of its own lane (m,
            + = left; ``keys.NEIGHBORS_LANE_OFFSET``; any value where absent).
        key_gaps: ``[*B, 3, 2]`` position of leaders a, b, c at :data:`KEY_STEPS` minus the ego position (m);
            NaN where not known (training: the leader's track ends before step 20).

    Returns:
        ``s_av`` ``[*B, 4]`` (speed, lateral speed, lane as float, lane offset), ``rel`` ``[*B, 6, 4]`` and
        ``lane_offset`` ``[*B, 6]`` (0 where absent), ``mask`` ``[*B, 6]`` bool, ``key_gaps`` ``[*B, 3, 2]``
        (0 where absent) and ``key_gaps_mask`` ``[*B, 3]`` bool: the leader is present and both its key gaps
        are finite. All float fields float32.
    """
    mask = torch.as_tensor(mask).bool()
    rel, key_gaps = torch.as_tensor(rel, dtype=torch.float32), torch.as_tensor(key_gaps, dtype=torch.float32)
    nb_offset = torch.as_tensor(neighbor_lane_offset, dtype=torch.float32)
    key_gaps_mask = mask[..., :3] & torch.isfinite(key_gaps).all(-1)
    s_av = torch.stack(
        [torch.as_tensor(x, dtype=torch.float32) for x in (speed, lateral_speed, lane, lane_offset)], dim=-1
    )
    zero = torch.zeros((), dtype=torch.float32, device=rel.device)
    return {
        "s_av": s_av,
        "rel": torch.where(mask.unsqueeze(-1), rel, zero),
        "lane_offset": torch.where(mask, nb_offset, zero),
        "mask": mask,
        "key_gaps": torch.where(key_gaps_mask.unsqueeze(-1), key_gaps, zero),
        "key_gaps_mask": key_gaps_mask,
    }
