"""The records a run leaves (``summary.json``, ``eval_episodes.csv``, ``train_episodes.csv``, ``validation.csv``,
``traces/``, also those of its ``eval__<its scenario>__*`` evaluations), found under any run or sweep folder and read
back for the report (:mod:`kddrl_trl.reporting.builder`). Each CSV may also be compressed (``eval_episodes.csv.xz`` or
``.gz``), as the committed studies keep them (:func:`record_file`).

A run folder is any folder holding ``summary.json`` and ``eval_episodes.csv`` (written by
:func:`kddrl_trl.eval.final.write_results`): a single run, a sweep job, or an evaluation of a trained run (whose
``algo`` / ``scenario`` are those of the evaluation). A training run with ``eval_scenarios`` names its final
evaluations (``final_evaluations`` in its ``summary.json``: the folders ``final__<scenario>``), which are read in its
place. A policy evaluated on another scenario than it was trained on (``trained_on`` in the summary) is reported under
the algo name ``"<algo> (trained on <scenario>)"``, never with the runs trained on the scenario it was evaluated on.
Bad or missing files raise, naming the file and column.
"""

from __future__ import annotations

import gzip
import json
import lzma
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..envs.episode_metrics import METRIC_FIELDS
from ..envs.fault import FAULTS
from ..eval.metrics import summarize
from ..run_folder import RunFolder

#: columns every ``eval_episodes.csv`` must hold (EpisodeTracker records)
EPISODE_COLUMNS = (*METRIC_FIELDS, "outcome", "collision_kind", "collision_with")


@dataclass
class RunRecord:
    """One run: where it is, what it ran, its evaluation episodes and (learning algos) its training history."""

    path: Path
    algo: str  # the algo's name, "<name> (trained on <scenario>)" when trained on another scenario
    scenario: str  # the scenario evaluated
    seed: int
    summary: dict
    episodes: pd.DataFrame
    training: pd.DataFrame | None = None
    validation: pd.DataFrame | None = None
    traces: list[Path] = field(default_factory=list)
    #: the folder of the training run behind these records: ``path`` itself, or, for a final evaluation
    #: (``final__<scenario>``), the run folder above it; and that run's summary (its times, ``wall_s`` and
    #: ``training``, are there; {} where the folder above holds none)
    trained: Path | None = None
    trained_summary: dict | None = None

    def __post_init__(self):
        if self.trained is None:  # records of a run folder itself
            self.trained, self.trained_summary = self.path, self.summary

    @property
    def seed_share(self) -> float:
        """This run's share of its training run's clock: 1 for a run alone, 1/N for a seed of a batch of N
        (``seed_batch`` in the training run's summary), whose ``training.elapsed_s`` and ``wall_s`` are the
        batch's shared wall time, so a sum of times over runs counts each batch once."""
        return 1.0 / len((self.trained_summary or {}).get("seed_batch", {}).get("seeds", [None]))

    @property
    def commit(self) -> str:
        """The commit of the code that made the run (its ``summary.json``), or ``"not recorded"``."""
        return str(self.summary.get("commit", "not recorded"))

    def metrics(self) -> dict:
        """The per-run driving metrics of Tables II-V (:func:`~kddrl_trl.eval.summarize` of its episodes)."""
        out = summarize(self.episodes.to_dict("records"))
        out["lane_changes_per_episode"] = out["lane_changes"]
        out["lane_changes_per_1000_episodes"] = 1000.0 * out["lane_changes"]
        out.setdefault("shield_rate", 0.0)  # runs without the shield option have none
        return out


#: compressed forms of a record file: suffix -> how its bytes decompress (pandas reads each by its suffix)
COMPRESSED = {".xz": lzma.decompress, ".gz": gzip.decompress}


def record_file(folder: Path, name: str) -> Path:
    """``folder / name``, or its compressed form ``name + ".xz"`` / ``".gz"`` where only that exists (the committed
    studies keep their CSVs xz-compressed; a run writes them plain). Each is read the same way."""
    plain = folder / name
    packed = [folder / f"{name}{suffix}" for suffix in COMPRESSED if (folder / f"{name}{suffix}").is_file()]
    return packed[0] if not plain.is_file() and packed else plain


