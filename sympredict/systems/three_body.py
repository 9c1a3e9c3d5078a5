"""The planar circular restricted three-body problem in the rotating frame.

Two primaries of masses ``1 - mu`` and ``mu`` (the mass ratio, the parameter)
circle their barycentre with unit angular velocity at unit distance; in the
frame rotating with them they sit at ``(-mu, 0)`` and ``(1 - mu, 0)``.  A test
particle of negligible mass has the Hamiltonian

``H(q, p; mu) = (px^2 + py^2)/2 + y px - x py - (1 - mu)/r1 - mu/r2``,

state ``x = (q1, q2, p1, p2) = (x, y, px, py)``, ``r1 = |(x + mu, y)|``,
``r2 = |(x - 1 + mu, y)|``.  The velocity in the rotating frame is
``(vx, vy) = (px + y, py - x)``, and the Jacobi constant is
``C = 2 Omega - |v|^2 = -2 H`` with ``Omega = (x^2 + y^2)/2 + (1 - mu)/r1 + mu/r2``.

Not separable (the Coriolis terms ``y px - x py``), so the reference flow is a
high-order adaptive Runge–Kutta method (scipy's DOP853, tight tolerances) on
the whole batch at once, not a symplectic composition.

The five Lagrange points are the equilibria: ``L4, L5 = (1/2 - mu, +-sqrt(3)/2)``
(linearly stable for ``mu < mu_Routh = (1 - sqrt(69)/9)/2 ~ 0.0385``) and
``L1, L2, L3`` on the x-axis (roots of ``dOmega/dx = 0``), all with zero
velocity in the rotating frame (``p = (-y, x)``).  :func:`librating_states`
samples states near ``L4`` (tadpole librations for small amplitudes), the
data box of this module's experiments.  :data:`MU_RANGE` contains the 3:1
resonance of the two libration frequencies at L4 (``mu ~ 0.01352``, where L4 is
nonlinearly unstable): there, even small librations grow and escape after a few
tens of time units (they may then pass close to the smaller primary), so long
rollouts in this range include chaotic orbits.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from sympredict._checks import as_parameter, as_positive_int, as_real, as_states, as_steps
from sympredict.exceptions import SympredictError
from sympredict.systems.flowmaps import _ScalarParameterSystem

__all__ = ["ThreeBody", "MU_RANGE", "ROUTH_MU", "lagrange_points", "librating_states"]

#: The mass-ratio range of the experiments (below Routh's critical ratio: L4 is stable).
MU_RANGE = (0.010, 0.014)

#: Routh's critical mass ratio: L4 and L5 are linearly stable for ``mu`` below it.
ROUTH_MU = 0.5 * (1.0 - np.sqrt(69.0) / 9.0)


class ThreeBody(_ScalarParameterSystem):
    """Planar circular restricted three-body problem, rotating frame, ``x = (x, y, px, py)``, ``mu`` = mass ratio."""

    dim = 4
    parameter_name = "mu (three-body mass ratio)"
    parameter_bounds = (0, 0.5)

    @staticmethod
    def _distances(x, mu):
        dx1 = x[:, 0] + mu
        dx2 = x[:, 0] - 1.0 + mu
        y = x[:, 1]
        r1 = np.sqrt(dx1 * dx1 + y * y)
        r2 = np.sqrt(dx2 * dx2 + y * y)
        return dx1, dx2, y, r1, r2

    def _geometry(self, x, mu):
        """``(x, mu, (dx1, dx2, y, r1, r2, (1 - mu) / r1^3, mu / r2^3))``: the states as floats, the mass ratios,
        the offsets and distances to the primaries and the inverse cubes the gradient and the Hessian share."""
        x = np.asarray(x, dtype=float)
        mu = self._parameter(mu, len(x))
        dx1, dx2, y, r1, r2 = self._distances(x, mu)
        return x, mu, (dx1, dx2, y, r1, r2, (1.0 - mu) / r1**3, mu / r2**3)

    def hamiltonian(self, x, mu) -> np.ndarray:
        """Energies (B,) of states (B, 4) for mass ratios ``mu`` (B,) or (B, 1)."""
        x, _ = as_states(x, "x", dim=4)
        mu = self._parameter(mu, len(x))
        _, _, _, r1, r2 = self._distances(x, mu)
        px, py = x[:, 2], x[:, 3]
        return 0.5 * (px * px + py * py) + x[:, 1] * px - x[:, 0] * py - (1.0 - mu) / r1 - mu / r2

    def jacobi_constant(self, x, mu) -> np.ndarray:
        """Jacobi constants ``C = 2 Omega - |v|^2 = -2 H``, shape (B,)."""
        return -2.0 * self.hamiltonian(x, mu)

    def gradient(self, x, mu) -> np.ndarray:
        """``grad H = (dH/dx, dH/dy, dH/dpx, dH/dpy)``, shape (B, 4)."""
        x, mu, (dx1, dx2, y, r1, r2, a, c) = self._geometry(x, mu)
        px, py = x[:, 2], x[:, 3]
        return np.column_stack([-py + a * dx1 + c * dx2, px + a * y + c * y, px + y, py - x[:, 0]])

    def hessian(self, x, mu) -> np.ndarray:
        """``grad^2 H``, shape (B, 4, 4)."""
        x, mu, (dx1, dx2, y, r1, r2, a3, c3) = self._geometry(x, mu)
        a5 = 3.0 * (1.0 - mu) / r1**5
        c5 = 3.0 * mu / r2**5
        hess = np.zeros((len(x), 4, 4))
        hess[:, 0, 0] = a3 + c3 - a5 * dx1 * dx1 - c5 * dx2 * dx2
        hess[:, 1, 1] = a3 + c3 - (a5 + c5) * y * y
        hess[:, 0, 1] = hess[:, 1, 0] = -(a5 * dx1 + c5 * dx2) * y
        hess[:, 0, 3] = hess[:, 3, 0] = -1.0
        hess[:, 1, 2] = hess[:, 2, 1] = 1.0
        hess[:, 2, 2] = hess[:, 3, 3] = 1.0
        return hess

    def vector_field(self, x, mu) -> np.ndarray:
        """``J grad H = (dH/dp, -dH/dq)``, shape (B, 4)."""
        g = self.gradient(x, mu)
        return np.column_stack([g[:, 2], g[:, 3], -g[:, 0], -g[:, 1]])

    def trajectory(self, x0, mu, dt, n_steps: int, rtol: float = 1e-12, atol: float = 1e-13) -> np.ndarray:
        """Reference trajectories on the macro grid ``t_k = k dt`` (DOP853, whole batch as one system).

        Time is rescaled per instance (``s = t / dt``), so instances with
        different macro steps share one grid ``s = 0, 1, ..., K``.

        Parameters
        ----------
        x0 : array_like of shape (B, 4) or (4,)
        mu : float or array_like of shape (B,)
            Mass ratio per instance.
        dt : float or array_like of shape (B,)
            Macro steps.
        n_steps : int
        rtol, atol : float
            DOP853's tolerances (on the batch's stacked state; the step is the
            smallest any instance needs).

        Returns
        -------
        ndarray of shape (B, K+1, 4)

        Raises
        ------
        SympredictError
            If the integrator fails or a state becomes non-finite (a collision with a primary).

        Notes
        -----
        ``O(B K s)`` gradient evaluations, ``s`` DOP853 stages per macro step
        (about 12 per accepted step, a few accepted steps per unit time at these tolerances).
        """
        x0, single = as_states(x0, "x0", dim=4)
        b = len(x0)
        mu = self._parameter(mu, b)
        dt = as_steps(dt, b)
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        rtol = as_real(rtol, "rtol", positive=True)
        atol = as_real(atol, "atol", positive=True)
        traj = np.empty((b, n_steps + 1, 4))
        traj[:, 0] = x0
        if n_steps:

            def rhs(_, z):
                return (dt[:, None] * self.vector_field(z.reshape(b, 4), mu)).ravel()

            sol = solve_ivp(
                rhs,
                (0.0, float(n_steps)),
                x0.ravel(),
                method="DOP853",
                rtol=rtol,
                atol=atol,
                t_eval=np.arange(n_steps + 1, dtype=float),
            )
            if not sol.success or sol.y.shape[1] != n_steps + 1 or not np.all(np.isfinite(sol.y)):
                raise SympredictError(
                    f"three-body reference: DOP853 failed ({sol.message}); "
                    "an orbit may have come too close to a primary"
                )
            traj[:] = sol.y.T.reshape(n_steps + 1, b, 4).transpose(1, 0, 2)
            traj[:, 0] = x0
        return traj[0] if single else traj

    def flow(self, x0, mu, t, rtol: float = 1e-12, atol: float = 1e-13) -> np.ndarray:
        """Reference flow ``Phi_mu^t(x0)`` (:meth:`trajectory` with one macro step ``t``), shape of ``x0``."""
        return self._one_step(x0, mu, t, rtol=rtol, atol=atol)


def lagrange_points(mu: float) -> np.ndarray:
    """The five equilibria ``L1 ... L5`` for mass ratio ``mu`` in ``(0, 0.5]``, as states, shape (5, 4).

    ``L1`` between the primaries, ``L2`` beyond the smaller one, ``L3`` beyond the larger one
    (roots of ``dOmega/dx = x - (1-mu)(x+mu)/|x+mu|^3 - mu(x-1+mu)/|x-1+mu|^3`` by Brent's method),
    ``L4``/``L5`` at ``(1/2 - mu, +-sqrt(3)/2)``; momenta ``p = (-y, x)`` (zero rotating-frame velocity).
    """
    mu = as_real(mu, "mu", positive=True)
    if mu > 0.5:
        raise ValueError(f"mu must lie in (0, 0.5], got {mu!r}")

    def d_omega(x):
        return x - (1 - mu) * (x + mu) / abs(x + mu) ** 3 - mu * (x - 1 + mu) / abs(x - 1 + mu) ** 3

    eps = 1e-9
    x1 = brentq(d_omega, -mu + eps, 1 - mu - eps, xtol=1e-15, rtol=4 * np.finfo(float).eps)
    x2 = brentq(d_omega, 1 - mu + eps, 2.0, xtol=1e-15, rtol=4 * np.finfo(float).eps)
    x3 = brentq(d_omega, -2.0, -mu - eps, xtol=1e-15, rtol=4 * np.finfo(float).eps)
    pos = np.array([[x1, 0.0], [x2, 0.0], [x3, 0.0], [0.5 - mu, np.sqrt(3) / 2], [0.5 - mu, -np.sqrt(3) / 2]])
    return np.column_stack([pos, -pos[:, 1], pos[:, 0]])


def librating_states(
    mu, n_samples: int, radial: float = 0.01, angle: float = 0.15, speed: float = 0.005, seed: int = 0
) -> np.ndarray:
    """States near ``L4`` on nearly circular orbits: tadpole librations for small amplitudes.

    In polar coordinates about the barycentre, ``r = 1 + dr`` and
    ``theta = pi/3 + dtheta`` with ``dr``, ``dtheta`` uniform in
    ``[-radial, radial]``, ``[-angle, angle]``; the rotating-frame velocity is
    that of a circular Kepler orbit about unit mass, ``(r^-1/2 - r)`` along
    ``theta``, plus a perturbation uniform in the disc of ``speed``; momenta
    ``p = v + (-y, x)``.  (A radial offset at rest in the rotating frame would
    drift along the orbit at ``1.5 dr``: small radial offsets keep the orbits
    tadpoles instead of horseshoes.)

    Parameters
    ----------
    mu : float or array_like of shape (n_samples,)
        Mass ratio(s) (the barycentre frame's ``L4`` is at unit distance for every ``mu``).
    n_samples : int
    radial, angle, speed : float
        Amplitudes of the radial offset, the angle offset (radians) and the velocity perturbation.
    seed : int

    Returns
    -------
    ndarray of shape (n_samples, 4)
    """
    n_samples = as_positive_int(n_samples, "n_samples")
    radial = as_real(radial, "radial", nonnegative=True)
    angle = as_real(angle, "angle", nonnegative=True)
    speed = as_real(speed, "speed", nonnegative=True)
    as_parameter(mu, n_samples, 1, name="mu (three-body mass ratio)")
    rng = np.random.default_rng(seed)
    r = 1.0 + rng.uniform(-radial, radial, n_samples)
    th = np.pi / 3 + rng.uniform(-angle, angle, n_samples)
    ang = rng.uniform(0, 2 * np.pi, n_samples)
    amp = speed * np.sqrt(rng.uniform(0, 1, n_samples))
    vt = 1.0 / np.sqrt(r) - r
    q = np.column_stack([r * np.cos(th), r * np.sin(th)])
    v = np.column_stack([-vt * np.sin(th) + amp * np.cos(ang), vt * np.cos(th) + amp * np.sin(ang)])
    return np.column_stack([q, v[:, 0] - q[:, 1], v[:, 1] + q[:, 0]])
