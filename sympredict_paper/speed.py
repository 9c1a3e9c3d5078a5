"""One timing harness for every speed-against-accuracy chart (pendulum, wave, Hénon–Heiles).

Every method of a chart is timed in one process on the same batch: one
untimed warm-up run (numba compilation, caches), then the median of
``repeats`` timed runs of the whole batch, divided by the batch size.  Threads
are set deliberately (:func:`deliberate_threads`: BLAS through threadpoolctl
and numba's thread count).  Each row says what the method needs:

* ``"equations"``: the right-hand side ``grad H`` (classical integrators, the micro-step reference);
* ``"reduced operator"``: the projected operator of an intrusive ROM (ROM integrators, the exact propagator);
* ``"only data"``: flow-map samples (kernel predictor, direct kernel model, VKOGA).
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np
from threadpoolctl import threadpool_limits

from sympredict.symplectic.integrators_compiled import EXPLICIT_SCHEMES, HAVE_NUMBA, rollout

if HAVE_NUMBA:  # pragma: no branch
    import numba
from sympredict.symplectic.metrics import relative_trajectory_error
from sympredict.estimators.predictor import newton_predictor

__all__ = ["model_sizes", "NEEDS", "SCHEME_LABELS", "deliberate_threads", "time_median", "SpeedTable", "add_classical"]

#: What a method needs, by key.
NEEDS = {"equations": "equations (grad H)", "reduced operator": "reduced operator (intrusive ROM)", "data": "only data"}

#: Chart labels of the compiled schemes.
SCHEME_LABELS = {
    "stormer_verlet": "Stormer-Verlet (compiled)",
    "yoshida4": "Yoshida-4 (compiled)",
    "kahan_li6": "Kahan-Li-6 (compiled)",
    "implicit_midpoint": "implicit midpoint (compiled)",
}


@contextmanager
def deliberate_threads(n: int):
    """BLAS (threadpoolctl) and numba (``numba.set_num_threads``) limited to ``n`` threads inside the block."""
    old = None
    if HAVE_NUMBA:
        old = numba.get_num_threads()
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        with threadpool_limits(limits=n):
            yield
    finally:
        if old is not None:
            numba.set_num_threads(old)


def time_median(run, repeats: int, batch: int = 1):
    """One untimed warm-up call (compilation, caches: the same for every method), then the median wall time of
    ``repeats`` calls divided by ``batch``; and the last output."""
    out = run()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = run()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) / batch, out


def timed(model):
    """``model`` as the speed charts time it: on the compiled Newton solver wherever ``backend='auto'`` may use it.

    ``auto`` runs small calls on NumPy (no compiled code to load in a fresh process); a chart
    compares warm, compiled methods, so the kernel predictor is pinned to the compiled solver
    like its compiled peers.  Returns ``model`` (changed in place).
    """
    inner = newton_predictor(model)
    if (
        inner is not None
        and getattr(inner.solver, "backend", "auto") == "auto"
        and inner.backend_for(10**6, 10**6) == "numba"
    ):
        inner.set_params(solver__backend="numba")
    return model


def model_sizes(sizes, n_centers: int) -> list:
    """The chart's kernel sizes: those of ``sizes`` below the fitted model's ``n_centers``, and the model itself.

    A greedy that stopped early (power breakdown) still gives the chart its largest model.
    """
    return sorted({int(c) for c in sizes if c < n_centers} | {int(n_centers)})


class SpeedTable:
    """Rows of a speed-against-accuracy run, errors against one reference.

    Parameters
    ----------
    reference : ndarray of shape (B, K+1, d)
        The trajectories errors are measured against.
    repeats : int
        Timed runs per method (after one warm-up).
    transform : callable, optional
        Maps a method's output to the reference's space (e.g. reconstruction ``V x``).
    """

    def __init__(self, reference: np.ndarray, repeats: int, transform=None):
        self.reference = reference
        self.repeats = repeats
        self.batch = len(reference)
        self.transform = transform
        self.rows: list[dict] = []

    def add(self, method: str, size, tag: str, needs: str, run) -> dict:
        """Time ``run()`` (returns (B, K+1, d) trajectories) and record its errors: mean over the batch, median / max over time."""
        seconds, traj = time_median(run, self.repeats, self.batch)
        if self.transform is not None:
            traj = self.transform(traj)
        with np.errstate(all="ignore"):
            err = relative_trajectory_error(
                np.nan_to_num(traj, nan=1e300, posinf=1e300, neginf=-1e300), self.reference
            ).mean(axis=0)[1:]
        row = {
            "method": method,
            "size": size,
            "tag": tag,
            "needs": NEEDS[needs],
            "time_per_trajectory_s": seconds,
            "median_err": float(np.median(err)),
            "max_err": float(err.max()),
        }
        self.rows.append(row)
        return row

    def add_model(self, method: str, model, run) -> dict | None:
        """A learned model's row: its size is its centres ``model.n_centers_``, it needs only data; nothing where
        ``model`` is ``None`` (a peer the run did not fit)."""
        if model is None:
            return None
        return self.add(method, model.n_centers_, f"m={model.n_centers_}", "data", run)


def add_classical(
    table: SpeedTable,
    system,
    x0,
    mu,
    dt,
    n_steps: int,
    refinements,
    schemes=EXPLICIT_SCHEMES,
    needs: str = "equations",
    wrap=None,
) -> None:
    """The compiled schemes of :func:`sympredict.symplectic.integrators_compiled.rollout` at ``dt / r`` for each refinement ``r``.

    ``wrap(run)`` may wrap each run (e.g. projection and reconstruction for a ROM).
    """
    for scheme in schemes:
        for r in refinements:
            run = lambda s=scheme, r=r: rollout(system, x0, mu, dt, n_steps, scheme=s, substeps=r)
            table.add(SCHEME_LABELS[scheme], r, f"dT/{r}", needs, run if wrap is None else wrap(run))
