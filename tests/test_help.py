"""Each entry point's ``--help`` is for people (Hydra's ``hydra/help`` template, ``conf/hydra/help/``): a one-line
description, example commands, the groups and keys a newcomer needs, under 60 lines; the full config stays one flag
away (``--cfg job``)."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("entry", ["train", "evaluate", "report", "pretrain"])
def test_help_describes_shows_examples_and_stays_short(entry, tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", f"kddrl_trl.{entry}", "--help"], cwd=tmp_path, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.strip().splitlines()
    assert len(lines) < 60 and lines[0].startswith(f"kddrl_trl.{entry}: ")
    examples = [line for line in lines if line.strip().startswith(f"python -m kddrl_trl.{entry}")]
    assert len(examples) >= 4 and "Examples:" in lines
    assert "Powered by Hydra" not in done.stdout and "--cfg job" in done.stdout
    assert not list(tmp_path.iterdir())  # asking for help leaves nothing behind


def test_train_help_names_the_keys_with_their_defaults_and_not_pretrains_group(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "kddrl_trl.train", "--help"], cwd=tmp_path, capture_output=True, text=True
    ).stdout
    for key in ("seed=0", "episodes=1000", "eval_episodes=1000", "video=false", "torch_threads=auto", "resume=false"):
        assert f"  {key} " in out, key
    assert "gan=" not in out and "SUMO" in out  # env=highway is SUMO, and pretrain's gan group is not train's