def record_bytes(folder: Path, name: str) -> bytes:
    """The content of the record ``name`` in ``folder`` (:func:`record_file`), decompressed: a plain record and its
    compressed form compare equal."""
    path = record_file(folder, name)
    raw = path.read_bytes()
    return COMPRESSED[path.suffix](raw) if path.suffix in COMPRESSED else raw


def _csv(path: Path, required: tuple = ()) -> pd.DataFrame:
    try:
        frame = pd.read_csv(path, keep_default_na=False, na_values=[""])
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: not a readable CSV ({err})") from err
    missing = [c for c in required if c not in frame.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)}")
    if frame.empty:
        raise ValueError(f"{path}: no rows")
    return frame


def read_episodes(episodes_path: Path, summary: dict, summary_path: Path) -> pd.DataFrame:
    """A run's evaluation episodes (``eval_episodes.csv``), checked: as many rows as its ``summary.json`` counts,
    ``collision`` True / False, every numeric column numeric and filled, ``collision_fault`` one of
    :data:`~kddrl_trl.envs.fault.FAULTS` on a collision and empty otherwise. A bad record is refused naming its
    file and column."""
    episodes = _csv(episodes_path, EPISODE_COLUMNS)
    if "episodes" in summary and int(summary["episodes"]) != len(episodes):
        raise ValueError(
            f"{episodes_path}: {len(episodes)} episode rows, but {summary_path} counts {summary['episodes']} "
            "(a record cut short or from another run)"
        )
    episodes["collision"] = (
        episodes["collision"].astype(str).str.lower().map({"true": True, "false": False, "1": True, "0": False})
    )
    if episodes["collision"].isna().any():
        raise ValueError(f"{episodes_path}: column collision holds values other than True / False")
    numeric = [c for c in EPISODE_COLUMNS if c not in ("collision", "outcome", "collision_kind", "collision_with")]
    bad = [c for c in numeric if not pd.api.types.is_numeric_dtype(episodes[c]) or episodes[c].isna().any()]
    if bad:
        raise ValueError(f"{episodes_path}: non-numeric or empty values in column(s) {', '.join(bad)}")
    episodes["collision_with"] = (
        episodes["collision_with"].astype(object).where(episodes["collision_with"].notna(), "").astype(str)
    )
    if "collision_fault" in episodes.columns:  # records made before the fault class lack the column
        fault = episodes["collision_fault"].astype(object).where(episodes["collision_fault"].notna(), "").astype(str)
        odd = sorted(set(fault[episodes["collision"]]) - set(FAULTS)) + sorted(
            set(fault[~episodes["collision"]]) - {""}
        )
        if odd:
            raise ValueError(
                f"{episodes_path}: column collision_fault holds {', '.join(map(repr, odd))} (a collision's class is "
                f"one of {', '.join(FAULTS)}; an episode without one has none)"
            )
        episodes["collision_fault"] = fault
    return episodes


def load_run(path: str | Path) -> RunRecord:
    """Read the run folder ``path``."""
    path = Path(path)
    summary_path = RunFolder(path).summary
    summary = _read_summary(summary_path)
    for key in ("algo", "scenario", "seed"):
        if key not in summary:
            raise ValueError(f"{summary_path}: no {key!r} key")
    episodes = read_episodes(record_file(path, RunFolder.EVAL_EPISODES), summary, summary_path)
    trained = path.parent if summary.get("final") else path  # a final__<scenario> folder: its run's training
    training_path = record_file(trained, RunFolder.TRAIN_EPISODES)
    validation_path = record_file(trained, RunFolder.VALIDATION)
    training = _csv(training_path, ("return_lc", "return_cf")) if training_path.is_file() else None
    validation = _csv(validation_path) if validation_path.is_file() else None
    # traces of its final evaluation, and of later evaluations of it on its own scenario (evaluate video=true)
    traces = sorted((path / "traces").glob("*.json")) + sorted(
        path.glob(f"eval__{summary['scenario']}__*/traces/*.json")
    )
    # the options it ran with: its training run's config (an evaluation folder of kddrl_trl.evaluate: its run's)
    config = _config(RunFolder(path.parent if path.name.startswith("eval__") else trained).config)
    label = algo_label(summary, config)
    if path.name.startswith("eval__"):  # evaluated in traffic set otherwise than its training's: a row of its own
        changed = evaluation_label(_config(path / ".hydra" / "config.yaml"), config)
        label = f"{label} [evaluated with {changed}]" if changed else label
    trained_summary = (
        summary
        if trained == path
        else _read_summary(RunFolder(trained).summary)
        if RunFolder(trained).is_finished()
        else {}
    )
    return RunRecord(
        path,
        label,
        str(summary["scenario"]),
        int(summary["seed"]),
        summary,
        episodes,
        training,
        validation,
        traces,
        trained,
        trained_summary,
    )


