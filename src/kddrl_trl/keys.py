"""Every TensorDict key shared across kddrl_trl modules (docs/design.md, "Key contract").

Conventions: nested keys, snake_case leaves, SI units (m, m/s, m/s², s), a trailing feature dimension.
The paper's coordinates are used throughout: ``y`` is *longitudinal* (along the road, metres from the
start of the 420 m study section), ``x`` is *lateral* (metres from the right road edge, growing to the left).

Neighbour slots are always ordered ``a, b, c, d, e, f`` = (left leader, current leader, right leader,
left follower, current follower, right follower) — paper Fig. 6. Lane-change actions are always ordered
(left, keep, right) — paper Eq. 25.
"""

from __future__ import annotations

# ----------------------------------------------------------------------------------------- orderings
LC_ACTIONS = ("left", "keep", "right")
LEFT, KEEP, RIGHT = 0, 1, 2
NEIGHBOR_SLOTS = ("a", "b", "c", "d", "e", "f")
LEADER_SLOTS = ("a", "b", "c")
#: index of each neighbour slot in ``NEIGHBORS_*`` tensors
SLOT = {name: i for i, name in enumerate(NEIGHBOR_SLOTS)}
#: feature order of ``NEIGHBORS_REL``: Δx (lateral), Δy (longitudinal), Δv_x, Δv_y — neighbour minus ego
REL_FEATURES = ("dx", "dy", "dvx", "dvy")
#: feature order of ``NEIGHBORS_KIN``: absolute longitudinal position, speed, acceleration
KIN_FEATURES = ("y", "v", "a")
#: feature order of ``EGO_STATE``: y, v_y, v_x — paper Eq. 24 (s_AV)
EGO_FEATURES = ("y", "vy", "vx")
#: feature order of ``LEADERS_AHEAD``: position, speed, presence (1.0 / 0.0) of the vehicle ahead of a leader
AHEAD_FEATURES = ("y", "v", "present")
#: feature order of ``LEADERS_HISTORY``: position, speed
HISTORY_FEATURES = ("y", "v")

# ------------------------------------------------------------------------------- raw (environment)
EGO_STATE = ("ego", "state")  # [3]  y, v_y, v_x
EGO_LANE = ("ego", "lane")  # [1]  int64, 0 = rightmost
EGO_ACCEL = ("ego", "accel")  # [1]  acceleration executed in the last frame (m/s²)
EGO_LANE_OFFSET = ("ego", "lane_offset")  # [1]  lateral offset from the centre of the ego's lane (m, + = left)
NEIGHBORS_REL = ("neighbors", "rel")  # [6, 4]
NEIGHBORS_MASK = ("neighbors", "mask")  # [6]  bool, neighbour present within sensing range
NEIGHBORS_KIN = ("neighbors", "kin")  # [6, 3]
NEIGHBORS_LANE_OFFSET = ("neighbors", "lane_offset")  # [6] each neighbour's offset from its lane's centre (m, + left)
LEADERS_AHEAD = ("leaders", "ahead")  # [3, 3]
LEADERS_HISTORY = ("leaders", "history")  # [3, H, 2], oldest first, last entry = current frame
LC_ACTION_MASK = ("lc", "action_mask")  # [3]  bool, which lane-change commands would be executed now
LC_ACTIVE = ("lc", "active")  # [1]  bool, a lane-change manoeuvre is in progress
LC_STARTED = ("lc", "started")  # [1]  bool, a lane-change manoeuvre started in this frame
COLLISION = "collision"  # [1]  bool, the ego collided in this frame (read under "next")

# ---------------------------------------------------------------- episode events (environment, under "next")
# Per-frame facts the episode metrics (``kddrl_trl.eval.EpisodeTracker``) need beyond the observation above.
# Codes are int64 indices into the tuples below; on a road whose episode ended and was not reset yet they
# keep the values of the ending frame.
#: how the episode ended in this frame: ``collision`` and ``left_section`` (past the study section) terminate,
#: ``max_steps`` and ``lost`` (SUMO lost the ego) truncate
OUTCOMES = ("running", "collision", "left_section", "max_steps", "lost")
RUNNING, COLLIDED, LEFT_SECTION, MAX_STEPS, LOST = range(len(OUTCOMES))
#: what kind of contact a collision was: the ego ran into a vehicle ahead, a vehicle behind ran into the ego,
#: or any contact while the ego's lane change is in progress
COLLISION_KINDS = ("none", "rear_end", "hit_from_behind", "side")
NO_CONTACT, REAR_END, HIT_FROM_BEHIND, SIDE_CONTACT = range(len(COLLISION_KINDS))
#: phases of the scenario-2 braking event on the ego's road (``none`` before it starts and in other scenarios);
#: ``vanished``: the braking vehicle left the simulation before it resumed
BRAKING_PHASES = ("none", "braking", "standing", "resumed", "vanished")
BRAKE_NONE, BRAKE_BRAKING, BRAKE_STANDING, BRAKE_RESUMED, BRAKE_VANISHED = range(len(BRAKING_PHASES))

