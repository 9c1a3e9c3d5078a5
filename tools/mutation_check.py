"""Mutation check: apply a fixed list of meaningful faults, one at a time, and run the tests that must catch each.

Usage (from the repository root, with the project's virtual environment)::

    .venv/bin/python tools/mutation_check.py                 # every fault, one at a time
    .venv/bin/python tools/mutation_check.py --only F1 E1    # some faults
    .venv/bin/python tools/mutation_check.py --list          # the list, nothing run
    .venv/bin/python tools/mutation_check.py --jobs 2 --json result.json

Each fault is an exact source snippet and its replacement in one file, with the
test files to run.  The script copies the tree once into a temporary folder
(the working tree is never touched), and for each fault restores the pristine
file, applies the replacement and runs ``pytest -x -q`` on the listed files
with the copy first on ``sys.path``.  Outcomes:

* ``CAUGHT``   -- the tests failed (what we want);
* ``SURVIVED`` -- the tests passed with the fault in place;
* ``TIMEOUT``  -- the tests ran past ``--timeout`` (counted as caught, listed);
* ``ERROR``    -- the snippet occurs zero times or more than once: the code moved or
  changed, and the fault must be re-targeted.  Never skipped silently.

The exit status is 0 only when every fault is caught (``CAUGHT`` or ``TIMEOUT``).
CPU use: one pytest process per fault (``--jobs`` in parallel); the whole list
takes several minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Fault:
    id: str
    area: str
    file: str
    snippet: str
    replacement: str
    tests: tuple
    what: str


P = "sympredict/"
FAULTS = [
    # ----------------------------------------------------------------- kernels
    Fault("K1", "kernels", P + "kernels/radial.py", "return -e2 * inv_u * sq, 3.0", "return -e2 * inv_u, 3.0",
          ("tests/kernels/test_kernel_families.py",), "IMQ first derivative factor A has the wrong power"),
    Fault("K2", "kernels", P + "kernels/radial.py", "B = 3.0 * e2 * e2 * inv_u * inv_u * sq", "B = 2.0 * e2 * e2 * inv_u * inv_u * sq",
          ("tests/kernels/test_kernels.py", "tests/kernels/test_kernel_families.py"), "IMQ second derivative factor B has the wrong constant"),
    Fault("K3", "kernels", P + "kernels/radial.py", "C = -15.0 * e2 * e2 * e2 * (inv_u * inv_u * inv_u) * sq", "C = -5.0 * e2 * e2 * e2 * (inv_u * inv_u * inv_u) * sq",
          ("tests/kernels/test_kernel_families.py", "tests/estimators/test_oracles.py"), "IMQ third derivative factor C (Hessian of s) wrong"),
    Fault("K4", "kernels", P + "kernels/radial.py", "return -(e * e / 3.0) * (1.0 + er) * E, (e**4 / 3.0) * E\n", "return -(e * e / 3.0) * er * E, (e**4 / 3.0) * E\n",
          ("tests/kernels/test_kernels.py", "tests/kernels/test_kernel_families.py"), "Matern 5/2 factor A wrong"),
    Fault("K5", "kernels", P + "kernels/radial.py", "return -e * e * E, e**3 * E * _inverse_r(r)", "return -e * e * E, e**2 * E * _inverse_r(r)",
          ("tests/kernels/test_kernels.py", "tests/kernels/test_kernel_families.py"), "Matern 3/2 factor B wrong"),
    # ----------------------------------------------------------------- surrogate and data
    Fault("S1", "surrogate", P + "interpolation/surrogate.py", "out[sl] = -np.matmul((w * B * g)[:, None, :], diff)[:, 0, :] - wA @ self._onehot",
          "out[sl] = -np.matmul((w * B * g)[:, None, :], diff)[:, 0, :] + wA @ self._onehot",
          ("tests/interpolation/test_surrogate.py", "tests/interpolation/test_greedy.py"), "sign of the A term in the surrogate gradient"),
    Fault("D1", "data", P + "data.py", "y = -j_times(inc)", "y = j_times(inc)",
          ("tests/estimators/test_predictor.py",), "gradient targets J^T (x1 - x0) / dT with the wrong sign"),
    Fault("D2", "data", P + "data.py", "xi = np.concatenate([x0[:, :n], x1[:, n:]], axis=1)", "xi = np.concatenate([x0[:, :n], x0[:, n:]], axis=1)",
          ("tests/estimators/test_predictor.py",), "mixed variables (q0, p0) instead of (q0, p1)"),
    # ----------------------------------------------------------------- greedy (lead is rewriting greedy.py: re-target after merge)
    Fault("G1", "greedy", P + "interpolation/greedy/dense.py", 'score = self.res_abs if self.criterion == "f" else self.p2.copy()', 'score = self.p2.copy() if self.criterion == "f" else self.res_abs',
          ("tests/interpolation/test_greedy.py",), "f-greedy and P-greedy selection rules swapped"),
    Fault("G2", "greedy", P + "interpolation/greedy/loop.py", 'if criterion == "f" and certified <= tol:', 'if criterion == "f" and certified < 0:',
          ("tests/interpolation/test_greedy.py", "tests/estimators/test_performance_paths.py"), "residual tolerance never stops the greedy"),
    # ----------------------------------------------------------------- Newton and the step (predictor.py, symplectic/_compiled_newton.py, interpolation/_compiled.py: lead's files)
    Fault("N1", "Newton", P + "symplectic/_compiled_newton.py", "u[a] = x[n + a] - h * grad[a]", "u[a] = x[n + a] + h * grad[a]",
          ("tests/estimators/test_oracles.py",), "compiled Newton: wrong sign of the explicit initial guess (same result, more iterations)"),
    Fault("N2", "Newton", P + "symplectic/_compiled_newton.py", "out[a] = x[a] + h * grad[n + a]\n                    out[n + a] = u[a]",
          "out[a] = x[a] - h * grad[n + a]\n                    out[n + a] = u[a]",
          ("tests/estimators/test_performance_paths.py",), "compiled step: q1 = q0 - dT d_p s"),
    Fault("N3", "Newton", P + "symplectic/newton.py", "out[idx, :n] = x[idx, :n] + dt[idx, None] * g[done, n:]",
          "out[idx, :n] = x[idx, :n] - dt[idx, None] * g[done, n:]",
          ("tests/estimators/test_performance_paths.py",), "NumPy reference step: q1 = q0 - dT d_p s"),
    Fault("N4", "Newton", P + "symplectic/updates.py", "return dt * np.linalg.norm(hess[:, :, n:], ord=2, axis=(1, 2))",
          "return dt * np.linalg.norm(hess[:, :, :n], ord=2, axis=(1, 2))",
          ("tests/estimators/test_oracles.py",), "solvability reads the q columns of the Hessian"),
    Fault("N5", "Newton", P + "symplectic/updates.py", "Minv = np.linalg.inv(eye + h * Sqp)", "Minv = np.linalg.inv(eye - h * Sqp)",
          ("tests/estimators/test_oracles.py",), "step Jacobian: wrong sign in M = I + dT S_qp"),
    Fault("N6", "Newton", P + "symplectic/updates.py", "dq_dp = h * (Spp @ Minv)", "dq_dp = h * Spp",
          ("tests/estimators/test_oracles.py",), "step Jacobian: dq1/dp0 misses M^-1"),
    Fault("N7", "Newton", P + "interpolation/_compiled.py", "hess[0, 0] -= h00 + s_bg + (2.0 * m0 if l == 0 else 0.0)",
          "hess[0, 0] -= h00 + s_bg + (m0 if l == 0 else 0.0)",
          ("tests/symplectic/test_midpoint_compiled.py",), "fused 2n = 2 pass: the full Hessian misses M_ca (midpoint Jacobian)"),
    Fault("N8", "Newton", P + "interpolation/_compiled.py", "fl += abs(bg) * (ad0 if ad0 > ad1 else ad1) + abs(a_)",
          "fl += abs(bg) * (ad0 if ad0 < ad1 else ad1) + abs(a_)",
          ("tests/kernels/test_kernel_families.py",), "fused 2n = 2 pass: the floor takes min |d| instead of max"),
    # ----------------------------------------------------------------- exact-linear-flow splitting
    Fault("SP1", "splitting", P + "flowmap/splitting.py", "_apply(inverse_symplectic_matrices(L), data.x1)", "_apply(L, data.x1)",
          ("tests/flowmap/test_splitting.py",), "training pairs: x1 transformed by L_h instead of L_-h"),
    Fault("SP2", "splitting", P + "systems/linear_flow.py", "gen = j_times(H, axis=-2)", "gen = j_times(H.swapaxes(-1, -2), axis=-1)",
          ("tests/flowmap/test_splitting.py",), "propagator of -A J instead of J A"),
    Fault("SP3", "splitting", P + "flowmap/scaling.py", "left, right = float(tau) * J.T @ M @ J, np.linalg.inv(M)",
          "left, right = float(tau) * M, np.linalg.inv(M)",
          ("tests/paper/test_sine_gordon_split.py",), "quadratic part in scaled coordinates conjugated like a map, not a form"),
    Fault("SP4", "splitting", P + "symplectic/_compiled_newton.py", "_matvec_into(post[i], y_out, traj[i, k + 1])", "_matvec_into(pre[i], y_out, traj[i, k + 1])",
          ("tests/flowmap/test_splitting.py",), "compiled split rollout: the map before the step applied after it too"),
    Fault("SP5", "splitting", P + "estimators/fitted.py", "pre, post = pre * scale[None, :, None], post / scale[None, None, :]",
          "pre, post = pre / scale[None, :, None], post * scale[None, None, :]",
          ("tests/flowmap/test_splitting.py",), "split rollout: state scaling conjugated the wrong way"),
    # ----------------------------------------------------------------- reduction
    Fault("R1", "reduction", P + "mor/basis.py", "return j_times(j_times(V, axis=0).T, axis=0)", "return V.T",
          ("tests/estimators/test_oracles.py",), "symplectic inverse V+ = V^T (coincides only for orthosymplectic V)"),
    Fault("R9", "reduction", P + "_numeric.py", "return np.concatenate([v[tuple(hi)], -v[tuple(lo)]], axis=axis)",
          "return np.concatenate([v[tuple(hi)], v[tuple(lo)]], axis=axis)",
          ("tests/paper/test_sine_gordon_long_time.py", "tests/estimators/test_oracles.py"), "J applied by block swap without the sign"),
    Fault("R2", "reduction", P + "mor/basis.py", "V = np.block([[Un.real, -Un.imag], [Un.imag, Un.real]])",
          "V = np.block([[Un.real, Un.imag], [Un.imag, Un.real]])", ("tests/systems/test_wave.py",), "complex-SVD basis not symplectic"),
    Fault("R3", "reduction", P + "mor/basis.py", "return float(np.sqrt(max(0.0, s2[self.n :].sum()) / s2.sum()))",
          "return float(np.sqrt(max(0.0, s2[self.n + 1 :].sum()) / s2.sum()))", ("tests/systems/test_wave.py", "tests/estimators/test_oracles.py"),
          "projection error skips a mode"),
    # ----------------------------------------------------------------- integrators
    Fault("I1", "integrators", P + "symplectic/integrators.py", "mid = 0.5 * (xa + x1a)", "mid = x1a",
          ("tests/symplectic/test_integrators.py",), "implicit midpoint evaluates at the end point (implicit Euler)"),
    Fault("I2", "integrators", P + "symplectic/integrators.py", "p = p - 0.5 * hh * system.gradient(x, mu)[:, :n]", "p = p - hh * system.gradient(x, mu)[:, :n]",
          ("tests/symplectic/test_integrators.py",), "Stormer-Verlet: full instead of half kick"),
    Fault("I3", "integrators", P + "symplectic/integrators.py", "return np.concatenate([q0 + hh * g[:, n:], p], axis=1)",
          "return np.concatenate([q0 - hh * g[:, n:], p], axis=1)", ("tests/symplectic/test_integrators.py",), "symplectic Euler: wrong sign of the q update"),
    # ----------------------------------------------------------------- systems and metrics
    Fault("P1", "systems", P + "systems/pendulum.py", "def __init__(self, g: float = 9.81, mass: float = 1.0):",
          "def __init__(self, g: float = 9.8, mass: float = 1.0):", ("tests/estimators/test_oracles.py",), "default g = 9.8"),
    Fault("P2", "systems", P + "systems/pendulum.py", "x[:, 1] / (self.mass * length**2)])", "x[:, 1] / length**2])",
          ("tests/estimators/test_oracles.py",), "mass dropped from dH/dp in the gradient"),
    Fault("P3", "systems", P + "systems/pendulum.py", "a = h / (2 * self.mass * length**2)", "a = h / (2 * length**2)",
          ("tests/estimators/test_oracles.py",), "mass dropped from dH/dp in the reference flow"),
    Fault("W1", "systems", P + "systems/wave.py", "2.0 * np.ones(n_points)", "2.5 * np.ones(n_points)",
          ("tests/systems/test_wave.py",), "finite-difference Laplacian diagonal wrong"),
    Fault("Q1", "systems", P + "systems/quadratic.py", 'return 0.5 * (np.einsum("bi,ij,bj->b", x, self.H0, x)',
          'return 1.0 * (np.einsum("bi,ij,bj->b", x, self.H0, x)', ("tests/systems/test_wave.py",), "quadratic Hamiltonian without 1/2"),
    Fault("M1", "metrics", P + "symplectic/metrics.py", "return np.linalg.norm(pred - ref, axis=-1) / np.linalg.norm(ref, axis=-1)",
          "return np.linalg.norm(pred - ref, axis=-1) / np.linalg.norm(pred, axis=-1)",
          ("tests/paper/test_published_numbers.py",), "relative error normalised by the prediction"),
    Fault("M2", "metrics", P + "symplectic/metrics.py", "return np.abs(energy - energy[:, :1]) / np.abs(energy[:, :1])",
          "return np.abs(energy - energy[:, 1:2]) / np.abs(energy[:, :1])", ("tests/paper/test_published_numbers.py",),
          "energy error against H(x_1) instead of H(x_0)"),
    # ----------------------------------------------------------------- experiments
    Fault("E1", "experiments", "sympredict_paper/pendulum.py", "err_im = relative_trajectory_error(im, ref).mean(axis=0)",
          "err_im = relative_trajectory_error(pred, ref).mean(axis=0)", ("tests/paper/test_published_numbers.py",),
          "scenario A: implicit-midpoint error computed from the kernel's prediction"),
    Fault("E2", "experiments", "sympredict_paper/pendulum.py", '"energy_im": relative_hamiltonian_error(system, im, lengths[:, None])',
          '"energy_im": relative_hamiltonian_error(system, pred, lengths[:, None])', ("tests/paper/test_published_numbers.py",),
          "scenario A: implicit-midpoint energy error from the kernel's prediction"),
    Fault("E3", "experiments", "sympredict_paper/pendulum.py", '"mu": float(lengths[-1])}', '"mu": float(lengths[0])}',
          ("tests/paper/test_published_numbers.py",), "phase portrait titled with the wrong length"),
    Fault("E4", "experiments", "sympredict_paper/pendulum.py",
          'for name, cls in (("symplectic", SymplecticKernelPredictor), ("direct", DirectKernelPredictor)):',
          'for name, cls in (("symplectic", DirectKernelPredictor), ("direct", SymplecticKernelPredictor)):',
          ("tests/paper/test_published_numbers.py",), "scenario B: the two model classes swapped"),
    Fault("E5", "experiments", "sympredict_paper/pendulum.py",
          '"ratio_median": float(np.median(r["err_im"][1:]) / np.median(r["err_kernel"][1:])),',
          '"ratio_median": float(np.median(r["err_kernel"][1:]) / np.median(r["err_im"][1:])),',
          ("tests/paper/test_published_numbers.py",), "published ratio inverted"),
    Fault("E6", "experiments", "sympredict_paper/wave.py", '"im_red": relative_trajectory_error(im, ref).mean(axis=0),',
          '"im_red": relative_trajectory_error(pred, ref).mean(axis=0),', ("tests/systems/test_wave.py",),
          "wave: implicit-midpoint error computed from the kernel's prediction"),
    Fault("E7", "experiments", "sympredict_paper/speed.py", '"median_err": float(np.median(err)), "max_err": float(err.max())}',
          '"median_err": float(np.min(err)), "max_err": float(err.max())}', ("tests/paper/test_speed_accuracy.py",),
          "speed-against-accuracy rows: the best time step's error published as the median"),
    # ----------------------------------------------------------------- figures and report
    Fault("F1", "figures", "sympredict_paper/report.py", '"kernel predictor": ex["kernel"], "implicit midpoint, macro step": ex["im"]',
          '"kernel predictor": ex["ref"], "implicit midpoint, macro step": ex["im"]', ("tests/paper/test_published_numbers.py",),
          "phase portrait draws the reference under the kernel's label"),
    Fault("F2", "figures", "sympredict_paper/report.py", '"symplectic kernel": ex["symplectic"], "direct kernel": ex["direct"]',
          '"symplectic kernel": ex["direct"], "direct kernel": ex["symplectic"]', ("tests/paper/test_published_numbers.py",),
          "scenario B: symplectic and direct trajectories swapped"),
    Fault("F3", "figures", "sympredict_paper/report.py", '{"kernel predictor": r0["energy_kernel"], "implicit midpoint, macro step": r0["energy_im"]',
          '{"kernel predictor": r0["energy_im"], "implicit midpoint, macro step": r0["energy_kernel"]', ("tests/paper/test_published_numbers.py",),
          "scenario A energy figure: labels swapped"),
    Fault("F4", "figures", "sympredict_paper/report.py", '"holds": min(ratios) >= 100 and min(pointwise) > 1,', '"holds": min(ratios) >= 10 and min(pointwise) > 1,',
          ("tests/paper/test_published_numbers.py",), "claim threshold: one order of magnitude instead of two"),
    Fault("F5", "figures", "sympredict_paper/plotting.py", 'ax.semilogy(c["t"][1:], c["values"][1:]', 'ax.semilogy(c["t"][:-1], c["values"][1:]',
          ("tests/paper/test_published_numbers.py",), "error curves shifted by one step in time"),
    Fault("F6", "figures", "sympredict_paper/plotting.py", "ax.plot(traj[:, 0], traj[:, 1]", "ax.plot(traj[:, 1], traj[:, 0]",
          ("tests/paper/test_published_numbers.py",), "phase portrait axes swapped"),
    Fault("F7", "figures", "sympredict_paper/plotting.py", "for ax, comp in zip(axes, (0, 1)):", "for ax, comp in zip(axes, (1, 0)):",
          ("tests/paper/test_published_numbers.py",), "q(t) and p(t) panels swapped"),
    # ----------------------------------------------------------------- I/O (io.py and container.py: other developers' files)
    Fault("O1", "I/O", P + "container.py", "    if expected != attrs[\"checksum\"]:", "    if False:",
          ("tests/io/test_io.py", "tests/estimators/test_predictor.py"), "checksum never verified"),
    Fault("O2", "I/O", P + "io/formats.py", 'arrays = {"x0": data.x0, "x1": data.x1, "mu": data.mu, "dt": data.dt}',
          'arrays = {"x0": data.x0, "x1": data.x1, "mu": data.mu, "dt": data.dt[::-1]}', ("tests/io/test_io.py",),
          "data set saved with reordered steps"),
    Fault("O3", "I/O", P + "estimators/model_files.py", 'val_max_residual=arrays.get("val_max_residual"),', "val_max_residual=None,",
          ("tests/io/test_io.py", "tests/estimators/test_predictor.py", "tests/cli/test_cli.py"), "validation history lost on load"),
    # ----------------------------------------------------------------- the reshaped core (loop, stores, contract)
    Fault("L1", "greedy", P + "interpolation/greedy/loop.py", "                m = m_best\n", "                pass\n",
          ("tests/interpolation/test_greedy.py",), "a diverged run is not truncated to its best step"),
    Fault("L2", "greedy", P + "interpolation/greedy/sharded.py", "if best is None or score > best[0]:", "if best is None or score >= best[0]:",
          ("tests/parallel/test_parallel.py",), "sharded ties go to the highest index, not the lowest (as np.argmax)"),
    Fault("L3", "greedy", P + "interpolation/greedy/active_set.py", "if full and self.full_max <= self.tol:", "if full and self.full_max <= 10 * self.tol:",
          ("tests/estimators/test_performance_paths.py",), "the active set stops before the full residual reaches tol"),
    Fault("B1", "contract", P + "base.py", "        return type(obj)(**params)", "        return obj",
          ("tests/estimators/test_estimator_contract.py",), "clone returns the object itself"),
    Fault("X1", "estimators", P + "estimators/fitted.py",
          "        self._warn_if_trajectory_leaves(traj if around is None else np.einsum(\"bij,bkj->bki\", around[0], traj), stride)\n",
          "",
          ("tests/estimators/test_no_silent_numerics.py",), "a symplectic rollout leaving the training states does not warn"),
    # ----------------------------------------------------------------- later additions (symmetry, selection, sine-Gordon)
    Fault("Y1", "symmetry", P + "kernels/radial.py", "                w = g[c, b]\n", "                w = np.abs(g[c, b])\n",
          ("tests/kernels/test_symmetry.py",), "group-averaged kernel: the derivative functionals lose the sign of g"),
    Fault("Y2", "symmetry", P + "kernels/radial.py",
          "out += w * (-B * d[rows, a] * d[:, c] - (A if g1 is None else A * g1) * (a == c))",
          "out += w * (-B * d[rows, a] * d[:, c] + (A if g1 is None else A * g1) * (a == c))",
          ("tests/kernels/test_symmetry.py",), "group-averaged Gramian diagonal with the wrong sign of the A term"),
    Fault("S3", "selection", P + "estimators/search.py", "if np.isfinite(value) and (best is None or value < best[2]):",
          "if np.isfinite(value) and (best is None or value > best[2]):",
          ("tests/estimators/test_select_by_score.py",), "select_by_score keeps the worst candidate"),
    Fault("SG1", "sine-Gordon", "sympredict_paper/sine_gordon.py", "m_after <= ratio * m and (rise is None or rise <= ratio - 1.0)",
          "m_after <= ratio * m",
          ("tests/paper/test_sine_gordon_long_time.py",), "energy boundedness ignores a secular drift below the ratio bound"),
    # the estimator's parts
    Fault("C1", "parts", P + "kernels/transforms.py", "return np.concatenate([a, 1.0 / a])", "return np.concatenate([a, a])",
          ("tests/kernels/test_state_scaling.py",), "Scaled: the scaling (a, a) is not symplectic"),
    Fault("C2", "parts", P + "base.py",
          "part = clone(target) if isinstance(target, Parametrized) else target",
          "part = target",
          ("tests/estimators/test_estimator_contract.py",), "set_params(trainer__...) changes a part the caller may share"),
    Fault("C3", "parts", P + "symplectic/updates.py", "return 0.5 * (x0 + x1), y", "return x0, y",
          ("tests/symplectic/test_midpoint.py",), "midpoint rule trained at x0 instead of the midpoint"),
    Fault("C4", "parts", P + "estimators/model_files.py",
          'if isinstance(settings, dict) and settings.get("layout", 1) in (1, 2):', "if False:",
          ("tests/estimators/test_parts.py",), "a pre-release model file is not refused with the advice to refit"),
    Fault("C5", "parts", P + "estimators/fitted.py", "out.append(np.ascontiguousarray(m))",
          "out.append(np.ascontiguousarray(np.swapaxes(m, 1, 2)))",
          ("tests/estimators/test_parts.py",), "the around hook applies the transposed maps"),
    Fault("C6", "parts", P + "estimators/fitted.py", "(lambda parts, rule: not rule.compiled,",
          "(lambda parts, rule: False,", ("tests/estimators/test_parts.py",),
          "an update rule without a compiled kernel not declared NumPy-only"),
    # the defaults' kernel search and diagnostics
    Fault("A1", "defaults", P + "estimators/auto.py", "a[ok] = np.sqrt(sp[ok] / sq[ok])", "a[ok] = np.sqrt(sq[ok] / sp[ok])",
          ("tests/estimators/test_auto_defaults.py",), "the symplectic normalisation inverted: q and p spreads pulled apart"),
    Fault("A2", "defaults", P + "estimators/search.py", "sub = val.subset(np.arange(min(len(val), largest)))",
          "sub = train.subset(np.arange(min(len(train), largest)))",
          ("tests/estimators/test_auto_defaults.py",), "the second stage scores candidates on their training samples"),
    Fault("A3", "defaults", P + "estimators/auto.py",
          "return data.subset(np.sort(rows[n_out:])), data.subset(np.sort(rows[:n_out]))",
          "return data, data.subset(np.sort(rows[:n_out]))",
          ("tests/estimators/test_auto_defaults.py",), "the held-out samples of the diagnostics are also trained on"),
    Fault("A4", "defaults", P + "estimators/model_files.py",
          '"choice": {k: encode_param(v) for k, v in _file_choice_of(model, params).items()},', '"choice": {},',
          ("tests/estimators/test_auto_defaults.py",), "a model file loses what the fit chose"),
]
_duplicate_ids = sorted({f.id for f in FAULTS if sum(g.id == f.id for g in FAULTS) > 1})
assert not _duplicate_ids, f"fault ids must be unique (--only selects by id): {_duplicate_ids}"


def _copy_tree(dst: Path):
    ignore = shutil.ignore_patterns(".venv", ".git", "_build", "__pycache__", "*.pyc", ".pytest_cache", ".hypothesis", "*.egg-info")
    shutil.copytree(ROOT, dst, ignore=ignore, dirs_exist_ok=True)


def run_fault(fault: Fault, workdir: Path, timeout: float) -> dict:
    """Apply ``fault`` in a private copy ``workdir`` of the tree and run its tests; returns the outcome."""
    target = workdir / fault.file
    pristine = (ROOT / fault.file).read_text()
    count = pristine.count(fault.snippet)
    result = {**asdict(fault), "tests": list(fault.tests), "seconds": 0.0}  # early returns ran nothing
    if count != 1:
        result.update(outcome="ERROR", detail=f"snippet found {count} times in {fault.file} (the code moved: re-target the fault)")
        return result
    missing = [t for t in fault.tests if not (workdir / t).exists()]
    if missing:
        result.update(outcome="ERROR", detail=f"test files missing: {missing}")
        return result
    target.write_text(pristine.replace(fault.snippet, fault.replacement))
    env = {**os.environ, "PYTHONPATH": str(workdir), "PYTHONDONTWRITEBYTECODE": "1", "OMP_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
           # a fresh compiled-code cache per fault: numba checks a cached kernel against its own file's date only,
           # so kernels cached under another fault would hide (or fake) a fault in a formula they inline
           "NUMBA_CACHE_DIR": str(workdir / ".numba_cache" / fault.id)}
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *fault.tests]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=workdir, env=env, capture_output=True, text=True, timeout=timeout)
        out = proc.stdout + proc.stderr
        if proc.returncode == 0:
            result.update(outcome="SURVIVED", detail=out.strip().splitlines()[-1] if out.strip() else "")
        elif proc.returncode in (1,):
            failed = [line for line in out.splitlines() if line.startswith(("FAILED", "ERROR"))]
            result.update(outcome="CAUGHT", detail=failed[0] if failed else out.strip().splitlines()[-1])
        else:
            result.update(outcome="ERROR", detail=f"pytest exit code {proc.returncode}: {out.strip()[-500:]}")
    except subprocess.TimeoutExpired:
        result.update(outcome="TIMEOUT", detail=f"tests ran past {timeout:.0f} s")
    finally:
        target.write_text(pristine)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    return result


def _check_import_path(workdir: Path):
    """The copy, not the installed checkout, must be what the tests import."""
    env = {**os.environ, "PYTHONPATH": str(workdir)}
    got = subprocess.run([sys.executable, "-c", "import sympredict, os; print(os.path.dirname(sympredict.__file__))"],
                         cwd=workdir, env=env, capture_output=True, text=True).stdout.strip()
    if Path(got).resolve() != (workdir / "sympredict").resolve():
        raise SystemExit(f"mutation_check: the tests would import sympredict from {got}, not from the copy {workdir}")


def summary_by_area(results: list[dict]) -> list[dict]:
    """Per area, in order of first appearance: ``area``, ``faults``, ``caught`` (``CAUGHT`` or ``TIMEOUT``) and the ``ids``."""
    areas: dict = {}
    for r in results:
        a = areas.setdefault(r["area"], {"area": r["area"], "faults": 0, "caught": 0, "ids": []})
        a["faults"] += 1
        a["caught"] += r["outcome"] in ("CAUGHT", "TIMEOUT")
        a["ids"].append(r["id"])
    return list(areas.values())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", nargs="+", metavar="ID", help="run these faults only")
    ap.add_argument("--list", action="store_true", help="print the faults and exit")
    ap.add_argument("--jobs", type=int, default=1, help="faults run in parallel (each in its own copy of the tree)")
    ap.add_argument("--timeout", type=float, default=900, help="seconds per fault before it counts as TIMEOUT")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    faults = FAULTS
    if args.only:
        unknown = set(args.only) - {f.id for f in FAULTS}
        if unknown:
            ap.error(f"unknown fault ids: {sorted(unknown)}")
        faults = [f for f in FAULTS if f.id in args.only]
    if args.list:
        for f in faults:
            print(f"{f.id:4s} {f.area:12s} {f.file:32s} {f.what}")
        return 0
    with tempfile.TemporaryDirectory(prefix="sympredict-mutants-") as tmp:
        workdirs = [Path(tmp) / f"copy{i}" for i in range(max(1, args.jobs))]
        for w in workdirs:
            _copy_tree(w)
        _check_import_path(workdirs[0])
        t0 = time.perf_counter()
        results = [None] * len(faults)

        def run_chunk(k):
            # copy k runs faults k, k + jobs, ...: faults that share a copy run one after the other
            for i in range(k, len(faults), len(workdirs)):
                results[i] = run_fault(faults[i], workdirs[k], args.timeout)
                r = results[i]
                print(f"{r['id']:4s} {r['outcome']:8s} {r['seconds']:6.1f} s  {r['what']}" + (f"  [{r['detail']}]" if r["outcome"] != "CAUGHT" else ""),
                      flush=True)

        with ThreadPoolExecutor(len(workdirs)) as pool:
            list(pool.map(run_chunk, range(len(workdirs))))
        total = time.perf_counter() - t0
    counts = {k: sum(r["outcome"] == k for r in results) for k in ("CAUGHT", "TIMEOUT", "SURVIVED", "ERROR")}
    print(f"{len(results)} faults in {total:.0f} s: " + ", ".join(f"{v} {k.lower()}" for k, v in counts.items()))
    if args.json:
        # command and machine: the documentation prints them under the tables it renders from this file
        record = {"command": shlex.join(getattr(sys, "orig_argv", [sys.executable, *sys.argv])),
                  "machine": f"{os.cpu_count()} CPUs, {platform.platform()}",
                  "total_seconds": total, "counts": counts, "areas": summary_by_area(results), "results": results}
        Path(args.json).write_text(json.dumps(record, indent=1))
    return 0 if counts["SURVIVED"] == counts["ERROR"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
