"""TensorDict modules of the vehicle-control module (paper §III.C.3, §III.G, Fig. 4-5).

- :class:`PriorFusion` — P_lc = embedding(P_lcGAN, P_MOBIL), Eq. 23.
- :class:`SharedEmbedding`, :func:`make_shared_embedding` — s_e = embedding(P_lc, y_lv^pre), Eq. 24; one
  instance shared by both agents.
- :func:`lc_state` (s_D3QN, Eq. 24 → ``keys.LC_OBS``) and :func:`cf_state` (s_TD3, Eq. 30 →
  ``keys.CF_OBS``), with fixed input scaling :class:`StateScale`.
- :mod:`~kddrl_trl.modules.sharing` — the decision on which losses train the embedding (both critics'
  value losses: D3QN's TD loss and TD3's critic loss; never the TD3 actor loss nor the bootstrap targets),
  and the helpers that implement it: :func:`build_agent_states`, :func:`detach_embedding`,
  :func:`embedding_parameters`, :func:`make_target_embedding`, :func:`soft_update_embedding_`.
"""

from .embedding import (
    KEY_GAP_CLIP,
    KEY_GAP_SCALE,
    SharedEmbedding,
    make_shared_embedding,
)
from .fusion import PriorFusion
from .sharing import (
    EMBEDDING_KEYS,
    build_agent_states,
    detach_embedding,
    embedding_parameters,
    make_target_embedding,
    soft_update_embedding_,
)
from .state import (
    BASE_DIM,
    STATE_EXTRAS,
    StateScale,
    cf_obs_dim,
    cf_state,
    check_extras,
    headway_features,
    lc_obs_dim,
    lc_state,
)

__all__ = [
    "BASE_DIM",
    "STATE_EXTRAS",
    "check_extras",
    "headway_features",
    "EMBEDDING_KEYS",
    "KEY_GAP_CLIP",
    "KEY_GAP_SCALE",
    "PriorFusion",
    "SharedEmbedding",
    "StateScale",
    "build_agent_states",
    "cf_obs_dim",
    "cf_state",
    "detach_embedding",
    "embedding_parameters",
    "lc_obs_dim",
    "lc_state",
    "make_shared_embedding",
    "make_target_embedding",
    "soft_update_embedding_",
]
