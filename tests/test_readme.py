"""The README's and the guide's code stays true: the two set-up commands are CI's, the README is a hand-written front
door whose figures are the guide's, the guide's verdict table is the report's, and the transform-reuse example of
docs/reuse.md runs as written."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
REUSE = ROOT / "docs" / "reuse.md"


def test_reuse_example_runs():
    text = REUSE.read_text()
    match = re.search(r"```python\n(import torch\nfrom torchrl.data import Bounded.*?)```", text, re.S)
    assert match, "docs/reuse.md lost its transform-reuse example"
    namespace: dict = {}
    exec(compile(match.group(1), str(REUSE), "exec"), namespace)  # noqa: S102 - our own guide
    td = namespace["td"]
    assert td["next", "pred", "key_gaps"].shape == (2, 5, 3, 2)
    assert td["next", "prior", "p_lcgan"].shape == (2, 5, 3)
    assert td["next", "leaders", "history"].shape == (2, 5, 3, 10, 2)  # the env writes none: LeaderHistory keeps it


def test_readme_gives_exactly_two_command_lines_first():
    block = re.search(r"```bash\n(.*?)```", README.read_text(), re.S).group(1).strip().splitlines()
    assert len(block) == 2 and "kddrl_trl.train" in block[0] and "pytest" in block[1]
    ci = (README.parent / ".ci" / "run").read_text()
    assert block[1] in ci  # CI runs the README's test command


def test_readme_is_a_front_door():
    """At most 120 lines, written by hand (no generated block), no line over 120 characters but the two set-up
    commands (kept whole, as CI runs them), and every relative link (pictures included) points to a file that
    exists."""
    text = README.read_text()
    commands = re.search(r"```bash\n(.*?)```", text, re.S).group(1).splitlines()
    assert len(text.splitlines()) <= 120
    assert max(len(line) for line in text.splitlines() if line not in commands) <= 120
    assert "| # | claim |" not in text and "<!--" not in text
    for target in re.findall(r"\]\(([^)#]+)\)", text):
        if not target.startswith("http"):
            assert (ROOT / target).exists(), target


def test_the_readme_results_are_the_guides_tested_figures():
    """Each interval and each percentage of the README's results is on the guide's home page, whose tables are the
    committed reports' and runs' (the two tests below): the front door states no figure of its own."""
    text = README.read_text()
    results = text[text.index("## Results") : text.index("## Everyday commands")]
    figures = re.findall(r"\[-?\d+\.\d+, -?\d+\.\d+\]|\d+(?:\.\d+)?(?:-\d+)? %", results)
    assert len(figures) >= 5
    home = (ROOT / "docs" / "index.md").read_text()
    for figure in figures:
        assert figure in home, figure


def test_conf_at_the_root_is_the_package_conf():
    """``conf/`` at the repository root (where a Hydra user looks) is the package's config folder itself, one copy."""
    root_conf = ROOT / "conf"
    assert root_conf.is_symlink() and root_conf.resolve() == (ROOT / "src" / "kddrl_trl" / "conf").resolve()
    assert (root_conf / "config.yaml").is_file() and (root_conf / "algo" / "kddrl.yaml").is_file()


def test_citation_names_the_paper():
    text = (ROOT / "CITATION.cff").read_text()
    assert "cff-version" in text and "Knowledge-Data-Dual-Driven Reinforcement Learning" in text


def test_one_version_everywhere():
    """``__version__`` is the installed package's (pyproject.toml), and the citation and the changelog name it."""
    import tomllib

    import kddrl_trl

    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert kddrl_trl.__version__ == version
    assert f"\nversion: {version}\n" in (ROOT / "CITATION.cff").read_text()
    assert f"## {version} (" in (ROOT / "CHANGELOG.md").read_text()
    assert (ROOT / "src" / "kddrl_trl" / "py.typed").is_file()


def test_the_guides_verdict_table_is_the_reports():
    """The guide home page's short verdict table is the "In short" table of the committed verdict report
    (:func:`kddrl_trl.reporting.sections.claims_summary` of ``studies/paper/report.json``, with the claims file's
    names): a regenerated report that changes a claim fails here until the page follows."""
    import json

    from kddrl_trl.reporting.claims import load_claims
    from kddrl_trl.reporting.sections import claims_summary

    report = json.loads((ROOT / "studies" / "paper" / "report.json").read_text())
    summary = claims_summary(report["claims"], load_claims(ROOT / "studies" / "paper" / "claims.yaml").names)
    assert summary in (ROOT / "docs" / "index.md").read_text()
    assert summary in (ROOT / "studies" / "paper" / "report.md").read_text()


def test_the_preset_confirmation_tables_are_the_runs(tmp_path):
    """The guide home page's safety table and studies/paper/README.md's confirmation table are ``studies/paper/confirmation.py``'s
    output on the committed run records: a run that lands and changes a row fails here until the prose follows."""
    from testkit import study_records

    from studies.paper import confirmation

    studies = study_records(
        tmp_path, "studies/paper/runs", "studies/paper/runs_5-14", "studies/ablation/runs", "studies/reproduction/runs"
    )
    assert confirmation.safety_table(studies) in (ROOT / "docs" / "index.md").read_text()
    assert confirmation.table(studies) in (ROOT / "studies" / "paper" / "README.md").read_text()
