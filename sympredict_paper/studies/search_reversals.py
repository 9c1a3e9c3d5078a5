"""Rank reversals of the kernel search's second-stage candidates between a checkpoint and their full size: the
evidence for the early stop's like-for-like margin (:data:`sympredict.estimators.search.REVERSAL_MARGINS`).

Per system (those of ``search_cost.py``), the default fit with every search candidate fitted to its full size
(``KernelSearch(early_stop=False)``), each second-stage candidate's held-out one-step error recorded at a quarter and
at half of its centres (the prefix of the same fit, scored as the full fit is) and at its full size.  Recorded:

* ``rows``: per second-stage candidate in the search's order, ``start`` (a starting finalist or its narrowed copy;
  otherwise a candidate of the coordinate search), its update, kernels, ``score`` (full size), ``n_centers``,
  ``quarter`` and ``half`` (the checkpoint scores; ``None`` where the fit stopped before);
* ``quarter`` and ``half``, per checkpoint: the rule's comparisons.  Each candidate ``c`` that reached the
  checkpoint is compared with its reference ``r``, the candidate the early stop compares it with: in the coordinate
  search the best candidate so far that reached its full size, for a start the same among its own update's
  candidates (none: no comparison).
  ``won`` lists ``checkpoint(c) / checkpoint(r)`` over the ``c`` that ended better than ``r`` (full size): a margin
  must exceed their maximum, or the rule stops a candidate that would have won; ``lost`` the same ratio over the
  others (a margin below it stops them); ``won_max`` and ``lost_min``; and ``pairs_max``: over every pair of
  second-stage candidates that reached their full size, the largest ``checkpoint(c) / checkpoint(d)`` of a ``c`` that
  ended better than ``d`` (the worst reversal among any two, ``pairs_n`` pairs);
* ``starts_narrowed``: per start that stopped before its full size (too flat: its shapes narrowed next), its ratio to
  its reference at half (``None``: no reference or no half score), its half-size score over the best score of its
  update so far (``half_over_bound``), whether the early stop would have stopped it (``stopped_by_rule``: then it
  would not have been narrowed) and whether a narrowed copy became its update's best: the evidence on whether a start
  clearly losing at half may be stopped;
* ``rule``: the early stop replayed on these rows with the library's factors (both comparisons): the candidates it
  stops, those of them that would have won (``won``: none may), and the fit seconds they took here.

``max``: over the systems, the largest ``won_max`` and ``pairs_max`` per checkpoint.

Run:  python sympredict_paper/studies/search_reversals.py --systems three_body readme_pendulum kepler henon_heiles \
          coupled_pendulums noisy_pendulum --json docs/data/search_reversals.json
      python sympredict_paper/studies/search_reversals.py --systems three_body --traj 300 \
          --json docs/data/search_reversals_300.json
One BLAS and one numba thread.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from search_cost import _Recorder, add_case_arguments, make_case, recorded_fit

from sympredict.estimators.search import EARLY_STOP_MARGINS, REVERSAL_MARGINS

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "data" / "search_reversals.json"
CHECKPOINTS = (("quarter", 0.25), ("half", 0.5))


def _finite(x) -> bool:
    return x is not None and bool(np.isfinite(x))


def second_stage_rows(name: str, case: dict) -> tuple:
    """``(rows, m_final, choice)``: the second stage's candidates of the default search with every candidate at full
    size, with their checkpoint scores."""
    recorder = _Recorder(margins=tuple((f, np.inf) for _, f in CHECKPOINTS))
    model = recorded_fit(case, recorder)
    search = model.search_
    later = [r for r in search.table if r.get("stage") in (2, 3, 4)]
    assert len(later) == len(recorder.history), "one recorded candidate per row of stages 2 to 4"
    m = search.m_final
    rows = []
    for row, scores in zip(later, recorder.history):
        if row["stage"] != 2:
            continue
        out = {
            "start": bool(row.get("start", False)),
            "update": row["update"],
            "kernels": row["kernels"],
            "ratio": float(row["ratio"]),
            "score": float(row["score"]),
            "n_centers": int(row["n_centers"]),
            "fit_s": float(row["fit_s"]),
        }
        for key, fraction in CHECKPOINTS:
            value = scores.get(int(fraction * m))
            out[key] = float(value) if value is not None else None
        rows.append(out)
    return rows, m, {k: repr(v) for k, v in model.choice_.items()}


def references(rows: list, m_final: int) -> list:
    """Per row, the index of the candidate the early stop compares it with (``None``: none yet): in the coordinate
    search the best candidate so far that reached ``m_final`` centres; for a start the same among its own update's.
    Ties go to the earlier candidate, as in the search."""
    out = []
    for i, row in enumerate(rows):
        pool = [
            j
            for j in range(i)
            if _finite(rows[j]["score"])
            and rows[j]["n_centers"] >= m_final
            and (not row["start"] or rows[j]["update"] == row["update"])
        ]
        out.append(min(pool, key=lambda j: (rows[j]["score"], j)) if pool else None)
    return out


def reversals(rows: list, m_final: int) -> dict:
    """The rule's comparisons (``reversal``), every pair's worst reversal (``pairs``) and the narrowed starts."""
    refs = references(rows, m_final)
    full = [r["n_centers"] >= m_final and _finite(r["score"]) for r in rows]
    out = {}
    for key, _ in CHECKPOINTS:
        won, lost = [], []
        for i, (row, j) in enumerate(zip(rows, refs)):
            if j is None or not _finite(row[key]) or not _finite(rows[j][key]) or rows[j][key] <= 0:
                continue
            ratio = row[key] / rows[j][key]
            entry = {"row": i, "reference": j, "ratio": ratio, "start": row["start"]}
            (won if _finite(row["score"]) and row["score"] < rows[j]["score"] else lost).append(entry)
        pair = [
            rows[c][key] / rows[d][key]
            for c in range(len(rows))
            for d in range(len(rows))
            if full[c]
            and full[d]
            and rows[c]["score"] < rows[d]["score"]
            and _finite(rows[c][key])
            and _finite(rows[d][key])
            and rows[d][key] > 0
        ]
        out[key] = {
            "won": won,
            "lost": lost,
            "won_max": max((e["ratio"] for e in won), default=None),
            "lost_min": min((e["ratio"] for e in lost), default=None),
            "pairs_max": max(pair, default=None),
            "pairs_n": len(pair),
        }
    stops = stopped_by_rule(rows, m_final)
    narrowed = []
    for i, row in enumerate(rows):
        if not row["start"] or row["n_centers"] >= m_final or not _finite(row["score"]):
            continue
        j = refs[i]
        ratio = (
            row["half"] / rows[j]["half"]
            if j is not None and _finite(row["half"]) and _finite(rows[j]["half"])
            else None
        )
        later = [k for k in range(i + 1, len(rows)) if rows[k]["start"] and rows[k]["update"] == row["update"]]
        best = min(
            (k for k in range(len(rows)) if rows[k]["update"] == row["update"] and _finite(rows[k]["score"])),
            key=lambda k: (rows[k]["score"], k),
        )
        narrowed.append(
            {
                "row": i,
                "half_ratio": ratio,
                "half_over_bound": (
                    row["half"] / stops["bounds"][i] if _finite(row["half"]) and _finite(stops["bounds"][i]) else None
                ),
                "stopped_by_rule": i in stops["rows"],
                "narrowed_copy_best_of_update": best in later,
            }
        )
    out["starts_narrowed"] = narrowed
    out["rule"] = stops
    return out


def stopped_by_rule(rows: list, m_final: int) -> dict:
    """The candidates the search's early stop (both comparisons, the library's factors) would stop at half their
    centres, replayed on the full-size run: ``rows`` (indices), ``won`` (those of them that ended better than the best
    score so far they were compared with: a stop that would change the search; must be empty), ``bounds`` (per row,
    that best score so far, ``inf`` for none) and ``seconds`` (the run's fit seconds of the stopped candidates)."""
    ((fraction, factor),), ((r_fraction, r_factor),) = EARLY_STOP_MARGINS, REVERSAL_MARGINS
    assert fraction == r_fraction == 0.5, "the rows record the half-size checkpoint"
    refs, bounds, stopped, won = references(rows, m_final), [], [], []
    for i, row in enumerate(rows):
        pool = [
            rows[j]["score"]
            for j in range(i)
            if _finite(rows[j]["score"]) and (not row["start"] or rows[j]["update"] == row["update"])
        ]
        bound = min(pool) if pool else float("inf")
        bounds.append(bound)
        j, half = refs[i], row["half"]
        by_bound = _finite(half) and np.isfinite(bound) and half > factor * bound
        like = _finite(half) and j is not None and _finite(rows[j]["half"]) and half > r_factor * rows[j]["half"]
        if by_bound or like:
            stopped.append(i)
            if _finite(row["score"]) and row["score"] < bound:
                won.append(i)
    return {"rows": stopped, "won": won, "bounds": bounds, "seconds": sum(rows[i]["fit_s"] for i in stopped)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_arguments(parser)
    _protocol.add_arguments(parser, threads=1, json_default=str(RESULTS))
    args = parser.parse_args(argv)
    with _protocol.limits(args.blas_threads, args.threads):
        protocol = _protocol.record_options(args, repeats=1, warmup=0, notes="one fit per system")
        out = []
        for name in args.systems:
            rows, m_final, choice = second_stage_rows(name, make_case(name, args))
            result = {"system": name, "m_final": m_final, "rows": rows, **reversals(rows, m_final), "choice": choice}
            summary = {k: {q: result[k][q] for q in ("won_max", "lost_min", "pairs_max")} for k, _ in CHECKPOINTS}
            print(f"  {name}: {summary}; narrowed starts {result['starts_narrowed']}", flush=True)
            out.append(result)
            maxima = {
                key: {
                    q: max((r[key][q] for r in out if r[key][q] is not None), default=None)
                    for q in ("won_max", "pairs_max")
                }
                for key, _ in CHECKPOINTS
            }
            _protocol.write_json(
                args.json,
                {"settings": {k: v for k, v in vars(args).items() if k != "json"}, "rows": out, "max": maxima},
                protocol,
            )
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
