"""The seed-batch sweeps the study READMEs give (their "as a batch" commands): each splits into the jobs Hydra's
basic sweeper would launch, and every job composes into a valid train job of one batch of the seeds it names, so a
renamed key, a refused option or a batch of a system that cannot batch fails here, not in a user's sweep."""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest
from testkit import compose_job

ROOT = Path(__file__).resolve().parents[1]
#: the studies whose READMEs say how to run more seeds as batches
STUDIES = ("paper", "safety")


def batched_commands(readme: Path) -> list[list[str]]:
    """The ``python -m kddrl_trl.train -m ... seeds=...`` lines of ``readme`` 's bash blocks (continuations
    joined, comments dropped), each as its Hydra arguments."""
    out, block, line = [], False, ""
    for raw in readme.read_text().splitlines():
        if raw.startswith("```"):
            block, line = raw.startswith("```bash"), ""
            continue
        if not block:
            continue
        line += raw.rstrip().removesuffix("\\")
        if raw.rstrip().endswith("\\"):
            continue
        words = shlex.split(line, comments=True)
        line = ""
        if words[:4] == ["python", "-m", "kddrl_trl.train", "-m"] and any(w.startswith("seeds=") for w in words):
            out.append(words[4:])
    return out


def sweep_jobs(arguments: list[str]) -> list[list[str]]:
    """The jobs Hydra's basic sweeper makes of ``arguments`` (the ``hydra`` keys and launcher left out: they choose
    where and how a job runs, not what it computes)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    kept = [a for a in arguments if not a.startswith(("hydra.", "hydra/", "+hydra."))]
    overrides = OverridesParser.create().parse_overrides(kept)
    return [job for batch in BasicSweeper.split_arguments(overrides, None) for job in batch]


@pytest.mark.parametrize("study", STUDIES)
def test_a_study_readme_s_batched_sweeps_compose(study):
    commands = batched_commands(ROOT / "studies" / study / "README.md")
    assert commands, f"studies/{study}/README.md gives no seed-batch sweep"
    for arguments in commands:
        jobs = sweep_jobs(arguments)
        assert len(jobs) >= 1
        for job in jobs:
            composed = compose_job(*job)
            assert composed.seeds and len(composed.seeds) >= 2, f"{job}: not a batch of seeds"
            assert len(set(composed.seeds)) == len(composed.seeds)


def test_the_helpers_read_a_sweep_as_hydra_does(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(
        "```bash\n"
        "python -m kddrl_trl.train -m algo=kddrl,ni \\\n"
        "  'seeds=${kddrl_seeds:3,6}' hydra.sweep.dir=x   # two jobs\n"
        "python -m kddrl_trl.train seed=1\n"
        "```\n"
        "python -m kddrl_trl.train -m seeds=[1,2] (not in a block)\n"
    )
    (arguments,) = batched_commands(readme)
    jobs = sweep_jobs(arguments)
    assert [compose_job(*j).algo.name for j in jobs] == ["kddrl", "ni"]
    assert all(compose_job(*j).seeds == [3, 4, 5] for j in jobs)
