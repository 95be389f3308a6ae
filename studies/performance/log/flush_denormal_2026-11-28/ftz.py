"""A compiled learner loaded with a finished job's state, its TD3 and D3QN updates and a gradient step's optimiser
steps timed over three passes, with the CPU's flush-to-zero mode off or on (set first):
``python ftz.py 0|1 RUN/checkpoints/ep001000.pt`` (or ``fresh`` for a new learner), from the repository root."""

import statistics
import sys
import time
from pathlib import Path

import torch

if sys.argv[1] == "1":
    assert torch.set_flush_denormal(True)
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import train_throughput as tt  # noqa: E402

from kddrl_trl.training import (
    HierarchicalLearner,  # noqa: E402
    base,  # noqa: E402
)


def main() -> None:
    torch.set_num_threads(2)
    torch.manual_seed(0)
    kw, lc_period = tt.learner_kwargs(False)
    rb_cf, rb_lc = tt.sample_batches(4000, 0, HierarchicalLearner(**kw).buffer_keys(), None)
    cf = [rb_cf.sample() for _ in range(400)]
    lc = [rb_lc.sample() for _ in range(100)]
    learner = HierarchicalLearner(**tt.learner_kwargs(True)[0])
    if sys.argv[2] != "fresh":
        learner.load_full_state_dict(torch.load(sys.argv[2], map_location="cpu", weights_only=False)["learner"])
    steps = []
    step_all = base.step_all

    def timed(opts):
        t0 = time.perf_counter()
        step_all(opts)
        steps.append(time.perf_counter() - t0)

    base.step_all = timed
    for _ in range(3):
        steps.clear()
        td3, d3qn, _ = tt.time_updates(learner.update_cf, learner.update_lc, cf, lc, lc_period)
        print(
            f"ftz {sys.argv[1]} TD3 {1e6 * td3:.1f} us  D3QN {1e6 * d3qn:.1f} us  "
            f"step_all median {1e6 * statistics.median(steps):.1f} us",
            flush=True,
        )


if __name__ == "__main__":
    main()
