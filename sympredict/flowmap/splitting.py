"""Exact-linear-flow splitting ("interaction picture") around a learned symplectic step.

With the quadratic part ``H0(x; mu) = 1/2 x^T A(mu) x`` of the Hamiltonian
(usually its Hessian at the equilibrium; :class:`~sympredict.systems.linear_flow.QuadraticPart`)
and ``L_h = expm(h J A(mu))``, ``h = dT / 2``, the predicted step is the
Strang-type composition

    Phi(x) = L_h S(L_h x; mu, dT),

with ``S`` a :class:`~sympredict.SymplecticKernelPredictor` fitted on the
transformed samples ``(L_h x0, L_{-h} x1)``.  Properties (verified in
``tests/flowmap/test_splitting.py``):

* symplectic: a composition of symplectic maps, ``DPhi = L_h DS L_h`` and
  ``DPhi^T J DPhi = J`` whenever ``DS^T J DS = J``;
* exact on a linear system with Hamiltonian ``H0``: there ``S`` is the
  identity (all targets are zero; the greedy stops with 0 centres);
* on small orbits ``S - id`` is of the order of the nonlinear remainder
  (``O(|x|^3)`` for an even potential), so the kernel's absolute error floor
  no longer dominates the relative error of small orbits, and the
  ``mu``-dependence of the linear frequencies is exact (only the correction
  is interpolated in ``mu``);
* time-symmetric with ``update='midpoint'``: ``Phi_{-dT} = L_{-h} S_{-dT} L_{-h}``
  inverts ``Phi_dT`` when ``S`` does (same ``s``);
* state symmetries: a symmetry ``g`` of the flow (``g`` symplectic, ``g A g^T = A``)
  commutes with ``L_h``; a reversing symmetry ``R`` (anti-symplectic,
  ``R A R^T = A``) gives ``R L_h R^-1 = L_{-h}``, so ``S = L_{-h} Phi L_{-h}`` is
  ``R``-reversible exactly when ``Phi`` is: the inner predictor's ``symmetry``
  setting (e.g. the pendulum's Klein group with the midpoint update) stays valid.
"""

from __future__ import annotations

import numpy as np
from pymor.core.logger import getLogger

from sympredict._checks import as_model_parameter, as_positive_int, as_states, as_steps
from sympredict.base import Parametrized, clone
from sympredict.container import read_container, write_container
from sympredict.data import FlowMapData
from sympredict.exceptions import ModelFileError, NonFinitePredictionError, NotFittedError
from sympredict.systems.linear_flow import QuadraticPart, inverse_symplectic_matrices
from sympredict.estimators import model_files
from sympredict.estimators.fitted import check_finite
from sympredict.estimators.model_files import pre_release_layout
from sympredict.estimators.predictor import MODEL_FORMAT, MODEL_LAYOUT, SymplecticKernelPredictor

logger = getLogger("sympredict.flowmap.splitting")

__all__ = ["SplitKernelPredictor"]

_INNER = "inner_"  # prefix of the inner predictor's arrays in a model file


