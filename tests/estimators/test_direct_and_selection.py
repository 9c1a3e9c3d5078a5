"""The direct (non-symplectic) baseline and kernel selection by validation."""

import numpy as np
import pytest

from sympredict import ExtrapolationWarning

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.data import FlowMapData
from sympredict.interpolation.functionals import ValueFunctionals, dense_interpolation
from sympredict.interpolation.greedy import greedy_interpolation
from sympredict.kernels import IMQ, Matern52, ProductKernel, kernel_from_spec
from sympredict.estimators.selection import SelectionResult, kernel_grid, log_grid, refine_kernel_shapes, select_kernels
from sympredict.interpolation.greedy import ExactGreedy


def test_value_greedy_to_exhaustion_equals_dense_solve(rng):
    kernel = ProductKernel(Matern52(0.8), IMQ(2.0), IMQ(5.0))
    x = rng.uniform(-2, 2, size=(25, 2))
    fun = ValueFunctionals(kernel, x, rng.uniform(0.7, 0.8, (25, 1)), rng.choice([0.04, 0.06], 25))
    y = np.column_stack([np.sin(x[:, 0]), np.cos(x[:, 1])])
    res = greedy_interpolation(fun, y, max_centers=25, tol=0.0, power_tol=0.0)
    coef = np.zeros_like(y)
    coef[res.selected] = res.coef
    dense = dense_interpolation(fun, y)
    np.testing.assert_allclose(coef, dense, atol=1e-8 * np.abs(dense).max())


def test_direct_model_interpolates_the_step(pendulum, small_pendulum_data, rng):
    d = small_pendulum_data.subset(slice(0, 60))
    model = DirectKernelPredictor(
        IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=60, trainer=ExactGreedy(tol=0.0, power_tol=0.0)
    )
    model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    assert model.n_centers_ == 60
    np.testing.assert_allclose(model.step(d.x0, mu=d.mu, dt=d.dt), d.x1, atol=1e-8)
    with pytest.warns(
        ExtrapolationWarning, match="leave the training states"
    ):  # 60 samples: a corner of the phase space
        traj = model.rollout(d.x0[:3], 4, mu=d.mu[:3], dt=d.dt[:3])
    assert traj.shape == (3, 5, 2)
    np.testing.assert_allclose(traj[:, 1], model.step(d.x0[:3], mu=d.mu[:3], dt=d.dt[:3]), atol=1e-14)
    with pytest.raises(ValueError, match="mu_kernel is set"):
        DirectKernelPredictor(IMQ(1.0), IMQ(1.0), IMQ(1.0)).fit(d.x0, d.x1, dt=d.dt)


def test_direct_model_drifts_in_energy_where_the_symplectic_one_does_not(pendulum):
    """The paper's qualitative claim, on a small case: same data, same kernel, long rollout."""
    from sympredict.symplectic.metrics import relative_hamiltonian_error
    from sympredict.systems.pendulum import flow_map_data

    d = flow_map_data(pendulum, n_grid=16, p_nonpositive=True)
    kernels = (IMQ(0.15), IMQ(2.0), IMQ(5.0))
    x0, mu = np.array([[1.0, 0.0]]), np.array([[0.75]])
    drift = {}
    for cls in (SymplecticKernelPredictor, DirectKernelPredictor):
        model = cls(*kernels, max_centers=300).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
        with pytest.warns(ExtrapolationWarning, match="leave the training states"):  # trained on p <= 0 (scenario B)
            traj = model.rollout(x0, 2000, mu=0.75, dt=0.05)
        energy_err = relative_hamiltonian_error(pendulum, traj, mu)[0]
        drift[cls.__name__] = energy_err[-200:].mean()
    assert drift["SymplecticKernelPredictor"] * 10 < drift["DirectKernelPredictor"]


def test_log_grid_and_kernel_grid():
    np.testing.assert_allclose(log_grid(1e-3, 1e-1, 2), [1e-3, 10**-2.5, 1e-2, 10**-1.5, 1e-1])
    assert kernel_grid(("imq", "matern52"), [0.1, 1.0]) == [IMQ(0.1), IMQ(1.0), Matern52(0.1), Matern52(1.0)]
    assert kernel_grid((), [0.1]) == [None]
    with pytest.raises(ValueError, match="unknown kernel families"):
        kernel_grid(("gauss",), [1.0])
    with pytest.raises(ValueError, match="lo <= hi"):
        log_grid(1.0, 0.1)


