"""Finite-difference 1-D sine-Gordon equation as a nonlinear pyMOR Hamiltonian model.

``u_tt = c^2 u_xx - s sin(u)`` on ``(0, L)`` (homogeneous Dirichlet: ``N``
interior points, ``dx = L / (N + 1)``; periodic: ``N`` points, ``dx = L / N``),
``c`` the wave speed (a pyMOR parameter), ``s`` the strength of the
nonlinearity (a constant of the model).  With ``D`` the SPD (Dirichlet) or
positive semi-definite (periodic) central-difference matrix of ``-d^2/dx^2``
and ``x = (q, p) = (u, u_t)`` at the grid points,

    H(q, p; c) = 1/2 p.p + 1/2 c^2 q.D q + s sum_i (1 - cos q_i),
    x' = J grad H(x),   grad H = (c^2 D q + s sin q, p).

``H`` is the grid Hamiltonian in canonical coordinates (it gives exactly the
semi-discrete equations with the canonical ``J``); the continuum energy
``E = int 1/2 u_t^2 + 1/2 c^2 u_x^2 + s (1 - cos u) dx`` is approximated by
``dx H`` (:meth:`SineGordonFOM.energy`).  Scaling ``H`` itself by ``dx`` would
need ``p = dx u_t`` to stay canonical; we keep ``p = u_t``.

The pyMOR model (:attr:`SineGordonFOM.model`) is an ``InstationaryModel``
``d_t x + A(x; c) = 0`` with the nonlinear operator ``A(x; c) = -J grad H(x; c)``
(:class:`SineGordonOperator`, with its Jacobian) on the blocked phase space
``(q, p)``, parameters ``c`` and ``amplitude`` (the initial state is
``amplitude * u0``, ``u0`` one member of the initial-data families below), and
a compiled symplectic time stepper (:class:`CompiledSymplecticTimeStepper`:
Kahan–Li order 6 from :mod:`sympredict.symplectic.integrators_compiled`, sub-steps chosen
so that ``h omega_max <= 0.5``).  pyMOR 2026.1 has Hamiltonian models only
for quadratic ``H`` (``QuadraticHamiltonianModel``); the nonlinear one is a
generic ``InstationaryModel``.

Reference trajectories (:meth:`SineGordonFOM.reference_trajectory`) halve the
step of the compiled Kahan–Li-6 composition until two successive results agree
to ``tol``.

Initial-data families (all decay to 0 at the boundary for ``L`` large against
the length scale ``l = c / sqrt(s)``): breathers (exact on the line),
kink–antikink pairs (superposed travelling kinks), windowed ``sech * cos``
states, and random smooth states of bounded energy.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
from pymor.algorithms.timestepping import TimeStepper
from pymor.operators.interface import Operator

from sympredict._checks import as_choice, as_parameter, as_positive_int, as_real, as_states, as_steps
from sympredict.symplectic.metrics import j_times
from sympredict.symplectic.integrators_compiled import (
    PointwiseHamiltonian,
    csr_fill_dense,
    csr_matvec,
    jit_pointwise,
    rollout,
    unit_mass_grad_T,
)

__all__ = [
    "fd_laplacian_1d",
    "laplacian_max_eigenvalue",
    "SineGordonFOM",
    "SineGordonOperator",
    "CompiledSymplecticTimeStepper",
    "INITIAL_FAMILIES",
]

BOUNDARIES = ("dirichlet", "periodic")
INITIAL_FAMILIES = ("breather", "kink_antikink", "sech_cos")

#: ``h omega_max`` of the reference and of the model's time stepper (Kahan–Li-6 is stable well beyond).
_H_OMEGA = 0.5


def fd_laplacian_1d(n_points: int, length: float, boundary: str = "dirichlet") -> sps.csr_matrix:
    """Central-difference matrix of ``-d^2/dx^2``: ``tridiag(-1, 2, -1) / dx^2`` (periodic: circulant).

    Dirichlet: ``dx = L / (N + 1)`` (interior points); periodic: ``dx = L / N``.
    Returns a CSR matrix (N, N) with sorted indices.
    """
    n_points = as_positive_int(n_points, "n_points", minimum=3)
    length = as_real(length, "length", positive=True)
    as_choice(boundary, "boundary", BOUNDARIES)
    dx = length / (n_points + 1) if boundary == "dirichlet" else length / n_points
    off = -np.ones(n_points - 1)
    D = sps.diags([off, 2.0 * np.ones(n_points), off], [-1, 0, 1], format="lil")
    if boundary == "periodic":
        D[0, n_points - 1] = -1.0
        D[n_points - 1, 0] = -1.0
    D = (D.tocsr() / dx**2).tocsr()
    D.sort_indices()
    return D


def laplacian_max_eigenvalue(n_points: int, length: float, boundary: str = "dirichlet") -> float:
    """Largest eigenvalue of :func:`fd_laplacian_1d` (an upper bound ``4 / dx^2`` for both boundaries)."""
    dx = length / (n_points + 1) if boundary == "dirichlet" else length / n_points
    return 4.0 / dx**2


# --------------------------------------------------------------- compiled per-instance functions
# mu = (c,); fargs = (s, D.data...); iargs = (D.indptr, D.indices) in CSR.  O(nnz(D)) = O(N) per gradient.
@jit_pointwise
def _grad_V(q, mu, fargs, iargs, out):
    """``c^2 D q + s sin q``."""
    csr_matvec(q, mu[0] * mu[0], fargs[1:], iargs, out)
    s = fargs[0]
    for j in range(q.shape[0]):
        out[j] += s * np.sin(q[j])


@jit_pointwise
def _grad_H(x, mu, fargs, iargs, out):
    """``(c^2 D q + s sin q, p)``."""
    n = x.shape[0] // 2
    _grad_V(x[:n], mu, fargs, iargs, out[:n])
    unit_mass_grad_T(x[n:], mu, fargs, iargs, out[n:])


@jit_pointwise
def _hess_H(x, mu, fargs, iargs, out):
    """``diag(c^2 D + s diag(cos q), I)``, dense (``O(N^2)`` writes: small ``N`` only)."""
    n = x.shape[0] // 2
    out[:, :] = 0.0
    csr_fill_dense(n, mu[0] * mu[0], fargs[1:], iargs, out)
    for j in range(n):
        out[j, j] += fargs[0] * np.cos(x[j])
        out[n + j, n + j] = 1.0


class SineGordonFOM:
    """The sine-Gordon full-order model: equations, compiled reference, initial data and the pyMOR model.

    Parameters
    ----------
    n_points
        Grid points ``N`` (state dimension ``2N``).
    length
        Domain length ``L``.
    boundary
        ``'dirichlet'`` or ``'periodic'``.
    strength
        ``s`` in ``- s sin(u)`` (``s >= 0``; ``s = 0`` is the linear wave).
    T
        Final time of the pyMOR model.
    nt
        Output steps of the pyMOR model over ``[0, T]``.
    c_range, amplitude_range
        Declared parameter ranges; ``c`` outside ``c_range`` raises ``ValueError``.
    initial
        Initial-data family of the pyMOR model (:data:`INITIAL_FAMILIES`); its
        state at ``amplitude = 1`` (:meth:`initial_state`) is scaled by the
        parameter ``amplitude``.
    initial_options : dict, optional
        Keyword arguments of the family's method (e.g. ``{"omega": 0.6}``).

    Attributes
    ----------
    D : scipy.sparse.csr_matrix of shape (N, N)
    x : ndarray of shape (N,)
        Grid points.
    dx : float
    model : pymor.models.basic.InstationaryModel
    phase_space : pymor BlockVectorSpace (q, p)
    """

    def __init__(
        self,
        n_points: int = 1000,
        length: float = 20.0,
        boundary: str = "dirichlet",
        strength: float = 1.0,
        T: float = 10.0,
        nt: int = 100,
        c_range=(0.8, 1.2),
        amplitude_range=(0.5, 1.5),
        initial: str = "sech_cos",
        initial_options=None,
    ):
        self.n_points = as_positive_int(n_points, "n_points", minimum=3)
        self.length = as_real(length, "length", positive=True)
        self.strength = as_real(strength, "strength")
        if self.strength < 0:
            raise ValueError(f"strength must be >= 0, got {strength!r}")
        self.D = fd_laplacian_1d(self.n_points, self.length, boundary)
        self.boundary = boundary
        if boundary == "dirichlet":
            self.dx = self.length / (self.n_points + 1)
            self.x = self.dx * np.arange(1, self.n_points + 1)
        else:
            self.dx = self.length / self.n_points
            self.x = self.dx * np.arange(self.n_points)
        self.c_range = self._range(c_range, "c_range")
        self.amplitude_range = self._range(amplitude_range, "amplitude_range")
        self.initial = as_choice(initial, "initial", INITIAL_FAMILIES)
        self.initial_options = dict(initial_options or {})
        self.T = as_real(T, "T", positive=True)
        self.nt = as_positive_int(nt, "nt")
        self._build_model()

    @staticmethod
    def _range(r, name):
        if len(r) != 2:
            raise ValueError(f"{name} must be (min, max), got {r!r}")
        lo, hi = (as_real(v, name) for v in r)
        if not (0 < lo <= hi):
            raise ValueError(f"{name} must satisfy 0 < min <= max, got {r!r}")
        return (lo, hi)

    @property
    def dim(self) -> int:
        """Phase-space dimension ``2N``."""
        return 2 * self.n_points

    def check_c(self, c, b: int) -> np.ndarray:
        """Wave speeds as an array (b,); ``ValueError`` outside ``c_range``."""
        c = as_parameter(c, b, 1, name="c")[:, 0]  # a float or (b,), finite
        lo, hi = self.c_range
        if np.any(c < lo * (1 - 1e-12)) or np.any(c > hi * (1 + 1e-12)):
            raise ValueError(f"c must lie in the declared range [{lo}, {hi}], got {c}")
        return c

    def omega_max(self, c: float) -> float:
        """Bound of the largest linearized frequency ``sqrt(c^2 lambda_max(D) + s)``."""
        return float(
            np.sqrt(c * c * laplacian_max_eigenvalue(self.n_points, self.length, self.boundary) + self.strength)
        )

    # ----------------------------------------------------------------- physics (NumPy, batched)
    def hamiltonian(self, x, c) -> np.ndarray:
        """Grid Hamiltonian ``H`` (B,) of states (B, 2N); ``O(B N)``."""
        x, _ = as_states(x, "x", dim=self.dim)
        c = self.check_c(c, len(x))
        n = self.n_points
        q, p = x[:, :n], x[:, n:]
        return (
            0.5 * np.einsum("bi,bi->b", p, p)
            + 0.5 * c**2 * np.einsum("bi,bi->b", q, (self.D @ q.T).T)
            + self.strength * np.sum(1.0 - np.cos(q), axis=1)
        )

    def energy(self, x, c) -> np.ndarray:
        """Continuum energy ``dx H`` (B,)."""
        return self.dx * self.hamiltonian(x, c)

    def gradient(self, x, c) -> np.ndarray:
        """``grad H = (c^2 D q + s sin q, p)``, shape (B, 2N); ``O(B N)``."""
        x, _ = as_states(x, "x", dim=self.dim)
        c = self.check_c(c, len(x))
        n = self.n_points
        q = x[:, :n]
        return np.hstack([(c**2)[:, None] * (self.D @ q.T).T + self.strength * np.sin(q), x[:, n:]])

    def hessian_sparse(self, x, c: float) -> sps.csr_matrix:
        """``diag(c^2 D + s diag(cos q), I)`` of one state (2N,), sparse (2N, 2N)."""
        x = np.asarray(x, dtype=float).reshape(-1)
        n = self.n_points
        c = float(self.check_c(c, 1)[0])
        return sps.block_diag(
            [c * c * self.D + sps.diags(self.strength * np.cos(x[:n])), sps.identity(n)], format="csr"
        )

    def hessian(self, x, c) -> np.ndarray:
        """Dense Hessians (B, 2N, 2N): for small ``N`` only."""
        x, _ = as_states(x, "x", dim=self.dim)
        c = self.check_c(c, len(x))
        return np.stack([self.hessian_sparse(xi, ci).toarray() for xi, ci in zip(x, c)])

    def pointwise(self) -> PointwiseHamiltonian:
        """Per-instance compiled gradients for :func:`sympredict.symplectic.integrators_compiled.rollout` (``mu = (c,)``).

        Separable: every scheme applies; ``grad V`` costs ``O(nnz(D)) = O(N)``.
        Implicit midpoint uses a dense Jacobian (``O(N^3)`` per Newton iteration): small ``N`` only.
        """
        return PointwiseHamiltonian.unit_mass_csr(
            self.D,
            grad_V=_grad_V,
            grad_H=_grad_H,
            hess_H=_hess_H,
            head=(self.strength,),
            check_mu=lambda mu: self.check_c(np.asarray(mu)[:, 0], len(mu)),
            name=f"SineGordonFOM(N={self.n_points})",
        )

    # ----------------------------------------------------------------- reference flow
    def reference_trajectory(
        self, x0, c, dt: float, n_steps: int, tol: float = 1e-10, max_doublings: int = 6, return_error: bool = False
    ):
        """Compiled Kahan–Li-6 trajectories, sub-steps doubled until two results agree to ``tol``.

        Starts with ``h omega_max <= 0.5``; the returned trajectory is the finer
        of the last two, and the estimate is ``max |x_2r - x_r|`` (its error is
        about ``2^-6`` of that).  ``O(B K r N)``.

        Parameters
        ----------
        x0 : array_like of shape (B, 2N) or (2N,)
        c : float or array_like of shape (B,)
        dt : float
            Output spacing.
        n_steps : int

        Returns
        -------
        ndarray of shape (B, K+1, 2N) (or (K+1, 2N)); with ``return_error``, also the estimate (float).

        Raises
        ------
        RuntimeError
            If ``max_doublings`` doublings do not reach ``tol``.
        """
        x0, single = as_states(x0, "x0", dim=self.dim)
        c = self.check_c(c, len(x0))
        dt = float(as_steps(dt, 1)[0])
        r = max(1, int(np.ceil(dt * self.omega_max(float(c.max())) / _H_OMEGA)))
        coarse = rollout(self, x0, c[:, None], dt, n_steps, scheme="kahan_li6", substeps=r)
        for _ in range(max_doublings):
            r *= 2
            fine = rollout(self, x0, c[:, None], dt, n_steps, scheme="kahan_li6", substeps=r)
            err = float(np.max(np.abs(fine - coarse)))
            if err <= tol:
                out = fine[0] if single else fine
                return (out, err) if return_error else out
            coarse = fine
        raise RuntimeError(
            f"reference trajectory: step halving did not reach tol = {tol:.1e} (last difference {err:.1e})"
        )

    # ----------------------------------------------------------------- initial data (amplitude 1)
    def _scales(self, c: float):
        s = self.strength if self.strength > 0 else 1.0
        return c / np.sqrt(s), np.sqrt(s)  # length scale l, frequency scale w0

    def breather(self, c: float = 1.0, omega: float = 0.6, center=None) -> np.ndarray:
        """Breather at its zero crossing: ``q = 0``, ``p = 4 w0 sqrt(1 - omega^2) / cosh(sqrt(1 - omega^2) (x - x0) / l)``.

        Exact solution on the line, ``u = 4 arctan(sqrt(1 - w^2)/w sin(w w0 t) / cosh(sqrt(1 - w^2)(x - x0)/l))``
        (:meth:`breather_exact`), ``l = c / sqrt(s)``, ``w0 = sqrt(s)``; shape (2N,).
        """
        if not 0 < omega < 1:
            raise ValueError(f"omega must lie in (0, 1), got {omega!r}")
        center = self.length / 2 if center is None else float(center)
        ell, w0 = self._scales(c)
        k = np.sqrt(1 - omega**2)
        return np.concatenate([np.zeros(self.n_points), 4 * w0 * k / np.cosh(k * (self.x - center) / ell)])

    def breather_exact(self, t, c: float = 1.0, omega: float = 0.6, center=None) -> np.ndarray:
        """The breather on the line at times ``t`` (T,), states (T, 2N) (the oracle of :meth:`breather`)."""
        center = self.length / 2 if center is None else float(center)
        ell, w0 = self._scales(c)
        k = np.sqrt(1 - omega**2)
        t = np.asarray(t, dtype=float).reshape(-1, 1)
        a = (k / omega) * np.sin(omega * w0 * t)
        sech = 1.0 / np.cosh(k * (self.x[None, :] - center) / ell)
        q = 4 * np.arctan(a * sech)
        da = (k / omega) * omega * w0 * np.cos(omega * w0 * t)
        p = 4 * da * sech / (1 + (a * sech) ** 2)
        return np.hstack([q, p])

    def kink_antikink(self, c: float = 1.0, velocity: float = 0.5, separation: float = 6.0, center=None) -> np.ndarray:
        """A kink at ``x0 - d/2`` moving right and an antikink at ``x0 + d/2`` moving left, speed ``v c``; (2N,).

        ``u = 4 arctan(e^{z1}) + 4 arctan(e^{z2}) - 2 pi``, ``z1 = g (xi - xi1 - v tau)``,
        ``z2 = -g (xi - xi2 + v tau)``, ``g = 1 / sqrt(1 - v^2)``, ``xi = x / l``, ``tau = w0 t``:
        zero far from the pair, ``2 pi`` between.
        """
        if not 0 <= velocity < 1:
            raise ValueError(f"velocity must lie in [0, 1), got {velocity!r}")
        center = self.length / 2 if center is None else float(center)
        ell, w0 = self._scales(c)
        g = 1.0 / np.sqrt(1 - velocity**2)
        z1 = g * (self.x - center + separation / 2) / ell
        z2 = -g * (self.x - center - separation / 2) / ell
        q = 4 * np.arctan(np.exp(z1)) + 4 * np.arctan(np.exp(z2)) - 2 * np.pi
        p = -2 * g * velocity * w0 * (1 / np.cosh(z1) + 1 / np.cosh(z2))
        return np.concatenate([q, p])

    def sech_cos(self, width: float = 2.0, wavenumber: float = 1.0, center=None) -> np.ndarray:
        """Windowed state ``q = sech((x - x0)/w) cos(k (x - x0))``, ``p = 0`` (amplitude 1); (2N,)."""
        center = self.length / 2 if center is None else float(center)
        xi = self.x - center
        return np.concatenate([np.cos(wavenumber * xi) / np.cosh(xi / width), np.zeros(self.n_points)])

    def energy_bounded_states(
        self, n_states: int, energy: float, c: float = 1.0, n_modes: int = 8, seed: int = 0
    ) -> np.ndarray:
        """Random smooth states (first ``n_modes`` sine modes of ``(0, L)``) with ``dx H <= energy``; (n, 2N).

        A random direction (coefficients ``~ 1/k``) is scaled by bisection on
        ``lambda`` until ``dx H(lambda x) = U energy``, ``U`` uniform in ``(0, 1]``
        (``H(lambda x)`` increases along the ray while ``|q| < pi``; the
        bisection keeps ``|q| <= pi``).
        """
        n_states = as_positive_int(n_states, "n_states")
        energy = as_real(energy, "energy", positive=True)
        rng = np.random.default_rng(seed)
        k = np.arange(1, n_modes + 1)
        modes = np.sin(np.pi * np.outer(self.x, k) / self.length)  # (N, K), zero at both ends
        out = np.empty((n_states, self.dim))
        for i in range(n_states):
            a, b = rng.normal(size=(2, n_modes)) / k
            d = np.concatenate([modes @ a, modes @ b])
            target = rng.uniform(0.05, 1.0) * energy
            hi = np.pi / max(np.abs(d[: self.n_points]).max(), 1e-300)
            if self.energy(hi * d, c)[0] < target:
                out[i] = hi * d
                continue
            lo = 0.0
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if self.energy(mid * d, c)[0] < target else (lo, mid)
            out[i] = lo * d
        return out

    def initial_state(self, c: float = 1.0) -> np.ndarray:
        """The model's initial state at ``amplitude = 1`` (family :attr:`initial`); (2N,).

        The breather and the kink pair are built at the centre of ``c_range``
        (one fixed state for all ``c``: the pyMOR initial data are linear in ``amplitude`` only).
        """
        if self.initial == "breather":
            return self.breather(c, **self.initial_options)
        if self.initial == "kink_antikink":
            return self.kink_antikink(c, **self.initial_options)
        return self.sech_cos(**self.initial_options)

    # ----------------------------------------------------------------- pyMOR
    def _build_model(self):
        from pymor.models.basic import InstationaryModel
        from pymor.operators.constructions import LincombOperator, VectorOperator
        from pymor.parameters.functionals import ProjectionParameterFunctional
        from pymor.vectorarrays.block import BlockVectorSpace
        from pymor.vectorarrays.numpy import NumpyVectorSpace

        space = NumpyVectorSpace(self.n_points)
        self.phase_space = BlockVectorSpace([space, space])
        self.operator = SineGordonOperator(self)
        u0 = self.to_pymor(self.initial_state(0.5 * sum(self.c_range)))
        initial = LincombOperator([VectorOperator(u0)], [ProjectionParameterFunctional("amplitude")])
        self.model = InstationaryModel(
            self.T,
            initial,
            self.operator,
            None,
            time_stepper=CompiledSymplecticTimeStepper(self.nt),
            name="sine_gordon",
        )
        self.parameter_space = self.model.parameters.space({"amplitude": self.amplitude_range, "c": self.c_range})

    def to_pymor(self, x):
        """States (K, 2N) or (2N,) -> VectorArray of length K in :attr:`phase_space`."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        n = self.n_points
        q_space, p_space = self.phase_space.subspaces
        return self.phase_space.make_array([q_space.from_numpy(x[:, :n].T), p_space.from_numpy(x[:, n:].T)])

    def from_pymor(self, U) -> np.ndarray:
        """VectorArray in :attr:`phase_space` -> states (K, 2N)."""
        return np.vstack([b.to_numpy() for b in U.blocks]).T