def _apply(L: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``L_b x_b`` for a batch (B, 2n, 2n) x (B, 2n): one batched matvec, ``O(B (2n)^2)``."""
    return np.ascontiguousarray(np.einsum("bij,bj->bi", L, x))


class SplitKernelPredictor(Parametrized):
    """Flow-map predictor ``Phi = L_h o S o L_h``: the exact flow of a quadratic part around a learned step.

    Parameters
    ----------
    predictor : SymplecticKernelPredictor
        The inner model ``S`` (unfitted template; :meth:`fit` fits a clone,
        ``predictor_``).  Any update, solver, or state-kernel transform (``Scaled``,
        ``Symmetric``; ``Periodic`` too).
        Its ``mu_kernel`` decides whether the model takes a parameter.
    quadratic : QuadraticPart
        ``A(mu)``; its powers use either no parameter component or all
        ``d_mu`` of the training parameter.

    Attributes
    ----------
    predictor_ : SymplecticKernelPredictor
        The fitted inner model (in the interaction-picture coordinates
        ``L_h x``).
    quadratic_ : QuadraticPart
        The validated quadratic part (float arrays).
    dim_ : int
        State dimension.
    n_mu_ : int
        Parameter dimension.

    Examples
    --------
    >>> quad = Pendulum().quadratic_part()                                   # doctest: +SKIP
    >>> inner = SymplecticKernelPredictor(IMQ(0.4), IMQ(0.75), IMQ(1.06), update="midpoint")  # doctest: +SKIP
    >>> model = SplitKernelPredictor(inner, quad).fit(x0, x1, mu=mu, dt=dt)  # doctest: +SKIP
    >>> traj = model.rollout(x_init, 400, mu=0.75, dt=0.05)                  # doctest: +SKIP
    """

    def __init__(self, predictor=None, quadratic=None):
        self.predictor = predictor
        self.quadratic = quadratic

    def __repr__(self) -> str:
        fitted = f", {self.predictor_.n_centers_} centres" if self.is_fitted else ", unfitted"
        return f"SplitKernelPredictor(predictor={self.predictor!r}, quadratic={self.quadratic!r}{fitted})"

    @property
    def is_fitted(self) -> bool:
        return hasattr(self, "predictor_")

    def _check_fitted(self):
        if not self.is_fitted:
            raise NotFittedError("this SplitKernelPredictor is not fitted yet: call fit() or load() first")

    @property
    def n_centers_(self) -> int:
        self._check_fitted()
        return self.predictor_.n_centers_

    @property
    def history_(self):
        """The inner greedy's history (``E_train(m)``, stop reason)."""
        self._check_fitted()
        return self.predictor_.history_

    # ------------------------------------------------------------- training
    def _check_settings(self, dim: int, n_mu: int) -> QuadraticPart:
        """The validated quadratic part for states of ``dim`` and ``n_mu`` parameter components (the inner
        predictor's type is checked by :meth:`fit` before the data)."""
        if not isinstance(self.quadratic, QuadraticPart):
            raise ValueError(
                f"quadratic must be a sympredict.systems.linear_flow.QuadraticPart, got {self.quadratic!r}"
            )
        mats, pw = self.quadratic.checked(dim=dim)
        if pw.shape[1] and not n_mu:
            raise ValueError(
                f"the quadratic part depends on mu ({pw.shape[1]} component(s)): pass mu (and give the "
                "inner predictor a mu_kernel)"
            )
        mats, pw = self.quadratic.checked(dim=dim, n_mu=n_mu)
        return QuadraticPart(mats, pw)

    def _propagators(self, quad: QuadraticPart, mu, dt) -> np.ndarray:
        """``L_h`` (B, 2n, 2n), ``h = dT / 2``, for validated ``mu`` (B, d_mu) and ``dt`` (B,)."""
        return quad.propagator(mu if mu.shape[1] else None, 0.5 * dt, n=len(dt))

    def _transformed(self, quad: QuadraticPart, data: FlowMapData):
        """``(L_h x0, L_{-h} x1)``: samples of ``S``."""
        L = self._propagators(quad, data.mu, data.dt)
        return _apply(L, data.x0), _apply(inverse_symplectic_matrices(L), data.x1)

    def fit(self, x0, x1, mu=None, dt=None, *, validation=None) -> "SplitKernelPredictor":
        """Fit the inner step on the transformed samples ``(L_h x0, L_{-h} x1)``.

        Arguments as in :meth:`SymplecticKernelPredictor.fit` (``dt`` is
        required: ``L_h`` needs it).  Cost: ``M`` propagators
        (``O(M (2n)^3)``) plus the inner fit.

        Returns
        -------
        self
        """
        if not isinstance(self.predictor, SymplecticKernelPredictor):
            raise ValueError(
                f"predictor must be a SymplecticKernelPredictor (the inner symplectic step S), got {self.predictor!r}"
            )
        # the inner model's own checks of the data (shapes, mu against its mu_kernel, dt against its dt_kernel)
        data, validation = self.predictor.validate_data(x0, x1, mu, dt, validation)
        dim, n_mu = data.x0.shape[1], data.mu.shape[1]
        quad = self._check_settings(dim, n_mu)
        y0, y1 = self._transformed(quad, data)
        val = None
        if validation is not None:
            v0, v1 = self._transformed(quad, validation)
            val = (v0, v1, validation.mu if n_mu else None, validation.dt)
        inner = clone(self.predictor)
        inner.fit(y0, y1, mu=data.mu if n_mu else None, dt=data.dt, validation=val)
        logger.info(
            f"split predictor: inner step fitted with {inner.n_centers_} centres ({inner.history_.stop_reason})"
        )
        self.predictor_ = inner
        self.quadratic_ = quad
        self.dim_ = dim
        self.n_mu_ = inner.n_mu_
        return self

    # -------------------------------------------------------------- queries
    def _query(self, x, mu, dt, name: str = "x"):
        """Validated states (B, 2n), single flag, mu (B, d_mu), dt (B,) and ``L_h`` (B, 2n, 2n)."""
        self._check_fitted()
        x, single = as_states(x, name, dim=self.dim_)
        b = len(x)
        mu_arr = as_model_parameter(mu, b, self.n_mu_)
        if dt is None:
            dt = self.predictor_.dt_fixed_  # a fixed-step inner model's default; None raises in as_steps
        dt_arr = as_steps(dt, b)
        try:  # mu and dt are valid here: a failure is the quadratic part's overflow at this query
            L = self._propagators(self.quadratic_, mu_arr, dt_arr)
        except ValueError:
            L = np.full((b, self.dim_, self.dim_), np.nan)
        finite = np.isfinite(L).all(axis=(1, 2))
        if not finite.all():  # the exact linear flow overflowed (a quadratic part far too stiff for dt)
            raise NonFinitePredictionError(
                np.flatnonzero(~finite), "the quadratic part's flow L_h of this SplitKernelPredictor"
            )
        return x, single, mu_arr, dt_arr, L

    def _inner_mu(self, mu_arr):
        return mu_arr if self.n_mu_ else None

    def step(self, x, mu=None, dt=None) -> np.ndarray:
        """One predicted step ``L_h S(L_h x)`` for states (B, 2n) or (2n,); arguments as :meth:`SymplecticKernelPredictor.step`.

        Cost: the propagators (``O(B (2n)^3)``) plus one inner step.
        """
        x, single, mu, dt, L = self._query(x, mu, dt)
        out = _apply(L, self.predictor_.step(_apply(L, x), mu=self._inner_mu(mu), dt=dt))
        out = check_finite(out, f"this {type(self.predictor_).__name__} (inside a SplitKernelPredictor)")
        return out[0] if single else out

    def rollout(self, x0, n_steps: int, mu=None, dt=None, *, stride: int = 1, progress=None) -> np.ndarray:
        """Trajectories (B, K // stride + 1, 2n) (or (K // stride + 1, 2n)) of ``n_steps`` predicted steps.

        ``stride`` and ``progress`` as in :meth:`SymplecticKernelPredictor.rollout` (chunked, Ctrl-C between chunks).

        Notes
        -----
        ``L_h`` is formed once per instance; the steps ``x_k+1 = L_h S(L_h x_k)``
        run on the inner predictor's Newton backend: the compiled rollout takes
        the two maps and does all ``K`` steps in one call (instances in
        parallel), the NumPy one loops over the steps with the batch
        vectorised.  Cost ``O(K B (m (2n)^2 n_newton + (2n)^2))``.  The inner
        model's warm start does not apply here (it warns; its extrapolation
        would mix ``x_k`` and ``L_h x_k``): every step starts from the explicit
        guess.  Extrapolation warnings are about the inner coordinates ``L_h x``.
        """
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        stride = as_positive_int(stride, "stride")
        x, single, mu, dt, L = self._query(x0, mu, dt, name="x0")
        # the inner model's public hook: x_k+1 = L_h S(L_h x_k) on its solver; it checks its inputs L_h x_k
        traj = self.predictor_.rollout(
            x, n_steps, mu=self._inner_mu(mu), dt=dt, stride=stride, progress=progress, around=(L, L)
        )
        return traj[0] if single else traj

    def step_jacobian(self, x, mu=None, dt=None) -> np.ndarray:
        """``D Phi = L_h DS(L_h x) L_h`` of shape (B, 2n, 2n) (or (2n, 2n)); symplectic when ``DS`` is."""
        x, single, mu, dt, L = self._query(x, mu, dt)
        jac = L @ self.predictor_.step_jacobian(_apply(L, x), mu=self._inner_mu(mu), dt=dt) @ L
        return jac[0] if single else jac

    # ----------------------------------------------------------------- files
    def save(self, path, *, overwrite: bool = True) -> None:
        """Save to an HDF5 model file (atomic; :mod:`sympredict.container`): the inner model and ``A_k``, powers.

        ``overwrite=False`` refuses an existing file (also one created while saving) with :class:`FileExistsError`."""
        self._check_fitted()
        inner_settings, inner_arrays = model_files.to_container(self.predictor_)
        mats, pw = self.quadratic_.checked()
        settings = {
            "layout": MODEL_LAYOUT,
            "class": type(self).__name__,
            "dim": self.dim_,
            "n_mu": self.n_mu_,
            "inner": inner_settings,
        }
        arrays = {f"{_INNER}{k}": v for k, v in inner_arrays.items()}
        arrays.update({"quadratic_matrices": mats, "quadratic_powers": pw})
        write_container(path, MODEL_FORMAT, settings, arrays, overwrite=overwrite)

    @classmethod
    def load(cls, path) -> "SplitKernelPredictor":
        """Load a model written by :meth:`save`; :class:`ModelFileError` for anything malformed (files are hostile input)."""
        settings, arrays = read_container(path, MODEL_FORMAT)
        return cls.from_container(settings, arrays, path)

    @classmethod
    def from_container(cls, settings, arrays: dict, path) -> "SplitKernelPredictor":
        """The model of a file's ``(settings, arrays)`` (:func:`~sympredict.container.read_container`)."""
        where = f"{str(path)!r} is not a valid split-predictor model file"
        if not isinstance(settings, dict) or settings.get("class") != cls.__name__:
            found = settings.get("class") if isinstance(settings, dict) else None
            raise ModelFileError(f"{str(path)!r} holds a {found!r}, not a {cls.__name__}")
        expected = {"layout", "class", "dim", "n_mu", "inner"}
        if set(settings) != expected:
            raise ModelFileError(
                f"{where}: its settings must have exactly the keys {sorted(expected)}, got {sorted(settings)}"
            )
        if settings["layout"] == 2:
            raise pre_release_layout(path)
        if settings["layout"] != MODEL_LAYOUT:
            raise ModelFileError(f"{where}: unknown layout {settings['layout']!r}")
        dim, n_mu = settings["dim"], settings["n_mu"]
        if (
            not all(isinstance(v, int) and not isinstance(v, bool) for v in (dim, n_mu))
            or dim < 2
            or dim % 2
            or n_mu < 0
        ):
            raise ModelFileError(f"{where}: invalid dimensions dim={dim!r}, n_mu={n_mu!r}")
        inner_settings = settings["inner"]
        if not isinstance(inner_settings, dict) or inner_settings.get("class") != SymplecticKernelPredictor.__name__:
            raise ModelFileError(f"{where}: the inner model must be a SymplecticKernelPredictor")
        if set(arrays) - {k for k in arrays if k.startswith(_INNER)} != {"quadratic_matrices", "quadratic_powers"}:
            extra = sorted(k for k in arrays if not k.startswith(_INNER))
            raise ModelFileError(
                f"{where}: expected the arrays 'quadratic_matrices', 'quadratic_powers' and the inner "
                f"model's, got {extra}"
            )
        mats, pw = arrays["quadratic_matrices"], arrays["quadratic_powers"]
        for name, arr in (("quadratic_matrices", mats), ("quadratic_powers", pw)):
            if arr.dtype.kind != "f" or not np.all(np.isfinite(arr)):
                raise ModelFileError(f"{where}: {name} must be finite floats")
        if (
            mats.ndim != 3
            or mats.shape[1:] != (dim, dim)
            or pw.ndim != 2
            or pw.shape[0] != mats.shape[0]
            or pw.shape[1] not in (0, n_mu)
        ):
            raise ModelFileError(
                f"{where}: quadratic_matrices {mats.shape} / quadratic_powers {pw.shape} do not fit "
                f"dim={dim}, n_mu={n_mu}"
            )
        try:
            quad = QuadraticPart(*QuadraticPart(mats, pw).checked(dim=dim, n_mu=n_mu))
        except ValueError as exc:
            raise ModelFileError(f"{where}: {exc}") from None
        inner = model_files.from_container(
            SymplecticKernelPredictor,
            inner_settings,
            {k[len(_INNER) :]: v for k, v in arrays.items() if k.startswith(_INNER)},
            path,
        )
        if inner.dim_ != dim or inner.n_mu_ != n_mu:
            raise ModelFileError(
                f"{where}: the inner model's dimensions ({inner.dim_}, {inner.n_mu_}) disagree with "
                f"the file's ({dim}, {n_mu})"
            )
        if pw.shape[1] and not n_mu:
            raise ModelFileError(f"{where}: the quadratic part needs a parameter the model does not have")
        box = inner.domain_
        corners_mu = np.stack([box["mu_min"], box["mu_max"]]) if n_mu else np.zeros((2, 0))
        corners_dt = np.array([float(box["dt_min"]), float(box["dt_max"])])
        try:
            finite = np.isfinite(quad.propagator(corners_mu if n_mu else None, 0.5 * corners_dt, n=2)).all()
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            finite = False
        if not finite:
            raise ModelFileError(f"{where}: the flow of its quadratic part is not finite over its training box")
        template = SymplecticKernelPredictor(**inner.get_params(deep=False))
        model = cls(predictor=template, quadratic=quad)
        model.predictor_, model.quadratic_, model.dim_, model.n_mu_ = inner, quad, dim, n_mu
        return model
