"""The multiplicative coordinate search the accuracy benchmarks share (a script helper, not library code).

Each searched parameter is multiplied and divided by ``factor`` in turn, keeping
any candidate that lowers the score; after a sweep without improvement the
factor's logarithm halves (``2 -> sqrt 2 -> 2^(1/4)``).  ``O(sweeps * 2 *
len(search))`` evaluations of ``score``.
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import numpy as np


def coordinate_search(score: Callable[[list], float], start: Sequence[float], names: Sequence[str],
                      search: Sequence[str], factor: float = 2.0, sweeps: int = 3,
                      start_score: Optional[float] = None, label: str = "") -> tuple[list, float]:
    """Return ``(best parameters, best score)``; ``start_score`` saves the start's evaluation when known."""
    best = [float(v) for v in start]
    best_score = score(best) if start_score is None else start_score
    log_f = np.log(factor)
    for sweep in range(sweeps):
        improved = False
        for name in search:
            i = list(names).index(name)
            for sign in (1, -1):
                cand = list(best)
                cand[i] = float(best[i] * np.exp(sign * log_f))
                value = score(cand)
                if value < best_score:
                    best, best_score, improved = cand, value, True
        print(f"sweep {sweep}: best {label}{dict(zip(names, best))}, score {best_score:.3e} "
              f"(factor {np.exp(log_f):.3f})", flush=True)
        if not improved:
            log_f /= 2
    return best, best_score
