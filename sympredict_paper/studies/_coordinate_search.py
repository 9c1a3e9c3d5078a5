"""The accuracy studies' multiplicative coordinate search, run by the library's one search engine
(:func:`sympredict.estimators.search.coordinate_search`); this module only names the coordinates and prints, and
keeps the scored candidates (:class:`Candidates`) and the command-line options of a study's hand search
(:func:`add_search_arguments`, :func:`quick_search`, :func:`with_overrides`) and runs it with them
(:func:`run_search`).

Each searched parameter is multiplied and divided by ``factor`` in turn, from the best candidate so far, keeping
any candidate that lowers the score; after a sweep without improvement the factor's logarithm halves
(``2 -> sqrt 2 -> 2^(1/4)``, the engine's ``shrink=0.5``) and all ``sweeps`` sweeps run.  At most
``1 + sweeps * 2 * len(search)`` evaluations of ``score``; a candidate that recurs is scored once.
"""

from __future__ import annotations

import argparse
import time
from typing import Callable, Iterable, Optional, Sequence

import numpy as np

from sympredict.estimators.search import coordinate_search as _engine_search


def coordinate_search(
    score: Callable[[list], float],
    start: Sequence[float],
    names: Sequence[str],
    search: Sequence[str],
    factor: float = 2.0,
    sweeps: int = 3,
    start_score: Optional[float] = None,
    label: str = "",
) -> tuple[list, float]:
    """Return ``(best parameters, best score)``; ``start_score`` saves the start's evaluation when known."""
    first = tuple(float(v) for v in start)
    scores = {} if start_score is None else {first: start_score}

    def key(cand: tuple) -> float:
        if cand not in scores:
            scores[cand] = score(list(cand))
        return scores[cand]

    shown = {"best": first, "log_f": np.log(factor)}

    def on_sweep(sweep: int, best: tuple) -> None:
        print(
            f"sweep {sweep}: best {label}{dict(zip(names, best))}, score {scores[best]:.3e} "
            f"(factor {np.exp(shown['log_f']):.3f})",
            flush=True,
        )
        if best == shown["best"]:  # no improvement: the engine's next sweep moves by the shrunk factor
            shown["log_f"] /= 2
        shown["best"] = best

    best = _engine_search(
        first,
        key,
        [list(names).index(n) for n in search],
        lambda v, i, f: v * f,
        factors=(factor, 1.0 / factor),
        sweeps=sweeps,
        from_best=True,
        on_sweep=on_sweep,
        shrink=0.5,
    )
    return list(best), scores[best]


def grid_then_coordinate_search(
    score: Callable[[dict], float],
    base: dict,
    families: Sequence[str],
    updates: Sequence[str],
    names: Sequence[str],
    search: Sequence[str],
    factor: float = 2.0,
    sweeps: int = 3,
    label: str = "",
) -> tuple[dict, float]:
    """An expert's search as the accuracy studies run it: every kernel ``family`` x ``update`` at the start shapes
    ``base``, then :func:`coordinate_search` over the ``search`` coordinates (of ``names``) from the best of them.

    ``score(settings) -> float`` scores a dict of settings (``family``, ``update`` and the ``names``).  Returns
    ``(chosen settings, best score)``."""
    best, best_score = None, np.inf
    for family in families:
        for update in updates:
            cand = dict(base, family=family, update=update)
            s = score(cand)
            if s < best_score:
                best, best_score = cand, s
    if best is None:
        raise RuntimeError(f"{label}every kernel family and update failed at the start shapes {base}")
    vec, best_score = coordinate_search(
        lambda v: score(dict(best, **dict(zip(names, v)))),
        [best[n] for n in names],
        names,
        search,
        factor,
        sweeps,
        start_score=best_score,
        label=label,
    )
    return dict(best, **dict(zip(names, vec))), best_score


