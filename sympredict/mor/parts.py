"""Small settings of a :class:`~sympredict.mor.reductor.SymplecticKernelReductor`: the training coordinates and
the split of the known linear flow.  Each stores its settings and checks them (``ValueError`` naming the
argument, the value and the choices)."""

from __future__ import annotations

from sympredict._checks import as_choice, as_flag
from sympredict.base import Setting
from sympredict.systems.linear_flow import QuadraticPart

__all__ = ["TrainingScaling", "QuadraticSplit"]

_STATE = ("diag", "uniform", "williamson", "none")
_PARAMETERS = ("box", "none")
_TIME = ("step", "none")


class TrainingScaling(Setting):
    """The coordinates the estimator is trained in (:mod:`sympredict.flowmap.scaling`).

    ``TrainingScaling("none", "none", "none")`` trains in the caller's units, where kernel shapes chosen in those
    units apply unchanged.

    Parameters
    ----------
    state : {"diag", "uniform", "williamson", "none"}, default="diag"
        :class:`~sympredict.flowmap.scaling.SymplecticScaling` mode (conformally symplectic, so the ROM's step stays
        symplectic); ``"williamson"`` (with :class:`~sympredict.mor.samples.GalerkinSamples` only) uses the
        Williamson form of ``V^T H(mu) V`` at the centre of the parameter box.
    parameters : {"box", "none"}, default="box"
        ``"box"``: parameters mapped from the box onto ``[0, 1]^d``; ``"none"``: as they are.
    time : {"step", "none"}, default="step"
        ``"step"``: the macro step becomes the time unit (the estimator sees ``dt = 1``); ``"none"``: it sees ``dt``.
    """

    def __init__(self, state: str = "diag", parameters: str = "box", time: str = "step"):
        self.state = state
        self.parameters = parameters
        self.time = time

    def check(self) -> "TrainingScaling":
        as_choice(self.state, "TrainingScaling state", _STATE)
        as_choice(self.parameters, "TrainingScaling parameters", _PARAMETERS)
        as_choice(self.time, "TrainingScaling time", _TIME)
        return self


class QuadraticSplit(Setting):
    """Split the exact linear flow of the quadratic part ``A(mu)`` of the reduced Hamiltonian off the learned step.

    The learned step becomes ``L_h o S o L_h``
    (:class:`~sympredict.flowmap.splitting.SplitKernelPredictor`, ``L_h = expm(dt/2 J A)``, carried into the
    scaled coordinates by :func:`~sympredict.flowmap.scaling.scaled_quadratic_part`), so the linear part of the
    flow is exact and only ``S`` is learned; the existence check and the kernel choice then see ``S``'s pairs
    ``(L_h x0, L_{-h} x1)``.

    Parameters
    ----------
    quadratic : QuadraticPart
        ``A(mu)`` in reduced coordinates, a function of the flow parameters (or constant).
    fallback : bool, default=False
        ``False``: always split.  ``True``: split only where the existence check finds no generating function at
        ``dt`` without it (after the midpoint form, where the update is left open); logged, and
        ``choice_["split"] = "split_fallback"`` says so.  A fallback needs the existence check.
    """

    def __init__(self, quadratic: QuadraticPart, fallback: bool = False):
        self.quadratic = quadratic
        self.fallback = fallback

    def check(self, dim: int, n_mu: int) -> "QuadraticSplit":
        if not isinstance(self.quadratic, QuadraticPart):
            raise ValueError(
                f"QuadraticSplit needs a sympredict.systems.linear_flow.QuadraticPart (the quadratic part "
                f"A(mu) of the reduced Hamiltonian), got {self.quadratic!r}"
            )
        as_flag(self.fallback, "QuadraticSplit fallback")
        self.quadratic.checked(dim=dim)
        if self.quadratic.checked()[1].shape[1] not in (0, n_mu):
            raise ValueError(
                f"QuadraticSplit depends on {self.quadratic.checked()[1].shape[1]} parameter component(s), "
                f"the flow map takes {n_mu}"
            )
        return self
