"""Text tables of the generative models' test metrics, beside the paper's figures (§IV.F)."""

from __future__ import annotations

from kddrl_trl.generative.gan_inputs import KEY_STEPS

#: paper §IV.F: trajGAN over the 2 s horizon; lcGAN accuracy and recalls (left, keep, right)
PAPER_TRAJGAN = {"mae": 4.39, "rmse": 5.36}
PAPER_LCGAN = {"accuracy": 0.9813, "recall_left": 0.972, "recall_keep": 0.960, "recall_right": 0.957}


def _trajgan(m: dict) -> str:
    cols = ("mae", "rmse", *(f"{e}_step{s}" for s in KEY_STEPS for e in ("mae", "rmse")))
    last = KEY_STEPS[-1]
    head = f"{'predictor (m)':22s}" + "".join(f"{c:>12s}" for c in cols)
    rows = [head, "-" * len(head)]
    for name, src in (
        ("trajGAN", m),
        ("IDM prior", m.get("idm_prior", {})),
        ("constant velocity", m.get("const_velocity", {})),
    ):
        rows.append(f"{name:22s}" + "".join(f"{src.get(c, float('nan')):12.2f}" for c in cols))
    rows.append(f"{'paper trajGAN':22s}" + f"{PAPER_TRAJGAN['mae']:12.2f}{PAPER_TRAJGAN['rmse']:12.2f}")
    if "min_of_k" in m:
        rows.append(
            f"min over K samples: MAE {m['min_of_k'].get('mae', float('nan')):.2f} m, at step {last} "
            f"{m['min_of_k'].get(f'mae_step{last}', float('nan')):.2f} m; spread at step {last} "
            f"{m.get(f'spread_step{last}', float('nan')):.2f} m"
        )
    for driver, d in m.get("per_driver", {}).items():
        rows.append(
            f"  {driver:12s} n={d.get('n', 0):>7}  MAE@{last} {d.get(f'mae_step{last}', float('nan')):6.2f}  "
            f"IDM {d.get(f'idm_prior_mae_step{last}', float('nan')):6.2f}  min-of-K "
            f"{d.get(f'min_of_k_mae_step{last}', float('nan')):6.2f}  "
            f"spread {d.get(f'spread_step{last}', float('nan')):5.2f}"
        )
    return "\n".join(rows)


def _lcgan(m: dict) -> str:
    cols = ("accuracy", "recall_left", "recall_keep", "recall_right", "balanced_accuracy")
    head = f"{'classifier (%)':22s}" + "".join(f"{c:>18s}" for c in cols)
    rows = [head, "-" * len(head)]
    name = "lcGAN" if m.get("adversarial", True) else "plain classifier"
    for name, src in ((name, m), ("MOBIL (P_MOBIL)", m.get("mobil", {})), ("paper lcGAN", PAPER_LCGAN)):
        rows.append(f"{name:22s}" + "".join(f"{100 * src[c]:18.2f}" if c in src else f"{'':18s}" for c in cols))
    if "n_per_class" in m:
        rows.append(f"test samples per class (left, keep, right): {m['n_per_class']}")
    return "\n".join(rows)


def format_metrics(kind: str, metrics: dict) -> str:
    return {"trajgan": _trajgan, "lcgan": _lcgan}[kind](metrics)
