"""``python -m kddrl_trl.report <run or sweep folders ...> [out=<folder>]``: the reproduction report.

Reads every run under the folders (:func:`kddrl_trl.reporting.records.find_runs`) and writes ``report.md``,
``report.json`` and the figures into ``out`` (:func:`kddrl_trl.reporting.builder.build_report`): the paper's
Tables II-V with across-seed 95 % CIs beside the paper's values, each algo against KDDRL, the collision
breakdown, Figs. 8-17 and a footer of what produced them; with ``claims=<a claims file>``, a study's planned claims
tested (``studies/paper/claims.yaml``: the paper's verdict). Folders given without ``key=`` are passed as
``runs=[...]`` to Hydra.
"""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from . import conf as _conf  # noqa: F401  (registers the typed schemas with Hydra)
from .conf.schema import ReportJob
from .reporting.builder import build_report
from .reporting.claims import load_claims
from .reporting.records import find_runs
from .run_folder import no_folder_if_refused

#: the lcGAN test metrics shipped beside the weights (``generative/shipped.py``), when there are any
SHIPPED_LCGAN_METRICS = Path(__file__).parent / "generative" / "weights" / "lcgan.metrics.json"


def read_lcgan_metrics(path: Path) -> dict | None:
    """Test metrics for Figs. 16-17 from a shipped ``<kind>.metrics.json`` (metrics under ``"test"``) or a
    pretraining run's ``metrics.json``; ``None`` if the file does not exist."""
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    return data["test"] if "test" in data and "dataset_hash" in data else data


def folders_as_override(argv: list[str]) -> list[str]:
    """``a b key=v`` -> ``runs=['a','b'] key=v``: positional folders become Hydra's ``runs`` list."""
    folders = [a for a in argv if "=" not in a and not a.startswith("-")]
    if not folders:
        return argv
    quoted = ",".join("'" + f.replace("\\", "\\\\").replace("'", "\\'") + "'" for f in folders)
    return [f"runs=[{quoted}]"] + [a for a in argv if a not in folders]


@hydra.main(version_base="1.3", config_path="conf", config_name="report")
def main(cfg: DictConfig) -> dict:
    # a refused record (one line naming its file) leaves no empty report folder behind
    with no_folder_if_refused():
        return _report(cfg)


def _report(cfg: DictConfig) -> dict:
    job: ReportJob = OmegaConf.to_object(cfg)
    plan = load_claims(job.claims) if job.claims else None
    metrics_path = Path(job.lcgan_metrics) if job.lcgan_metrics else SHIPPED_LCGAN_METRICS
    lcgan = read_lcgan_metrics(metrics_path)
    if job.lcgan_metrics and lcgan is None:
        raise SystemExit(f"lcgan_metrics={job.lcgan_metrics}: no such file")
    runs = find_runs(job.runs)
    command = "python -m kddrl_trl.report " + " ".join(shlex.quote(r) for r in job.runs) + f" out={job.out}"
    if job.claims:
        command += f" claims={shlex.quote(job.claims)}"
    if job.title:
        command += " " + shlex.quote(f"title={job.title}")
    if not job.lcgan_figures:
        command += " lcgan_figures=false"
        lcgan = False
    if not job.space_time_figures:
        command += " space_time_figures=false"
    result = build_report(
        runs,
        job.out,
        command=command,
        lcgan_metrics=lcgan,
        claims=plan,
        title=job.title,
        space_time_figures=job.space_time_figures,
    )
    print(
        f"{len(runs)} runs -> {Path(job.out) / 'report.md'}, report.json and {sum(1 for v in result['figures'].values() if v)} figures"
    )
    return result


if __name__ == "__main__":
    sys.argv[1:] = folders_as_override(sys.argv[1:])
    main()