OUTCOME = ("episode", "outcome")  # [1]  int64, code in OUTCOMES (running while the episode goes on)
COLLISION_KIND = ("episode", "collision_kind")  # [1]  int64, code in COLLISION_KINDS of this frame's collision
COLLISION_SLOT = ("episode", "collision_slot")  # [1]  int64, NEIGHBOR_SLOTS index of the other vehicle in the last
#                                                      observation before the collision; -1 none / not a neighbour
BRAKING_PHASE = ("braking", "phase")  # [1]  int64, code in BRAKING_PHASES
BRAKING_DISTANCE = ("braking", "distance")  # [1]  gap (m) to the braking leader when it started; 0 before
# the event's car, from the frame it starts braking to the episode's end (0 before; the last values once it is gone):
BRAKING_GAP = ("braking", "gap")  # [1]  m from the ego's front bumper to the car's rear bumper (< 0: behind the ego)
BRAKING_SPEED = ("braking", "speed")  # [1]  its speed (m/s)
BRAKING_LANE_CHANGES = ("braking", "lane_changes")  # [1]  int64, its lane changes since it was released
BRAKING_CONTACT = ("braking", "contact")  # [1]  bool, this frame's collision of the ego was with it
BRAKING_SLOT = ("braking", "slot")  # [1]  int64, the leader slot (0, 1, 2 = a, b, c) it holds in this observation; -1
#: the event car's position (m) 10 and 20 frames ahead as its script makes it (braking at ``decel`` to a stop, standing,
#: a programmed release), and where the script fixes it (False once SUMO drives the car, after a ``sumo`` release)
BRAKING_FUTURE = ("braking", "future")  # [2]  m, at frames +10 and +20 (the key steps of Eq. 24)
BRAKING_FUTURE_KNOWN = ("braking", "future_known")  # [2]  bool

#: the raw keys a driver senses: the ego's own state, its neighbours, their leaders and its lane-change state
SENSED_KEYS = (
    EGO_STATE,
    EGO_LANE,
    EGO_ACCEL,
    NEIGHBORS_REL,
    NEIGHBORS_MASK,
    NEIGHBORS_KIN,
    LEADERS_AHEAD,
    LEADERS_HISTORY,
    LC_ACTION_MASK,
    LC_ACTIVE,
    LC_STARTED,
    EGO_LANE_OFFSET,
    NEIGHBORS_LANE_OFFSET,
)
#: the raw keys that label the episode for metrics and study records (whether and how it ended, the scripted event's
#: phase, its car's scripted future for an oracle predictor): written by the env beside the observation, never
#: something a driver senses
EPISODE_LABEL_KEYS = (
    COLLISION,
    OUTCOME,
    COLLISION_KIND,
    COLLISION_SLOT,
    BRAKING_PHASE,
    BRAKING_DISTANCE,
    BRAKING_GAP,
    BRAKING_SPEED,
    BRAKING_LANE_CHANGES,
    BRAKING_CONTACT,
    BRAKING_SLOT,
    BRAKING_FUTURE,
    BRAKING_FUTURE_KNOWN,
)
#: every raw key the env writes
RAW_OBSERVATION_KEYS = SENSED_KEYS + EPISODE_LABEL_KEYS

# ------------------------------------------------------------------------------ derived (transforms)
PRED_PRIOR_TRAJ = ("pred", "prior_traj")  # [3, 20] IDM-rolled prior positions TC of a, b, c
PRED_TRAJ = ("pred", "traj")  # [3, 20] trajGAN-refined positions TG of a, b, c
PRED_KEY_GAPS = ("pred", "key_gaps")  # [3, 2]  TG at steps 10 and 20 minus ego position
PRIOR_P_MOBIL = ("prior", "p_mobil")  # [3]     P_MOBIL over (left, keep, right), Eq. 22
PRIOR_P_LCGAN = ("prior", "p_lcgan")  # [3]     P_lcGAN over (left, keep, right), Eq. 16
PRIOR_P_LC = ("prior", "p_lc")  # [d]     fused prior, Eq. 23
EMBED_S_E = ("embed", "s_e")  # [d]     shared embedding, Eq. 24
MOBIL_INCENTIVE = ("prior", "mobil_incentive")  # [3] MOBIL utilities U_left, U_keep, U_right (m/s², Eq. 21-22)
MOBIL_SAFE = ("prior", "mobil_safe")  # [3] bool, MOBIL safety criterion per direction (Eq. 20-21)