def _read_summary(summary_path: Path) -> dict:
    """A ``summary.json``, or a ``ValueError`` naming the file."""
    try:
        return json.loads(summary_path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"{summary_path}: not a readable summary ({err})") from err


def _config(path: Path) -> dict | None:
    """A run's ``config.yaml`` (None where there is none: an evaluation folder, records without it)."""
    if not path.is_file():
        return None
    from omegaconf import OmegaConf

    try:
        return OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    except Exception as err:
        raise ValueError(f"{path}: not a readable config ({err})") from err


#: the options that make a run a row of its own in the report when they differ from its algo's defaults
#: (not ``episodes``: short smoke and test sweeps would all be rows of their own); ``collector.sync``: the overlapped
#: collection acts one batch behind, so what a run learns may differ
OPTION_KEYS = (
    "env.reward",
    "env.ego_start",
    "algo.mobil_safety_mask",
    "algo.lc_reward",
    "algo.shield",
    "algo.shield_ttc",
    "algo.shield_penalty",
    "algo.shield_buffer",
    "algo.state_extras",
    "algo.transforms.weights",
    "algo.transforms.event_oracle",
    "env.highwayenv.ego_driver",
    "algo.learner.d3qn.semi_mdp",
    "algo.learner.d3qn.eps_decisions",
    "algo.learner.td3.exploration_clip",
    "train.n_steps",
    "train.updates_per_decision",
    "train.prioritized",
    "train.priority_alpha",
    "train.priority_beta",
    "collector.sync",
    "matmul_precision",
)


def _dotted(cfg: dict, key: str):
    for part in key.split("."):
        if not isinstance(cfg, dict) or part not in cfg:
            return _MISSING
        cfg = cfg[part]
    return cfg


_MISSING = object()
_DEFAULTS: dict[tuple[str, str, str], dict] = {}


def default_config(algo: str, scenario: str, simulator: str = "sumo") -> dict:
    """The package's composed config of ``algo=<algo> +scenario=<scenario>`` (resolved; cached): what a run of
    that algo and scenario runs with when no option is set. On another ``simulator`` (its env node
    ``env=<simulator>``) the scenario is that simulator's label (:func:`kddrl_trl.highway_config.scenario_label`:
    ``<simulator>`` or ``<simulator>_<preset>``)."""
    if (algo, scenario, simulator) not in _DEFAULTS:
        from hydra import compose, initialize_config_module
        from hydra.core.global_hydra import GlobalHydra
        from omegaconf import OmegaConf

        from ..highway_config import preset_name

        preset = scenario if simulator == "sumo" else preset_name(scenario) or "baseline"
        env = [f"env={simulator}"] if simulator != "sumo" else []
        overrides = [f"algo={algo}", *env] + ([f"+scenario={preset}"] if preset != "baseline" else [])
        if GlobalHydra.instance().is_initialized():  # inside an entry point (kddrl_trl.report): its config module
            cfg = compose(config_name="config", overrides=overrides)
        else:
            with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
                cfg = compose(config_name="config", overrides=overrides)
        _DEFAULTS[(algo, scenario, simulator)] = OmegaConf.to_container(cfg, resolve=True)
    return _DEFAULTS[(algo, scenario, simulator)]