class SineGordonOperator(Operator):
    """The nonlinear pyMOR operator ``A(x; c) = -J grad H(x; c)`` (``d_t x + A(x) = 0``) on the blocked phase space.

    ``apply`` is ``O(K N)`` for ``K`` vectors; ``jacobian`` returns the sparse
    ``-J hess H(x)`` as a ``NumpyMatrixOperator`` on the blocks.  The FOM is
    reachable as :attr:`fom` (its compiled ``pointwise()`` is what
    :class:`CompiledSymplecticTimeStepper` integrates).
    """

    linear = False

    def __init__(self, fom, name="sine_gordon_operator"):
        from pymor.parameters.base import Parameters

        self.fom = fom
        self.source = self.range = fom.phase_space
        self.parameters_own = Parameters({"c": 1})
        self.name = name

    def c_of(self, mu) -> float:
        """The wave speed of pyMOR parameter values (a ``Mu`` with at least ``c``)."""
        if mu is None or "c" not in mu:
            raise ValueError(f"the sine-Gordon operator needs the parameter c, got {mu!r}")
        return float(np.asarray(mu["c"]).reshape(-1)[0])

    def apply(self, U, mu=None):
        assert U in self.source
        c = self.c_of(mu)
        x = self.fom.from_pymor(U)
        g = self.fom.gradient(x, np.full(len(x), c)) if len(x) else x
        return self.fom.to_pymor(-j_times(g)) if len(x) else self.range.zeros(0)

    def jacobian(self, U, mu=None):
        from pymor.operators.block import BlockOperator
        from pymor.operators.numpy import NumpyMatrixOperator

        assert len(U) == 1
        c = self.c_of(mu)
        hess = self.fom.hessian_sparse(self.fom.from_pymor(U)[0], c)
        n = self.fom.n_points
        Hq, Hp = hess[:n, :n], hess[n:, n:]
        # -J hess H = [[0, -Hp], [Hq, 0]]
        return BlockOperator([[None, NumpyMatrixOperator(-Hp)], [NumpyMatrixOperator(Hq), None]])