# ------------------------------------------------------------------------- agent states (modules/)
# Written by the state builders of ``kddrl_trl.modules.state`` from raw keys (scaled to ~unit range) and,
# when present, ``EMBED_S_E``. Not stored in replay buffers: recomputed at update time because s_e is trained.
LC_OBS = ("lc", "obs")  # [33 + d] D3QN state s_D3QN = [s_AV, Δs_i, mask, s_e], Eq. 24 (d = 0 without s_e)
CF_OBS = ("cf", "obs")  # [37 + d] TD3 state s_TD3 = [s_AV, Δs_i, mask, s_e, a_D3QN, a_TD3^{t-1}], Eq. 30
JOINT_OBS = ("joint", "obs")  # [37] state of a unified agent = [s_AV, Δs_i, mask, a_lc^{t-1}, a^{t-1}]

# --------------------------------------------------------------------------------- actions, rewards
LC_ACTION = ("lc", "action")  # [3] one-hot (left, keep, right), held between decisions
LC_DECIDE = ("lc", "decide")  # [1] bool, the lane-change agent decides on this frame
CF_ACTION = ("cf", "action")  # [1] acceleration in [-5, 5] m/s²
LC_REWARD = ("lc", "reward")  # [1] paper Eq. 26-29
CF_REWARD = ("cf", "reward")  # [1] paper Eq. 32-33
# the rewards' named terms, written by the env under "next" beside the two rewards (which are their sums: LC_REWARD =
# efficiency + lane_change + collision, CF_REWARD = efficiency + comfort + collision; envs/rewards.py)
REWARD_TERMS = "reward_terms"
EFFICIENCY_TERM = (REWARD_TERMS, "efficiency")  # [1] r_eff, Eq. 27 (or the variant of HighwayConfig.reward)
LANE_CHANGE_TERM = (REWARD_TERMS, "lane_change")  # [1] r_lc, Eq. 28
COLLISION_TERM = (REWARD_TERMS, "collision")  # [1] r_collision, Eq. 29
COMFORT_TERM = (REWARD_TERMS, "comfort")  # [1] r_acc, Eq. 33
TERM_KEYS = (EFFICIENCY_TERM, LANE_CHANGE_TERM, COLLISION_TERM, COMFORT_TERM)
CF_SHIELD = ("cf", "shield")  # [1] bool, the car-following shield lowered the command in this frame (under "next";
#                                     transforms.SafetyShield, algo.shield; absent without a shield)
JOINT_ACTION = ("joint", "action")  # [3 x levels] one-hot joint (lane command, acceleration level) of d3qn_unified
JOINT_ACTION_MASK = ("joint", "action_mask")  # [3 x levels] bool, LC_ACTION_MASK repeated over the levels
JOINT_REWARD = ("joint", "reward")  # [1] reward of a unified agent: LC_REWARD + CF_REWARD (under "next")

# ------------------------------------------------------------------------- clocks (collectors/)
LC_HELD = ("lc", "held")  # [3] one-hot lane-change action in force (executed last frame; keep at reset)
LC_MACRO_FRAMES = ("lc", "macro_frames")  # [1] int64, frames a macro-transition of buffer H spans (under "next")

# -------------------------------------------------------------------------- learner outputs (objectives/)
LC_ACTION_VALUE = ("lc", "action_value")  # [3] Q(s, ·) of D3QN, Eq. 3
LC_CHOSEN_VALUE = ("lc", "chosen_action_value")  # [1] Q(s, a) of the taken action
CF_STATE_ACTION_VALUE = ("cf", "state_action_value")  # [1] TD3 / DDPG critic value Q_k(s, a), Eq. 7
JOINT_ACTION_VALUE = ("joint", "action_value")  # [3 x levels] Q(s, ·) of d3qn_unified
JOINT_CHOSEN_VALUE = ("joint", "chosen_action_value")  # [1] Q(s, a) of the taken joint action
PASAC_LOGITS = ("pasac", "logits")  # [3] lane-choice logits of the PASAC policy (invalid commands masked)
PASAC_LOC = ("pasac", "loc")  # [3, 1] mean of the pre-tanh Gaussian of the PASAC acceleration, per lane command
PASAC_SCALE = ("pasac", "scale")  # [3, 1] its standard deviation
PASAC_STATE_ACTION_VALUE = ("pasac", "state_action_value")  # [1] soft Q(s, lane, accel)
PRIORITY = "priority"  # [B] |TD error| of each sampled transition, written by a learner's update
# into the sample: a prioritized buffer's new priorities (train.prioritized;
# not TorchRL losses' own "td_error", which they write in their own shapes)
PRIORITY_WEIGHT = "priority_weight"  # [B] importance-sampling weight of a prioritized sample (TorchRL's
# PrioritizedSampler writes it; TorchRL losses weight their mean by it)
STEPS_TO_NEXT_OBS = "steps_to_next_obs"  # [1] int64, frames a buffer-L transition spans (train.n_steps; TorchRL's
# TD(0) estimator discounts its bootstrap by gamma ** this)
