"""The README's code stays true: its transform-reuse example runs as written."""
from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_reuse_example_runs():
    text = README.read_text()
    match = re.search(r"```python\n(import torch\nfrom torchrl.data import Bounded.*?)```", text, re.S)
    assert match, "the README lost its transform-reuse example"
    namespace: dict = {}
    exec(compile(match.group(1), str(README), "exec"), namespace)  # noqa: S102 - our own README
    td = namespace["td"]
    assert td["next", "pred", "key_gaps"].shape == (2, 5, 3, 2)
    assert td["next", "prior", "p_lcgan"].shape == (2, 5, 3)
    assert td["next", "leaders", "history"].shape == (2, 5, 3, 10, 2)  # the env writes none: LeaderHistory keeps it


def test_readme_gives_exactly_two_command_lines_first():
    block = re.search(r"```bash\n(.*?)```", README.read_text(), re.S).group(1).strip().splitlines()
    assert len(block) == 2 and "kddrl_trl.train" in block[0] and "pytest" in block[1]
    ci = (README.parent / ".ci" / "run").read_text()
    assert block[1] in ci  # CI runs the README's test command