class CompiledSymplecticTimeStepper(TimeStepper):
    """pyMOR time stepper running the compiled Kahan–Li-6 composition of an operator's FOM.

    For operators with a ``fom`` having ``pointwise()``, ``omega_max(c)`` and
    ``from_pymor``/``to_pymor`` (:class:`SineGordonOperator`); no right-hand
    side or mass.  ``nt`` output steps, each of ``ceil(dt omega_max / 0.5)`` sub-steps.
    """

    def __init__(self, nt, scheme="kahan_li6"):
        self.nt = nt
        self.scheme = scheme

    def estimate_time_step_count(self, initial_time, end_time):
        return self.nt

    def iterate(self, initial_time, end_time, initial_data, operator, rhs=None, mass=None, mu=None, num_values=None):
        if rhs is not None or mass is not None:
            raise ValueError("CompiledSymplecticTimeStepper: no right-hand side or mass supported")
        fom = operator.fom
        c = operator.c_of(mu)
        dt = (end_time - initial_time) / self.nt
        r = max(1, int(np.ceil(abs(dt) * fom.omega_max(c) / _H_OMEGA)))
        x0 = fom.from_pymor(initial_data)
        traj = rollout(fom, x0, np.full((len(x0), 1), c), dt, self.nt, scheme=self.scheme, substeps=r)[0]
        if num_values and (num_values < 2 or self.nt % (num_values - 1)):
            raise ValueError(f"num_values - 1 must divide nt = {self.nt}, got num_values = {num_values}")
        every = 1 if not num_values else self.nt // (num_values - 1)
        for k in range(0, self.nt + 1, every):
            yield fom.to_pymor(traj[k]), initial_time + k * dt
