"""The live view (``gui=true``, Gymnasium's ``render_mode="human"``): the simulation runs in sumo-gui under a virtual
display (Xvfb), its window follows the ego, and what it records is what the same job records without it."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

pytestmark = [
    pytest.mark.gui,
    pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="no xvfb-run here (Debian's xvfb package)"),
]

JOB = ["algo=idm_mobil", "eval_episodes=2", "env.num_roads=1", "compile=false", "progress=false"]


def _xvfb(args, cwd, timeout=600):
    return subprocess.run(
        ["xvfb-run", "-a", "-s", "-screen 0 1280x800x24", sys.executable, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_gui_true_drives_sumo_gui_and_records_what_the_headless_job_records(tmp_path):
    live = _xvfb(["-m", "kddrl_trl.train", *JOB, "gui=true", f"hydra.run.dir={tmp_path / 'live'}"], tmp_path)
    assert live.returncode == 0, live.stderr[-3000:]
    assert "gui: sumo-gui (over TraCI) follows road 0's ego in real time" in live.stdout + live.stderr
    bare = subprocess.run(
        [sys.executable, "-m", "kddrl_trl.train", *JOB, f"hydra.run.dir={tmp_path / 'bare'}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert bare.returncode == 0, bare.stderr[-3000:]
    assert (tmp_path / "live" / "eval_episodes.csv").read_bytes() == (
        tmp_path / "bare" / "eval_episodes.csv"
    ).read_bytes()


GYM = """
import numpy as np
from kddrl_trl.envs.network import GUI_VIEW
from kddrl_trl.envs.observe import _libsumo
from kddrl_trl.gym_env import SumoHighwayGymEnv

if __name__ == "__main__":
    env = SumoHighwayGymEnv(render_mode="human", seed=0, process="here")
    obs, info = env.reset(seed=0)
    for _ in range(20):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert env.render() is None  # the window draws itself
        if terminated or truncated:
            break
    gui = _libsumo().gui
    assert gui.getTrackedVehicle(GUI_VIEW) == env.sim.sim.ego[0], (gui.getTrackedVehicle(GUI_VIEW), env.sim.sim.ego)
    gui.screenshot(GUI_VIEW, "view.png")
    _libsumo().simulationStep()  # sumo-gui writes the screenshot at the next step
    env.close()
    print("tracked the ego")
"""


def test_render_mode_human_follows_the_ego_in_sumo_gui(tmp_path):
    (tmp_path / "live_gym.py").write_text(GYM)
    done = _xvfb(["live_gym.py"], tmp_path)
    assert done.returncode == 0 and "tracked the ego" in done.stdout, done.stderr[-3000:]
    import numpy as np
    from PIL import Image

    view = np.asarray(Image.open(tmp_path / "view.png").convert("RGB")).astype(int)
    red = (view[..., 0] > 200) & (view[..., 1] < 60) & (view[..., 2] < 60)  # the ego is painted red
    assert view.shape[1] >= 1000 and red.sum() > 20, (view.shape, red.sum())
