"""The kernel search's first stage (grids by ``E_val(m_star)``): the early stop's bound across the grids of the stage
(families and updates), on small fitted pendulum cases.  Every comparison below runs the same fits of the same arrays
with and without the early stop, so scores compare bit for bit; which candidates stop is checked against each
candidate's own validation residual curve from a fit to ``m_star`` (an independent run of the same fit)."""

import numpy as np
import pytest

from sympredict import KernelSearch, SymplecticKernelPredictor
from sympredict.base import clone
from sympredict.data import FlowMapData
from sympredict.estimators.search import E_VAL_STOP_MARGINS, EarlyStop, fit_candidate, grid_search
from sympredict.kernels import IMQ


@pytest.fixture(scope="module")
def samples():
    """Pendulum samples at one length: train and validation parts."""
    from sympredict.systems.pendulum import Pendulum

    rng = np.random.default_rng(3)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, 400), rng.uniform(-2.0, 2.0, 400)])
    data = FlowMapData(x0, Pendulum().flow(x0, 0.8, 0.1), None, np.full(400, 0.1))
    return data.subset(np.arange(300)), data.subset(np.arange(300, 400))


def _curves(grid, est, train, val, m_star):
    """Each candidate's validation residual curve ``E_val(0..m)`` of its fit to ``m_star`` centres."""
    out = {}
    for k in grid:
        model = clone(est).set_params(state_kernel=k, max_centers=m_star, trainer__tol=0.0)
        out[repr(k)] = fit_candidate(model, train, val).history_.val_max_residual
    return out


def _stops_at(curve, bound, m_star):
    """Where the early stop's rule (:data:`E_VAL_STOP_MARGINS`, written out) stops a candidate with this curve that
    must beat ``bound``: the first checkpoint whose residual exceeds its factor times the bound; ``None``: never."""
    for fraction, factor in sorted(E_VAL_STOP_MARGINS):
        c = int(fraction * m_star)
        if c >= EarlyStop.smallest and c < len(curve) and np.isfinite(bound) and curve[c] > factor * bound:
            return c
    return None


def test_the_margins_check_a_quarter_half_and_three_quarters_of_m_star_with_factors_falling_towards_m_star():
    """The first stage's checkpoints and factors: a quarter, half and three quarters of ``m_star``, the factor
    falling as the checkpoint nears ``m_star`` (the residual can fall less from there); each factor at a checkpoint
    is the one :class:`EarlyStop` applies from it on.  That each lies above the falls recorded on the six systems is
    checked against the published run (tests/paper/test_published_search_ratios.py)."""
    margins = sorted(E_VAL_STOP_MARGINS)
    assert [f for f, _ in margins] == [0.25, 0.5, 0.75]
    assert margins[0][1] > margins[1][1] > margins[2][1] > 1
    early = EarlyStop(criterion="E_val", margins=E_VAL_STOP_MARGINS)
    assert early.checkpoints(300) == [75, 150, 225]
    assert [early.factor(c, 300) for c in (75, 149, 150, 224, 225, 299)] == [
        margins[0][1],
        margins[0][1],
        margins[1][1],
        margins[1][1],
        margins[2][1],
        margins[2][1],
    ]


def test_a_bound_from_before_the_grid_stops_a_clearly_losing_grid_and_keeps_its_rows(samples):
    """A grid of kernels far too sharp against the best ``E_val(m_star)`` of a grid before it: with that bound every
    candidate stops at the first checkpoint its residual exceeds the margin (written out from its own curve), the
    ``ValueError`` of no finalist carries the rows (``abandoned``, ``E_val = inf``); without the bound, the same grid
    runs as before (its own winner, bit for bit the plain search's)."""
    train, val = samples
    est = SymplecticKernelPredictor(update="midpoint")
    good = grid_search(train, val, [IMQ(e) for e in (0.2, 0.5, 1.0)], m_star=60, estimator=est, widen=0)
    losing = [IMQ(e) for e in (40.0, 80.0)]
    curves = _curves(losing, est, train, val, 60)
    expected = {k: _stops_at(c, good.score, 60) for k, c in curves.items()}
    assert all(c is not None for c in expected.values()), expected  # the case is what the test needs
    with pytest.raises(ValueError, match="clearly losing") as info:
        grid_search(train, val, losing, m_star=60, estimator=est, widen=0, early_stop=True, bound=good.score)
    rows = info.value.table
    assert [r["kernels"] for r in rows] == list(curves)
    for r in rows:
        assert r["abandoned"] == expected[r["kernels"]] == r["n_centers"] and r["E_val"] == np.inf
        assert r["abandoned_E_val"] == curves[r["kernels"]][r["abandoned"]]
    plain = grid_search(train, val, losing, m_star=60, estimator=est, widen=0)
    alone = grid_search(train, val, losing, m_star=60, estimator=est, widen=0, early_stop=True)
    assert (alone.state, alone.score) == (plain.state, plain.score)
    assert plain.score > good.score  # the stopped grid would have lost