def test_select_kernels_picks_the_smallest_validation_residual(small_pendulum_data):
    data, val = small_pendulum_data.split(0.2, seed=1)
    result = select_kernels(data, val, [IMQ(0.05), IMQ(0.15), IMQ(5.0)], [IMQ(2.0)], [IMQ(5.0)], m_star=60, widen=0)
    scores = {kernel_from_spec(row["state"]): row["E_val"] for row in result.table}
    assert len(scores) == 3
    for row in result.table:
        assert row["complete"] == (row["n_centers"] >= 60)
    assert result.score == min(scores.values()) == scores[result.state]
    preferred = select_kernels(
        data, val, [IMQ(0.05), IMQ(0.15), IMQ(5.0)], [IMQ(2.0)], [IMQ(5.0)], m_star=60, prefer_complete=True, widen=0
    )
    complete = {kernel_from_spec(row["state"]): row["E_val"] for row in preferred.table if row["complete"]}
    assert preferred.score == min(complete.values() or scores.values())
    assert result.state != IMQ(5.0)  # a far too narrow kernel cannot interpolate 60 centres' worth of data
    with pytest.raises(ValueError, match="must not contain None"):
        select_kernels(data, val, [IMQ(0.15)], [IMQ(2.0)], [None], m_star=10)


def test_selection_ranks_complete_runs_before_early_stops():
    early = SelectionResult(IMQ(0.1), None, None, 1e-6, complete=False)
    complete = SelectionResult(IMQ(0.2), None, None, 1e-4, complete=True)
    worse = SelectionResult(IMQ(0.3), None, None, 1e-3, complete=True)
    broken = SelectionResult(IMQ(0.4), None, None, float("nan"), complete=True)
    assert sorted([broken, early, worse, complete], key=lambda r: r.rank(prefer_complete=True)) == [
        complete,
        worse,
        early,
        broken,
    ]
    assert sorted([broken, early, worse, complete], key=SelectionResult.rank) == [early, complete, worse, broken]


def test_refine_kernel_shapes_moves_by_factor_two_and_never_gets_worse(small_pendulum_data):
    data, val = small_pendulum_data.split(0.2, seed=1)
    start = select_kernels(data, val, [IMQ(0.6)], [IMQ(2.0)], [IMQ(5.0)], m_star=80)
    refined = refine_kernel_shapes(data, val, start, m_star=80, max_sweeps=2, prefer_complete=True)
    assert refined.rank(True) <= start.rank(True)
    assert refined.state.eps < 0.6  # 0.6 is too narrow for this data: the search moves towards flatter kernels
    for row in refined.table:  # every candidate is the start scaled by powers of two, per factor
        for key, eps0 in (("state", 0.6), ("mu", 2.0), ("dt", 5.0)):
            eps = row[key]["eps"]
            assert np.log2(eps / eps0) == pytest.approx(round(np.log2(eps / eps0)))
    assert len({r["kernels"] for r in refined.table}) == len(refined.table)  # nothing refitted
    with pytest.raises(ValueError, match="factor"):
        refine_kernel_shapes(data, val, start, m_star=10, factor=1.0)


def test_flow_map_data_split_and_concatenate(small_pendulum_data):
    train, val = small_pendulum_data.split(0.25, seed=0)
    assert len(train) + len(val) == len(small_pendulum_data)
    both = train.concatenate(val)
    assert isinstance(both, FlowMapData) and len(both) == len(small_pendulum_data)
    with pytest.raises(ValueError, match="validation_fraction"):
        small_pendulum_data.split(1.5)


def test_selection_survives_failing_candidates_and_widens_its_grid(small_pendulum_data, caplog):
    """A failing fit is scored inf and skipped; a winner on the edge of its grid moves beyond it; a too small m* warns."""
    import logging

    data, val = small_pendulum_data.split(0.2, seed=1)

    class FailsAtHalf(SymplecticKernelPredictor):  # a candidate whose fit raises
        def fit(self, *args, **kwargs):
            if self.state_kernel.eps == 0.5:
                raise ValueError("the kernel coefficients overflow (test)")
            return super().fit(*args, **kwargs)

    caplog.set_level(logging.INFO, logger="sympredict.estimators.selection")
    result = select_kernels(
        data, val, [IMQ(0.5), IMQ(1.2), IMQ(2.4)], [IMQ(2.0)], [IMQ(5.0)], m_star=60, estimator=FailsAtHalf(), widen=0
    )
    failed = [row for row in result.table if "error" in row]
    assert len(failed) == 1 and failed[0]["E_val"] == np.inf and failed[0]["state"]["eps"] == 0.5
    assert result.state == IMQ(1.2)  # the best that could be fitted
    # the grid 0.6, 1.2: the flatter edge wins, so the search goes on to 0.3 and 0.15 (grid ratio 2)
    widened = select_kernels(data, val, [IMQ(0.6), IMQ(1.2)], [IMQ(2.0)], [IMQ(5.0)], m_star=60, widen=2)
    tried = [row["state"]["eps"] for row in widened.table if row["widened"]]
    assert tried[:1] == [0.3] and widened.state.eps < 0.6
    assert widened.score <= min(row["E_val"] for row in widened.table if not row["widened"])
    # every validation curve still falls at m* = 8: the warning says so
    caplog.clear()
    select_kernels(data, val, [IMQ(0.15), IMQ(0.3)], [IMQ(2.0)], [IMQ(5.0)], m_star=8, widen=0)
    assert any("below what every candidate needs" in r.getMessage() for r in caplog.records)
