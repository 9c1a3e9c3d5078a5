"""Redraw the committed figures whose data a run's results.json keeps, in the package's figure style.

    .venv/bin/python tools/redraw_figures.py docs/data/quick_run.json docs/figures

The speed-against-accuracy charts (pendulum, wave) and the pendulum stability sweeps are drawn
from the summaries in ``results.json`` alone, so a change of style needs no new run; the other
figures need the run's models and trajectories (``sympredict-paper run all --quick``, then
``python sympredict_paper/figures/collect_figures.py``).  Only the PNGs are written (the docs show those).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from sympredict_paper import plotting, report


def redraw(results_json, out) -> list[str]:
    r = json.loads(Path(results_json).read_text())
    r = r.get("results", r)
    figures = {}
    sa = r["pendulum"]["speed_accuracy"]
    figures.update(
        report.speed_accuracy_figure(sa, "pendulum_speed_accuracy", f"Pendulum: speed against accuracy, dT={sa['dt']}")
    )
    figures.update(report.stability_figures(r["pendulum"]["stability"]))
    sa = r["wave"]["speed_accuracy"]
    figures.update(
        report.speed_accuracy_figure(sa, "wave_speed_accuracy", f"Wave: FOM vs ROM vs ROM + kernel, dT={sa['dt']}")
    )
    written = []
    for name, fig in figures.items():
        fig.savefig(Path(out) / f"{name}.png", dpi=150, bbox_inches="tight")
        plotting.plt.close(fig)
        written.append(f"{name}.png")
    return written


if __name__ == "__main__":
    print("wrote", ", ".join(redraw(sys.argv[1], sys.argv[2])))
