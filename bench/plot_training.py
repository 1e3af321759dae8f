"""Training curves (the paper's Fig. 5): success and collision rate over training steps.

    python bench/plot_training.py results/runs/*/train_log.csv --out results/training_curves.png

Each curve is a moving average over 100 episodes of one run's train_log.csv (written by
tarl.py). For TARL the first 40 % of the steps are Algorithm 1's step 1, plain SAC.
"""
import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def moving_average(x, n=100):
    """Mean of the last n values (of fewer at the start)."""
    c = np.cumsum(np.insert(np.asarray(x, dtype=float), 0, 0.0))
    i = np.arange(1, len(x) + 1)
    lo = np.maximum(i - n, 0)
    return (c[i] - c[lo]) / (i - lo)


def load(path: Path):
    rows = list(csv.DictReader(open(path)))
    step = np.array([int(r["step"]) for r in rows])
    return step, np.array([int(r["success"]) for r in rows]), np.array([int(r["collision"]) for r in rows])


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("logs", type=Path, nargs="+")
    p.add_argument("--out", type=Path, default=Path("results/training_curves.png"))
    a = p.parse_args()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharex=True)
    for log in a.logs:
        step, success, collision = load(log)
        label = log.parent.name
        axes[0].plot(step, moving_average(success), label=label)
        axes[1].plot(step, moving_average(collision), label=label)
    axes[0].set(title="success rate (100-episode moving average)", xlabel="simulator step", ylim=(0, 1))
    axes[1].set(title="collision rate (100-episode moving average)", xlabel="simulator step", ylim=(0, 1))
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=120)
    print("wrote", a.out)
