"""Draw docs/figures/error_estimate_over_time.png: the error estimate against the true error over a rollout.

Reads the curves that ``sympredict_paper/studies/error_estimate.py`` wrote into ``docs/data/error_estimate.json``
(per system: the median over the test trajectories of the estimate and of the true error at every
kept step, and one trajectory's pair of curves); computes nothing itself.

Run:  python sympredict_paper/figures/error_estimate_figure.py
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

DOCS = Path(__file__).resolve().parents[2] / "docs"
SOURCE = DOCS / "data" / "error_estimate.json"
TARGET = DOCS / "figures" / "error_estimate_over_time.png"


def main() -> Path:
    result = json.loads(SOURCE.read_text())
    systems = {k: v for k, v in result["systems"].items() if "curves" in v}
    fig, axes = plt.subplots(1, len(systems), figsize=(3.6 * len(systems), 3.2), squeeze=False)
    for ax, (name, entry) in zip(axes[0], systems.items()):
        c = entry["curves"]
        t = [k * entry["dt"] for k in c["step"]]
        ax.semilogy(t[1:], c["median_true"][1:], color="C0", label="true error (median)")
        ax.semilogy(t[1:], c["median_estimate"][1:], color="C1", label="estimate (median)")
        ax.semilogy(t[1:], c["example_true"][1:], color="C0", ls=":", lw=1, label="true, one trajectory")
        ax.semilogy(t[1:], c["example_estimate"][1:], color="C1", ls=":", lw=1, label="estimate, one trajectory")
        ax.set_title(name.replace("_", " ") + ("" if entry["held_out"] else " (development system)"), fontsize=9)
        ax.set_xlabel("t")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel(r"$\|x_k - x(t_k)\|_2$")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    TARGET.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(TARGET, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return TARGET


if __name__ == "__main__":
    print(main())
