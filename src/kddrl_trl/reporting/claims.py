"""A study's planned claims, read from its claims file (``studies/paper/claims.yaml`` is the verdict study's): which
comparisons its analysis plan fixed, on which confirmatory seeds, at which commit. The file is study data; the
library holds only the claim type and the tests (:mod:`kddrl_trl.reporting.verdict`).

The file (YAML), every key required but ``title``, ``pilot_seeds``, ``paper_runs``, ``names`` and ``secondary``::

    title: The paper's claims        # the report's heading of its claims section (default "The claims")
    plan: studies/paper/plan.md      # the analysis plan the claims come from
    plan_commit: "0123abc"           # the commit that fixed it
    test_seeds: [5, 6, ...]          # the confirmatory seeds: the primary test reads these and no others
    pilot_seeds: [0, 1, 2, 3, 4]     # seeds run before the plan: described with the rest, never tested
    paper_runs: [1, 3]               # the size question again, the paper's difference read as 1 and 3 runs
    names: {kddrl: KDDRL, ...}       # short names for the summary table
    primary:                         # the primary family: tested once, Holm over the family
      - {id: P1, table: II, scenario: baseline, metric: mean_speed_kmh, a: kddrl, b: ni, claimed: greater}
    secondary: [...]                 # described, never tested

A claim reads: ``a``'s ``metric`` is ``claimed`` (``greater`` or ``less``) than ``b``'s on ``scenario``; ``paired:
true`` tests it on paired seeds. A malformed file is refused with its path and the key at fault.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .metrics import METRICS

#: how a claim reads, by (metric, direction); any other pair reads "has a higher / lower <metric> than"
VERB = {
    ("mean_speed_kmh", "greater"): "drives faster than",
    ("mean_speed_kmh", "less"): "drives slower than",
    ("collision_rate", "less"): "collides less than",
    ("collision_rate", "greater"): "collides more than",
    ("lane_changes_per_episode", "greater"): "changes lanes more often than",
    ("lane_changes_per_episode", "less"): "changes lanes less often than",
    ("mean_accel", "greater"): "accelerates more on average than",
    ("frame_accel_sd", "less"): "has a narrower acceleration spread than",
}
#: what a metric counts, in a sentence ("the paired t-test for braking collisions")
NOUN = {"collision_rate": "collisions", "mean_speed_kmh": "speeds"}
DIRECTIONS = ("greater", "less")
_CLAIM_KEYS = ("id", "table", "scenario", "metric", "a", "b", "claimed")


@dataclass(frozen=True)
class Claim:
    """``a``'s ``metric`` is ``claimed`` (``"greater"`` or ``"less"``) than ``b``'s on ``scenario``; ``paired``:
    tested on paired seeds (the plan's choice, from the pilot's correlation)."""

    id: str
    table: str
    scenario: str
    metric: str
    a: str
    b: str
    claimed: str
    family: str = "secondary"
    paired: bool = False

    @property
    def text(self) -> str:
        verb = VERB.get((self.metric, self.claimed))
        if verb is None:
            verb = f"has a {'higher' if self.claimed == 'greater' else 'lower'} {METRICS[self.metric][0]} than"
        return f"Table {self.table}: {self.a} {verb} {self.b}"


@dataclass(frozen=True)
class ClaimPlan:
    """A claims file, read: its claims (the primary family first, in the file's order) and the plan's facts."""

    source: Path
    plan: str
    plan_commit: str
    test_seeds: tuple[int, ...]
    claims: tuple[Claim, ...]
    title: str = "The claims"
    pilot_seeds: tuple[int, ...] = ()
    paper_runs: tuple[int, ...] = (1, 3)
    names: dict[str, str] = field(default_factory=dict)

    @property
    def primary(self) -> tuple[Claim, ...]:
        return tuple(c for c in self.claims if c.family == "primary")

    @property
    def secondary(self) -> tuple[Claim, ...]:
        return tuple(c for c in self.claims if c.family != "primary")


def load_claims(path: str | Path) -> ClaimPlan:
    """The claims file at ``path`` (module docstring); ``SystemExit`` naming the file and the key at fault."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise SystemExit(f"claims={path}: no such file")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise SystemExit(f"{path}: not YAML ({err})") from None
    if not isinstance(data, dict):
        raise SystemExit(f"{path}: a mapping of plan, plan_commit, test_seeds, primary, ... expected")
    known = {"title", "plan", "plan_commit", "test_seeds", "pilot_seeds", "paper_runs", "names", "primary", "secondary"}
    for key in sorted(set(data) - known):
        raise SystemExit(f"{path}: unknown key {key!r} (known: {', '.join(sorted(known))})")
    for key in ("plan", "plan_commit", "test_seeds", "primary"):
        if not data.get(key):
            raise SystemExit(f"{path}: key {key!r} missing or empty")
    claims = [_claim(path, "primary", i, c) for i, c in enumerate(data["primary"])]
    claims += [_claim(path, "secondary", i, c) for i, c in enumerate(data.get("secondary") or [])]
    ids = [c.id for c in claims]
    for dup in sorted({i for i in ids if ids.count(i) > 1}):
        raise SystemExit(f"{path}: claim id {dup!r} given twice")
    return ClaimPlan(
        source=path,
        plan=str(data["plan"]),
        title=str(data.get("title") or "The claims"),
        plan_commit=str(data["plan_commit"]),
        test_seeds=_seeds(path, "test_seeds", data["test_seeds"]),
        pilot_seeds=_seeds(path, "pilot_seeds", data.get("pilot_seeds") or []),
        paper_runs=_seeds(path, "paper_runs", data.get("paper_runs", [1, 3])),
        names={str(k): str(v) for k, v in (data.get("names") or {}).items()},
        claims=tuple(claims),
    )


def _seeds(path: Path, key: str, value) -> tuple[int, ...]:
    if not isinstance(value, list) or not all(isinstance(s, int) and not isinstance(s, bool) for s in value):
        raise SystemExit(f"{path}: {key} must be a list of integers, got {value!r}")
    if len(set(value)) != len(value):
        raise SystemExit(f"{path}: {key} repeats a value: {value!r}")
    return tuple(value)


def _claim(path: Path, family: str, i: int, entry) -> Claim:
    where = f"{path}: {family}[{i}]"
    if not isinstance(entry, dict):
        raise SystemExit(f"{where}: a mapping of {', '.join(_CLAIM_KEYS)} expected, got {entry!r}")
    for key in sorted(set(entry) - {*_CLAIM_KEYS, "paired"}):
        raise SystemExit(f"{where}: unknown key {key!r}")
    for key in _CLAIM_KEYS:
        if entry.get(key) in (None, ""):
            raise SystemExit(f"{where}: key {key!r} missing")
    if entry["metric"] not in METRICS:
        raise SystemExit(f"{where}: metric {entry['metric']!r} is not a report metric ({', '.join(METRICS)})")
    if entry["claimed"] not in DIRECTIONS:
        raise SystemExit(f"{where}: claimed {entry['claimed']!r}, not one of {', '.join(DIRECTIONS)}")
    if not isinstance(entry.get("paired", False), bool):
        raise SystemExit(f"{where}: paired must be true or false, got {entry['paired']!r}")
    return Claim(**{k: str(entry[k]) for k in _CLAIM_KEYS}, family=family, paired=bool(entry.get("paired", False)))