def add_search_arguments(
    parser: argparse.ArgumentParser,
    *,
    search_help: str,
    starts: Sequence[str],
    start_default: str,
    start_help: str,
    names: Sequence[str],
    sweeps: int,
    factor: Optional[float] = None,
) -> None:
    """The options of a study's hand search (:func:`grid_then_coordinate_search`).

    ``--search`` (redo the search; ``search_help``), ``--search-start`` (one of ``starts``, default
    ``start_default``), ``--search-families``, ``--search-updates``, ``--search-params`` (the searched coordinates,
    all of ``names`` by default, no others), ``--search-factor`` where ``factor`` is
    given (its default; otherwise the study searches by factors of 2) and ``--search-sweeps`` (default ``sweeps``).
    """
    parser.add_argument("--search", action="store_true", help=search_help)
    parser.add_argument("--search-start", choices=list(starts), default=start_default, help=start_help)
    parser.add_argument("--search-families", nargs="+", default=["imq", "matern52"])
    parser.add_argument("--search-updates", nargs="+", default=["symplectic_euler", "midpoint"])
    parser.add_argument("--search-params", nargs="+", default=list(names), choices=list(names))
    if factor is not None:
        parser.add_argument("--search-factor", type=float, default=factor)
    parser.add_argument("--search-sweeps", type=int, default=sweeps)


def quick_search(args: argparse.Namespace) -> None:
    """The smallest search (``--quick``): one family (IMQ), one update (midpoint), one coordinate (``eps_state``)."""
    args.search_families, args.search_updates, args.search_params = ["imq"], ["midpoint"], ["eps_state"]


def run_search(
    args: argparse.Namespace,
    score: Callable[[dict], float],
    base: dict,
    names: Sequence[str],
    search: Sequence[str],
    factor: float,
    label: str = "",
) -> tuple[dict, float]:
    """:func:`grid_then_coordinate_search` over the families, updates and sweeps of the :func:`add_search_arguments`
    options ``args``, moving the coordinates ``search`` (of ``names``) by ``factor``."""
    return grid_then_coordinate_search(
        score, base, args.search_families, args.search_updates, names, search, factor, args.search_sweeps, label=label
    )


def with_overrides(settings: dict, items: Iterable[str]) -> dict:
    """``settings`` with the command line's ``NAME=VALUE`` items applied (``family`` and ``update`` as strings, every
    other value a float)."""
    out = dict(settings)
    for item in items:
        key, value = item.split("=", 1)
        out[key] = value if key in ("family", "update") else float(value)
    return out


def search_record(base: dict, rows: list, t_start: float, best_score: float, **details) -> dict:
    """The JSON record of a :func:`grid_then_coordinate_search`: ``details`` (what was scored, the split), then its
    start, the number of evaluations, the cost since ``t_start`` (``time.perf_counter``), the best score and every
    row."""
    return {
        **details,
        "start": base,
        "evaluations": len(rows),
        "cost_s": time.perf_counter() - t_start,
        "best_score": float(best_score),
        "candidates": rows,
    }


class Candidates:
    """The candidates an accuracy study scores: each scored once, timed and kept as a row of its JSON.

    ``names``: the parameters' names (a row's ``params``). A candidate whose ``measure`` raises (a fit or a Newton
    solve that fails) is kept with its ``error`` and scores ``inf``: it ranks last.
    """

    def __init__(self, names: Sequence[str]):
        self.names = list(names)
        self.rows: list = []
        self._scores: dict = {}

    def score(self, p: Sequence[float], measure: Callable[[Sequence[float]], dict], **fields) -> float:
        """The score of the parameters ``p``: ``measure(p)``'s ``"score"`` (its other entries go into the row).

        ``fields``: entries that lead the row and tell candidates with equal ``p`` apart (e.g. ``sampling=``);
        their values are printed before the parameters.
        """
        key = tuple(fields.values()) + tuple(round(v, 10) for v in p)
        if key in self._scores:
            return self._scores[key]
        t0 = time.perf_counter()
        params = dict(zip(self.names, p))
        row = {**fields, "params": params}
        try:
            row.update(measure(p))
        except Exception as exc:  # a candidate whose fit or Newton solve fails ranks last
            row.update(error=repr(exc), score=np.inf)
        row["time_s"] = time.perf_counter() - t0
        self.rows.append(row)
        self._scores[key] = row["score"]
        shown = "".join(f"{v} " for v in fields.values())
        print(
            f"  {shown}{params}: score {row['score']:.3e}, {row.get('n_centers')} centres ({row['time_s']:.0f} s)",
            flush=True,
        )
        return row["score"]
