"""The figure style of the shipped commands: the Agg backend whatever ``MPLBACKEND`` says, one colour per method,
labelled axes, and figures written whole as PNG, PDF and the JSON of the data they show.

``sympredict demo`` draws with it, and so does the paper's package (``sympredict_paper.plotting``).  Imported
only by the commands that plot: the library never imports matplotlib.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

# the figures are drawn with Agg whatever MPLBACKEND says: an invalid value there must not break the import
_MPLBACKEND = os.environ.get("MPLBACKEND")
if _MPLBACKEND is not None:
    os.environ["MPLBACKEND"] = "agg"
try:
    import matplotlib
finally:
    if _MPLBACKEND is not None:
        os.environ["MPLBACKEND"] = _MPLBACKEND

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sympredict.container import atomic_output  # noqa: E402


__all__ = ["plt", "METHOD_COLORS", "method_color", "decorate", "figure_data", "save"]

#: One colour per method on every figure of the package (matched by a keyword of the curve's label, first
#: match wins): the symplectic kernel model is always orange, the reference always black/grey.
METHOD_COLORS = (
    (("reference", "exact", "fom", "full model"), "0.15"),
    (("direct", "non-symplectic", "kernel model of the states"), "tab:green"),
    (("vkoga",), "tab:purple"),
    (("rom + kernel", "kernel rom", "symplectic kernel", "kernel predictor", "kernel model", "kernel"), "tab:orange"),
    (("implicit midpoint", "midpoint"), "tab:blue"),
    (("störmer", "stormer", "verlet"), "tab:cyan"),
    (("yoshida",), "tab:gray"),
    (("kahan",), "tab:olive"),
    (("galerkin", "rom"), "tab:brown"),
    (("deim",), "tab:pink"),
    (("mlp", "sympnet", "neural"), "tab:red"),
)
_OTHER_COLORS = ("darkgoldenrod", "teal", "indigo", "crimson", "slategray")


def method_color(label: str, index: int = 0) -> str:
    """The colour of a method on every figure (:data:`METHOD_COLORS`); others by ``index`` from a spare set."""
    low = str(label).lower()
    for keys, color in METHOD_COLORS:
        if any(k in low for k in keys):
            return color
    return _OTHER_COLORS[index % len(_OTHER_COLORS)]


def decorate(ax, xlabel: str, ylabel: str, title: str, legend_outside: bool = False):
    """Labels (with units), title, grid and legend: the same on every figure."""
    _decorate(ax, xlabel, ylabel, title, legend_outside)


def _decorate(ax, xlabel: str, ylabel: str, title: str, legend_outside: bool = False):
    """Labels, title, grid and legend: the same on every figure."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    if legend_outside:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    else:
        ax.legend(fontsize=8)


def _finite_or_none(values) -> list:
    return [float(v) if math.isfinite(float(v)) else None for v in values]


def figure_data(fig) -> dict:
    """The data a figure shows, as plain lists: per panel its title, axis labels and scales, and every labelled line.

    Returns
    -------
    dict
        ``{"axes": [{"title", "xlabel", "ylabel", "xscale", "yscale", "lines": [{"label", "x", "y"}]}]}``;
        non-finite values become ``None``.  Lines whose label starts with ``_``
        (matplotlib's unlabelled artists) are left out.
    """
    axes = []
    for ax in fig.axes:
        lines = [
            {"label": line.get_label(), "x": _finite_or_none(line.get_xdata()), "y": _finite_or_none(line.get_ydata())}
            for line in ax.get_lines()
            if not line.get_label().startswith("_")
        ]
        axes.append(
            {
                "title": ax.get_title(),
                "xlabel": ax.get_xlabel(),
                "ylabel": ax.get_ylabel(),
                "xscale": ax.get_xscale(),
                "yscale": ax.get_yscale(),
                "lines": lines,
            }
        )
    return {"axes": axes}


def save(fig, out_dir, name: str) -> list[str]:
    """Write ``name.png`` and ``name.pdf`` into ``out_dir``, and the data shown in ``name.json``.

    The JSON file (:func:`figure_data`) lets tests and readers check what a
    figure shows without parsing the image.  Returns the names of the PNG and PDF files.
    """
    out_dir = Path(out_dir)
    names = []
    for ext in ("png", "pdf"):
        with atomic_output(out_dir / f"{name}.{ext}") as fh:  # whole files or none (a full disk, Ctrl-C)
            fig.savefig(fh, format=ext, dpi=150, bbox_inches="tight")
        names.append(f"{name}.{ext}")
    with atomic_output(out_dir / f"{name}.json") as fh:
        fh.write(json.dumps(figure_data(fig)).encode())
    plt.close(fig)
    return names