def test_a_bound_never_stops_the_winner_and_stops_exactly_the_candidates_beyond_its_margin(samples):
    """A grid whose own winner's score is the bound (as where it ties the stage's best): the same winner and score as
    without the early stop; a candidate stops iff its residual at a checkpoint exceeds the margin times the smaller of
    the bound and the grid's best so far (each candidate's curve from its own fit)."""
    train, val = samples
    est = SymplecticKernelPredictor(update="midpoint")
    grid = [IMQ(e) for e in (0.05, 0.2, 1.0, 5.0, 20.0, 50.0)]
    plain = grid_search(train, val, grid, m_star=60, estimator=est, widen=0)
    early = grid_search(train, val, grid, m_star=60, estimator=est, widen=0, early_stop=True, bound=plain.score)
    assert (early.state, early.score) == (plain.state, plain.score)
    curves = _curves(grid, est, train, val, 60)
    full = {r["kernels"]: r["E_val"] for r in plain.table}
    for i, r in enumerate(early.table):
        bound = min([q["E_val"] for q in early.table[:i] if np.isfinite(q["E_val"])] + [plain.score])
        stop = _stops_at(curves[r["kernels"]], bound, 60)
        assert r.get("abandoned") == stop, r["kernels"]
        assert r["E_val"] == (np.inf if stop else full[r["kernels"]])
    assert any("abandoned" in r for r in early.table)


def test_grid_search_refuses_a_bound_that_is_not_a_number(samples):
    train, val = samples
    with pytest.raises(ValueError, match="bound must be"):
        grid_search(train, val, [IMQ(1.0)], m_star=10, estimator=SymplecticKernelPredictor(), bound=float("nan"))


def _first_stage(search, train, val, m_star):
    est = SymplecticKernelPredictor(max_centers=m_star)

    def template(update):
        return clone(est).set_params(update=update)

    grid = [IMQ(e) for e in (0.25, 0.5, 1.0)]
    return search._first_stage(
        train, val, (grid, [None], [None]), ["symplectic_euler", "midpoint"], template, True, m_star
    )


def test_the_first_stage_drops_a_family_clearly_losing_against_its_update_and_keeps_every_other_finalist(samples):
    """Two families (IMQ and a Matern family far behind on the smooth pendulum) and two updates: with the early stop
    bounded by the best of each update's grids before it, every finalist that remains is the one the stage without
    the early stop chose (same kernels, same score), each update keeps its first family's finalist (its grid is
    bounded by its own candidates only), and a family without a finalist of an update was clearly losing there (its
    best ``E_val(m_star)`` without the early stop above three times the update's best); its rows stay in the table
    with ``abandoned``, and the stage takes fewer greedy steps."""
    train, val = samples
    search = KernelSearch(families=("imq", "matern52"), seed=0)
    on_table, on = _first_stage(search, train, val, 60)
    off_table, off = _first_stage(clone(search).set_params(early_stop=False), train, val, 60)
    key = {(u, type(r.state).__name__): r for r, u in off}
    kept = {(u, type(r.state).__name__): r for r, u in on}
    assert set(kept) < set(key)  # something was dropped (the case is what the test needs) ...
    assert ("symplectic_euler", "IMQ") in kept and ("midpoint", "IMQ") in kept  # ... never the first family
    for k, r in kept.items():
        assert (r.state, r.mu, r.dt, r.score) == (key[k].state, key[k].mu, key[k].dt, key[k].score)
    for update, family in set(key) - set(kept):
        assert key[(update, family)].score > 3 * key[(update, "IMQ")].score
        rows = [row for row in on_table if row.get("update") == update and family in row.get("kernels", "")]
        assert rows and all("abandoned" in row and row["E_val"] == np.inf for row in rows)
    centres = [sum(row.get("n_centers", 0) for row in t) for t in (on_table, off_table)]
    assert centres[0] < centres[1]  # the greedy steps taken: the cost, without timing noise