def option_label(config: dict, algo: str, scenario: str) -> str:
    """``key=value, ...`` of the :data:`OPTION_KEYS` a run's ``config`` sets otherwise than its algo's defaults on
    its training ``scenario`` (keys a run's config lacks, saved before they existed, ran as the paper; keys
    the package no longer has are left out)."""
    simulator = _dotted(config, "env.simulator")
    try:
        defaults = default_config(algo, scenario, "sumo" if simulator is _MISSING else str(simulator))
    except Exception:  # an algo or scenario this package does not know: nothing to compare with
        return ""
    diffs = []
    for key in OPTION_KEYS:
        value, default = _dotted(config, key), _dotted(defaults, key)
        if value is not _MISSING and default is not _MISSING and value != default:
            shown = "[" + ",".join(map(str, value)) + "]" if isinstance(value, list) else value
            diffs.append(f"{key}={shown}")
    return ", ".join(diffs)


#: traffic keys an evaluation (``kddrl_trl.evaluate``) may set otherwise than the training did
EVALUATION_KEYS = ("env.braking.release", "env.braking.resume_accel", "env.braking.stand_time", "env.braking.decel")


def evaluation_label(evaluation: dict | None, training: dict | None) -> str:
    """``key=value, ...`` of the :data:`EVALUATION_KEYS` an evaluation's own config sets otherwise than its
    training run's (a key the training config lacks, saved before it existed, ran as its default today)."""
    if not evaluation:
        return ""
    from ..highway_config import BrakingEvent

    defaults = {f"env.braking.{k}": v for k, v in vars(BrakingEvent()).items()}
    diffs = []
    for key in EVALUATION_KEYS:
        value = _dotted(evaluation, key)
        trained = _dotted(training or {}, key)
        trained = defaults.get(key, _MISSING) if trained is _MISSING else trained
        if value is not _MISSING and value != trained:
            diffs.append(f"{key}={value}")
    return ", ".join(diffs)


def algo_label(summary: dict, config: dict | None = None) -> str:
    """The report's name of a run's policy: its algo, then the options its ``config`` (the run's ``config.yaml``)
    sets otherwise than the algo's defaults (:func:`option_label`, e.g. ``kddrl [train.n_steps=3]``: a row of its
    own), with the training scenario where that is not the scenario evaluated (``trained_on``:
    ``kddrl_trl.evaluate``, ``kddrl_trl.train eval_scenarios=...``)."""
    algo, trained_on = str(summary["algo"]), str(summary.get("trained_on", summary["scenario"]))
    options = option_label(config, algo, trained_on) if config else ""
    name = f"{algo} [{options}]" if options else algo
    return name if trained_on == str(summary["scenario"]) else f"{name} (trained on {trained_on})"


def _expand(summary_path: Path) -> list[Path]:
    """A run folder's evaluation folders: itself, or the ``final_evaluations`` its summary names."""
    finals = _read_summary(summary_path).get("final_evaluations")
    if not finals:
        return [summary_path.parent]
    return [summary_path.parent / name for name in finals]


def find_runs(paths) -> list[RunRecord]:
    """Every run folder at or under ``paths`` (run folders, sweep folders, or folders of those), sorted by
    (scenario, algo, seed). Evaluations inside a training run (``eval__*``, ``kddrl_trl.evaluate``) are left out
    unless named themselves in ``paths``; a training run's final evaluations (``final__*``) are its records. Raises
    if a path does not exist or holds no run."""
    found: dict[Path, RunRecord] = {}
    for p in map(Path, paths):
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such run or sweep folder")
        summaries = (
            [RunFolder(p).summary]
            if RunFolder(p).is_finished()
            else [s for s in sorted(p.rglob(RunFolder.SUMMARY)) if not s.parent.name.startswith("eval__")]
        )
        if not summaries:
            raise FileNotFoundError(f"{p}: holds no run (no {RunFolder.SUMMARY} at or under it)")
        for s in summaries:
            for folder in _expand(s):
                if folder.resolve() not in found:
                    found[folder.resolve()] = load_run(folder)
    runs = sorted(found.values(), key=lambda r: (r.scenario, r.algo, r.seed, str(r.path)))
    seen: dict[tuple, Path] = {}
    for r in runs:
        key = (r.scenario, r.algo, r.seed)
        if key in seen:
            raise ValueError(
                f"two runs of {r.algo} on {r.scenario} with seed {r.seed}: {seen[key]} and {r.path}; "
                "pass only one of them"
            )
        seen[key] = r.path
    return runs
