"""The automatic choice of what an estimator leaves open: kernels, their shapes, the update rule.

:class:`KernelSearch` is the part a :class:`~sympredict.estimators.predictor.SymplecticKernelPredictor`
stores as ``search``.  At ``fit`` it chooses every factor the data need but the estimator leaves
``None`` (as scikit-learn's ``GaussianProcessRegressor`` fits its kernel's hyperparameters by default):

* the **state kernel** (``state_kernel=None``): the states are normalised symplectically,
  ``(a_i q_i, p_i / a_i)`` with ``a_i = sqrt(std(p_i) / std(q_i))`` (a
  :class:`~sympredict.kernels.transforms.Scaled` transform: symplectic, so the learned step stays
  symplectic; the conformal factor that makes the spread 1 is the shape's unit), and a kernel family and
  shape are searched in units of the spread of the mixed variable ``xi``;
* the **parameter kernel** (``mu`` given, ``mu_kernel=None``): an isotropic kernel with a shape in units of the
  mean width of the parameter box's components (components of very different widths draw a
  :class:`~sympredict.exceptions.ScaleWarning` naming them; so do conjugate pairs of very different spreads,
  which the symplectic normalisation cannot balance against each other);
* the **step kernel** (several ``dt``, ``dt_kernel=None``): a shape in units of the width of the steps;
* the **update** (``update=None``): ``'symplectic_euler'`` and ``'midpoint'`` compete.

Criterion, in two stages on a subsample split into search training and validation parts.  First the
paper's validation residual ``E_val(m_star)`` (:func:`~sympredict.estimators.search.grid_search`) at a small
``m_star``: one greedy fit per candidate on the shape grids, for every update and family (both updates learn
the same targets ``y = J^T (x1 - x0) / dT``, at different points, so their residuals compare in the same
units).  A small ``m_star`` favours kernels too flat for the final size (they break down early), so the
finalists then compete at the final size (at most ``final_centers``) by the mean relative one-step error on
the validation samples, the error a rollout compounds, with a coordinate search (factor 2) of their shapes and
of the ratio of the ``q`` to the ``p`` shapes.  Where ``max_centers`` exceeds ``final_centers``, the choice is then
fitted to ``max_centers`` centres as well, its shapes narrowed where that fit stops early
(``KernelSearch(final_size=True)``).  For scattered one-step samples no rollout can be scored, and the
one-step error of the whole implicit step is the closest cheap proxy.  Where the data are trajectories, the fit
holds whole trajectories out, and the last word goes to what the user will do with the model: the finalists (the
best candidate of each update, and each symmetric candidate of the structure stage) can be scored by the error of
their rollouts of those held-out trajectories, the smallest winning (``KernelSearch(rollout_finalists=True)``; off
by default, see its Notes).  With
``KernelSearch(halving=True)`` both stages compare candidates first at a quarter of their centres and fit only
those not clearly losing there to full size (successive halving; the rule is in :class:`KernelSearch`'s Notes).
:meth:`KernelSearch.quick` compares the candidates well below the final size (100 and 250 centres, 1,200 samples,
halving) and leaves the final size to the final-size stage: a fraction of the default's cost for fits of 1,000
centres or more.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from sympredict._checks import as_flag
from sympredict.base import Setting, clone
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.estimators.search import (
    CANDIDATE_FIT,
    EARLY_STOP,
    SEARCH_LOGGER,
    EarlyStop,
    coordinate_search,
    grid_search,
    final_size_score,
    one_step_score,
    standard_error,
    pair_factors,
    quiet_logs,
    without_target,
    column_std,
)
from sympredict.estimators.structure import compete as _structure_stage
from sympredict.estimators.structure import fold
from sympredict.exceptions import ExtrapolationWarning, NewtonConvergenceError, NonFinitePredictionError, ScaleWarning
from sympredict.kernels import IMQ, KERNEL_FAMILIES
from sympredict.kernels.radial import _EPS_RANGE
from sympredict.kernels.transforms import KernelTransform, Scaled, Symmetric, lower_state_kernel
from sympredict.symplectic.updates import UPDATE_RULES, as_update

__all__ = ["KernelSearch", "SearchResult", "FitDiagnostics"]

logger = logging.getLogger("sympredict.estimators.auto")

_FAMILIES = ("imq", "matern52", "matern32")

#: Successive halving's rungs are never below this many centres (below it the search is cheap anyway).
MIN_RUNG = 25
#: Stage 2 fits a candidate to ``m_final`` centres only if its one-step error at the rung (``m_final / 4`` centres)
#: is at most this factor times the smallest rung error so far.  Large on purpose: at a quarter of the centres flat
#: kernels lead (sharper ones converge later but further), and on the three-body problem a candidate 21 times
#: worse than the best at the rung was the best at full size; only candidates clearly losing beyond that are cut.
RUNG_MARGIN = 30.0
#: The structure stage normalises a symmetric candidate on the states its group folds where that changes some pair
#: factor by more than this factor (:func:`_refine_structured`): the three-body problem's two clusters change them
#: 4 times, the pendulum's overlapping images by 2 per cent.
FOLD_CHANGE = 2.0
#: Stage 1's rungs: ``m_star // d`` centres for each ``d`` (those of at least :data:`MIN_RUNG` centres).
STAGE1_RUNGS = (4, 2)
#: Stage 2's rung: ``m_final // RUNG_FRACTION`` centres.
RUNG_FRACTION = 4
#: Held-out trajectories the finalists roll out, at most, and steps of each (the fit's prefix scoring uses the same).
ROLLOUT_TRAJECTORIES, ROLLOUT_HORIZON = 50, 100
#: Fewest held-out trajectories whose rollouts decide among the finalists.  A trajectory's rollout error depends on
#: where it runs (near a separatrix, an edge of the data) more than on the model, so a mean over two or three of
#: them is a sample too small to rank models: on the pendulum of the README (40 trajectories, 2 held out) deciding
#: by their rollouts chose the better model on the 20 test trajectories in one of four data sets and the worse in
#: another (median error at step 200 0.5 and 2.9 times the one-step choice's).
MIN_ROLLOUT_TRAJECTORIES = 5


@dataclass
class SearchResult:
    """What :meth:`KernelSearch.choose` chose.

    Attributes
    ----------
    params : dict
        Estimator parameters that replace the open ones: ``state_kernel``, ``mu_kernel``, ``dt_kernel``, ``update``
        (only the keys that were open).
    score : float
        The winner's mean relative one-step error on the search's validation samples with ``m_final`` centres
        (with :attr:`final_size` centres where the final-size stage ran).
    m_star : int
        Centres at which the first stage compared candidates (by ``E_val(m_star)``).
    n_train, n_validation : int
        Samples of the search's training and validation subsets.
    seconds : float
        Wall time of the search.
    table : list of dict
        Every candidate fitted, by ``stage``: 1 (kernels, update, ``E_val``, ``E_train``, centres, fit time) and 2
        (kernels, ``ratio``, update, one-step ``score``, centres, fit time); ``error`` where a fit failed, ``abandoned``
        (the centres it stopped at, its score ``inf``) where :attr:`KernelSearch.early_stop` stopped a clearly losing one.
    m_final : int
        Centres at which the second stage compared candidates (the final budget, at most
        :attr:`KernelSearch.final_centers`).
    fit_seconds : float or None
        Wall time of the whole fit the search was part of (set by the estimator's ``fit``; ``None`` for a search
        run on its own): :attr:`share` is ``seconds / fit_seconds``.
    """

    params: dict
    score: float
    m_star: int
    n_train: int
    n_validation: int
    seconds: float
    table: list = field(default_factory=list, repr=False)
    m_final: int = 0
    #: What the structure stage tested and found (:class:`~sympredict.estimators.structure.StructureFinding`).
    structure: list = field(default_factory=list, repr=False)
    fit_seconds: Optional[float] = None
    #: Processor time of the search (this process; less sensitive than ``seconds`` to other jobs on the machine).
    cpu_seconds: Optional[float] = None
    #: What decided among the finalists: ``'one-step error'``, or ``'held-out rollouts'`` where held-out
    #: trajectories scored them (:attr:`KernelSearch.rollout_finalists`).
    decided_by: str = "one-step error"
    #: The winner's rollout score on the held-out trajectories (``None`` where none scored the finalists): the mean
    #: over them of ``max_k |x_k - X_k| / rms_k |X_k|`` (:func:`~sympredict.estimators.search.relative_rollout_error`).
    rollout_score: Optional[float] = None
    #: The finalists rollouts compared: ``{'kernels', 'update', 'score', 'rollout'}`` each (empty without rollouts).
    finalists: list = field(default_factory=list, repr=False)
    #: Centres of the final-size stage (:attr:`KernelSearch.final_size`; 0 where it did not run): :attr:`score` is
    #: then the winner's one-step error with this many centres.
    final_size: int = 0

    @property
    def rollout_seconds(self) -> float:
        """Wall time of the candidates' rollouts of held-out trajectories (0 without them): the cost of
        :attr:`KernelSearch.rollout_finalists`, a part of :attr:`seconds`."""
        return float(sum(row.get("rollout_s", 0.0) for row in self.table))

    @property
    def stage_seconds(self) -> dict:
        """Where :attr:`seconds` went: ``{stage: seconds}`` of the candidates of each stage of :attr:`table` (1 the
        grids, 2 the finalists and their coordinate search, 3 the structure stage, 4 the final-size stage; each
        candidate's ``fit_s``, its fits and its scoring), in the order of the stages.  The rest of :attr:`seconds`
        (the normalisation, the structure tests, the bookkeeping) is ``seconds - sum(stage_seconds.values())``."""
        out = {}
        for row in self.table:
            out[row.get("stage")] = out.get(row.get("stage"), 0.0) + float(row.get("fit_s", 0.0))
        return {stage: out[stage] for stage in sorted(out)}

    @property
    def share(self) -> Optional[float]:
        """The search's share of the fit's wall time (``None`` without :attr:`fit_seconds`)."""
        return None if not self.fit_seconds else self.seconds / self.fit_seconds

    def summary(self) -> str:
        """One line: what was chosen and how."""
        chosen = ", ".join(f"{k}={v!r}" for k, v in self.params.items())
        found = [f.summary() for f in self.structure if f.verdict == "holds"]
        decided = (
            f"decided by held-out rollouts: rollout error {self.rollout_score:.3e}, best of {len(self.finalists)} "
            f"finalists; "
            if self.decided_by == "held-out rollouts" and self.rollout_score is not None
            else ""
        )
        return (
            f"chose {chosen} ({decided}one-step error {self.score:.3e} on held-out samples with {self.m_final} "
            f"centres; "
            + (f"refitted with {self.final_size} centres; " if self.final_size else "")
            + f"{len(self.table)} candidates, {self.n_train} + {self.n_validation} samples, {self.seconds:.1f} s)"
            + (f"; structure found: {'; '.join(found)}" if found else "")
        )


class KernelSearch(Setting):
    """How an estimator chooses the kernels, shapes and update it leaves open (``None``).

        Parameters
        ----------
        families : sequence of str
            State-kernel families tried (``'imq'``, ``'matern52'``, ``'matern32'``).  The first is searched over
            every update; the others compete at the winner's update and shape.
        shapes : sequence of float
            Multiples of the unit shape tried first for the state kernel (unit: ``1 / spread`` of the normalised
            mixed variable ``xi``, the root of the summed variances of its components).
        parameter_shapes : sequence of float
            Multiples of the unit shape tried for the parameter and step kernels (unit: ``1 / mean width`` of the
            parameter box's components; ``1 / width`` of the steps).
        updates : sequence of str
            Update rules that compete when the estimator's ``update`` is ``None``.
        m_star : int or None
            Centres at which the first stage compares candidates (by ``E_val(m_star)``); ``None``:
            ``min(max_centers, 300)``.
        final_centers : int
            Centres at which the second stage compares its candidates: ``min(max_centers, final_centers)``.
        max_samples : int
            Samples of the subsample the candidates are fitted to (the rest of the data is not used by the search).
        validation_fraction : float
            Part of that subsample held out to score the candidates.
        refine_sweeps : int
            Sweeps of the second stage's coordinate search (each shape, and the ratio of the ``q`` to the ``p``
            shapes, times 1/2 and 2); it stops after a sweep without improvement.
        seed : int
            Seed of the subsample and the split.
        structure : bool
            Test the data for symmetries, reversing symmetries and wrapped angles and let the symmetries that hold
            compete (:mod:`sympredict.estimators.structure`): one quick fit, then per group that holds its symmetric
            candidate fitted to ``m_final`` centres, and where the group's images of the data lie apart from them
            also that candidate normalised on the folded states (:func:`_refine_structured`); where the candidate's
            shapes were never refined (its update is not the one the second stage chose, as a reversing symmetry's
            midpoint update may not be, or it was normalised on the folded states), also its open shapes refined by
            the second stage's coordinate search (:func:`_refine_symmetric_shapes`).
        halving : bool
            Successive halving: candidates are first compared at a fraction of their centres, and only those not
            clearly losing there are fitted to full size (see Notes); ``False`` (the default): every candidate at full
            size (unless ``early_stop`` stops it at half of it).  On the five systems of
            ``sympredict_paper/studies/search_cost.py`` both choose the same settings; on noisy pendulum trajectories
            (30 x 20 steps, noise 1e-3) halving chose a wider kernel whose held-out error was 1.25 times the full
            search's, so it is not the default.
        rollout_finalists : bool
            Where the fit holds at least five whole trajectories out (data given as 91 or more trajectories, see
            :meth:`~sympredict.estimators.predictor.SymplecticKernelPredictor.fit`), score the finalists by the
            error of their rollouts of the held-out trajectories and choose the smallest (see Notes); ``False``:
            the smallest one-step error decides, as it does for scattered samples.  Off by default: on pendulum
            trajectories it chose a worse model for the test trajectories more often than a better one (Notes).
        early_stop : bool
            Stop the fit of a candidate once it is clearly losing (:class:`~sympredict.estimators.search.EarlyStop`;
            rows with ``abandoned``, never chosen): in the first stage where its validation residual at a quarter,
            half or three quarters of ``m_star`` exceeds 2000, 200 or 40 times the smallest ``E_val(m_star)`` so far
            of its grid and, for the families after the first, of its update's grids before it (the greedy's own
            residual, no extra cost; a family whose every candidate stops has no finalist of that update); in the
            second stage where its one-step error at half its centres (the prefix scored as the full fit would be)
            exceeds 300 times the best score so far, or, like with like, 8 times the half-size score of the best
            candidate so far that reached its full size (the best of its own update, for a start).  Such a candidate
            cannot win unless its score falls more than that over the rest of its centres, or the two swap ranks by
            more than 8 times from half to full size; on the search candidates of the six systems of
            ``sympredict_paper/studies/search_cost.py`` the residual fell at most 613, 62 and 12 times from a
            quarter, half and three quarters of ``m_star``, the one-step error 107 times from half its centres, and a
            second-stage candidate that ended better than another scored at most 3.4 times that one's score at half
            their centres (:data:`~sympredict.estimators.search.E_VAL_STOP_MARGINS`,
            :data:`~sympredict.estimators.search.EARLY_STOP_MARGINS`,
            :data:`~sympredict.estimators.search.REVERSAL_MARGINS`; ``sympredict_paper/studies/search_reversals.py``).
            A start stopped this way is losing, and is not narrowed as one that stops early for being too flat is (in
            those runs no start the rule would have stopped broke down later).  No candidate is stopped where
            held-out rollouts decide among the finalists (``rollout_finalists``: one losing on one step may win
            there) or with ``halving`` (its rung rule decides there).  ``False``: every candidate is fitted to its full
            size.
        final_size : bool
            Where the estimator's ``max_centers`` exceeds ``final_centers``, fit the chosen settings to
            ``max_centers`` centres too, and where that fit stops early (numerically singular: shapes too flat for
            the final size; before :data:`NEAR_FULL` of its centres), try them with the open shapes doubled, up to
            three times, while the doubled shape is better beyond the noise of its own score (the flatter one's
            error exceeds it by more than its standard error over the held-out samples); the smallest one-step error at the final size wins (see
            Notes).  Where the structure stage ran, its best candidate and the best one
            without a structure both go through this stage (a symmetric kernel reaches further per centre).

        Notes
        -----
        Two stages.  The first fits every update and family on the shape grids to ``m_star`` centres and keeps, per
        update and family, the tuple with the smallest validation residual ``E_val(m_star)`` (cheap, but at a small
        ``m_star`` flat kernels win that break down before the final size).  With ``early_stop``, a family after the
        first whose every candidate is clearly losing against its update's best (above) has no finalist there: both
        learn the same targets on the same samples, so their residuals compare, and a family that far behind at
        ``m_star`` did not win the second stage on the six systems (Matern52, the default's second family, stops
        this way on the three-body problem, the README's pendulum and Hénon–Heiles, 37 to 2,700 times behind IMQ
        there, and for the midpoint update on the coupled pendulums, 60 times behind; it competes on the Kepler orbits
        and the noisy pendulum, 1.2 and 0.3 to 0.5 times IMQ's, where it wins).  The second fits those finalists (a
        finalist that stops early for being too flat also with its open shapes doubled, up to three times), then the
        coordinate search's candidates, to ``m_final = min(max_centers, final_centers)`` centres (with ``early_stop``,
        one clearly losing at half of them stops there: against the best so far, a start against the best of its
        own update) and ranks them by the
        mean relative one-step error ``|Phi(x0) - x1| / |x1 - x0|`` on the held-out samples (a Newton failure scores
        ``inf``): the error a rollout compounds, at the size the model will have.  Errors are measured in the data's
        normalised coordinates ``(a_i q_i, p_i / a_i)`` (:func:`~sympredict.estimators.search.state_weights`), so the
        choice does not depend on the units of the states (raw norms of states in metres and m/s weigh only the
        positions).
        With ``halving`` (where ``m_star >= 4 MIN_RUNG``, resp. ``m_final >= 4 MIN_RUNG``; :data:`MIN_RUNG` = 25):

        * stage 1 trains each grid's candidates to ``m_star / 4`` centres, the best third of them (at least two, by
          ``E_val``) to ``m_star / 2``, and the best third of those (at least two) to ``m_star``
          (:func:`~sympredict.estimators.search.grid_search`'s ``rungs``);
        * stage 2 (and the structure stage) first fits every candidate to the rung ``m_final / 4`` and scores its
          one-step error there; a candidate is fitted to ``m_final`` only if that rung error is at most
          :data:`RUNG_MARGIN` (30) times the smallest rung error so far (the starting finalists are all rung-scored
          first); the others are recorded with ``score = inf`` and ``cut = True`` and never chosen, unless every
          candidate fitted to full size fails (then they are fitted to full size after all, rows ``after_cut``).

        A fit costs about ``m^2`` times the samples, so a rung at a quarter of the centres costs a sixteenth of a
        full fit: stage 1 fits about 4 instead of 15 full candidates per grid, stage 2 fits to full size only the
        candidates within the margin.  The rule is deterministic (ties go to the earlier candidate).

        Finalists by rollouts (``rollout_finalists``, with at least :data:`MIN_ROLLOUT_TRAJECTORIES` (5) held-out
        trajectories: a fit from 91 or more trajectories holds a twentieth out, or the caller's validation
        trajectories): every candidate fitted to ``m_final`` centres in the second and structure stages also rolls
        out the held-out trajectories (at most :data:`ROLLOUT_TRAJECTORIES`, their first :data:`ROLLOUT_HORIZON`
        steps) from their first states; its rollout score is the mean over them of the worst relative error along
        the rollout.  The shapes are still
        refined by the one-step error (many candidates, few held-out trajectories: a noisy score would be
        overfitted); the finalists, the best candidate of each update and every symmetric candidate of the structure
        stage, are then ranked by their rollout score (ties to the one-step order).  A one-step error compounds
        differently along a rollout for each update and structure (a symmetric midpoint model can be better on
        one step and worse over a rollout, or the reverse), which is why the finalists differ there.  Cost: ``P K``
        more implicit steps per full-size candidate (``P`` held-out trajectories of ``K`` steps), in batches of
        ``P``; no extra fit.  Measured (``sympredict_paper/studies/structure_search.py`` and the pendulum of the
        README, 20 test trajectories of 200 steps): on the three-body problem (160 orbits, 400 and 1,000 centres, 8
        held out) the rollouts and the one-step error chose the same model; on pendulum trajectories (40 and 120
        trajectories, four data sets each) the rollouts chose a worse model in three of eight cases (median error at
        step 200 1.3 to 3.6 times the one-step choice's), a better one in one (0.52 times), the same in four.  A
        trajectory's rollout error depends on where it runs more than on the model, and a few held-out trajectories
        are a small sample of the orbits a user rolls out; so it is an option, not the default.
        Final size (``final_size``, where ``max_centers > final_centers``): the chosen settings are fitted to
        ``max_centers`` centres on the search's samples and scored by the one-step error; while such a fit stops
        before :data:`NEAR_FULL` (90 %) of ``max_centers`` (or of the functionals the samples give) and succeeds, the
        open shapes (state, parameter and step kernels) are doubled, up to three times, as the second stage does
        for its finalists, but a doubled shape replaces the flatter one only where the flatter one's one-step error
        exceeds the doubled one's by more than the doubled one's standard error over the held-out samples (the
        "one-standard-error rule": within its noise the flatter kernel is kept, and the doubling stops); the
        smallest one-step error among the starts wins (rows of ``stage`` 4).  A fit on the search's subsample stops
        early for shapes that can suit the whole data (more samples: denser centres), so narrowing within the
        score's noise would trade a good flat kernel for a sharper one.  Shapes chosen at fewer centres than the model will have are
        too flat for it: on the three-body problem (160 orbits of 60 steps, ``max_centers=1000``) a search with
        ``final_centers=250`` and no final-size stage chose a state shape 8 times flatter whose fit stopped at 184
        centres: median error at step 200 0.13; the final-size stage doubled that shape three times, 8.1e-3 (the
        search at 1,000 centres: 5.2e-3 without the structure stage, 1.6e-3 with it; rows ``quarter_size_only``,
        ``quarter_size``, ``defaults_no_structure``, ``defaults`` of ``docs/data/structure_search.json``, from
        ``sympredict_paper/studies/structure_search.py``).  Cost: one to four fits to ``max_centers`` centres.
        Both stages fit with the estimator's own ``trainer`` (the one-at-a-time greedy by default: with
        :class:`~sympredict.interpolation.greedy.BlockedGreedy` fits in the second stage the search took a half to a
        third of its time on two acceptance systems of ``sympredict_paper/studies/defaults_acceptance.py``, but chose another update
        and parameter kernel on the Kepler orbits, with a 1.3x larger rollout error).
        Cost: about ``len(updates) (len(shapes) len(parameter_shapes)^k + 3 (len(families) - 1))`` fits to ``m_star``
        centres (``k`` open parameter and step kernels; with ``early_stop`` a candidate stopped at a fraction ``f`` of
        ``m_star`` costs about ``f^2`` of one, and a family stopped in stage 1 adds no finalist to stage 2), then
        ``len(updates) len(families) + 8 refine_sweeps`` fits to ``m_final`` centres, each ``O(m^2 2n max_samples)``,
        without ``halving`` (a candidate the early stop gives up at half its centres costs a quarter of a fit, plus
        one scoring of its prefix); with it, per grid of ``c`` candidates
    about ``c / 16 + c / 12 + 2`` fits' worth to ``m_star`` instead of ``c``, and in the second stage a sixteenth of a
    fit for each candidate cut at its rung (the rung fit of one that goes on adds a sixteenth to its full fit).
    """

    def __init__(
        self,
        families: Sequence[str] = ("imq", "matern52"),
        shapes: Sequence[float] = (0.125, 0.25, 0.5, 1.0, 2.0),
        parameter_shapes: Sequence[float] = (0.1, 0.5, 2.5),
        updates: Sequence[str] = ("symplectic_euler", "midpoint"),
        m_star: Optional[int] = None,
        final_centers: int = 1000,
        max_samples: int = 3000,
        validation_fraction: float = 0.25,
        refine_sweeps: int = 2,
        seed: int = 0,
        structure: bool = True,
        halving: bool = False,
        rollout_finalists: bool = False,
        final_size: bool = True,
        early_stop: bool = True,
    ):
        self.families = families
        self.shapes = shapes
        self.parameter_shapes = parameter_shapes
        self.updates = updates
        self.m_star = m_star
        self.final_centers = final_centers
        self.max_samples = max_samples
        self.validation_fraction = validation_fraction
        self.refine_sweeps = refine_sweeps
        self.seed = seed
        self.structure = structure
        self.halving = halving
        self.rollout_finalists = rollout_finalists
        self.final_size = final_size
        self.early_stop = early_stop

    @classmethod
    def quick(cls, **overrides) -> "KernelSearch":
        """A search that compares its candidates well below the final size, at a fraction of the default's cost.

        ``KernelSearch(max_samples=1200, m_star=100, final_centers=250, halving=True, refine_sweeps=1)`` with
        ``overrides`` (any other parameter) on top.  Stage 1 compares at 100 centres, stage 2 (and the structure
        stage) at ``min(max_centers, 250)`` centres, both on a subsample of 1,200 samples with successive halving; a
        model of more than 250 centres then gets its shapes at its own size from the final-size stage (``final_size``:
        the choice fitted to ``max_centers`` centres on the search's samples, its open shapes doubled while that fit
        stops early and the doubled shape scores better beyond the score's noise), the only fits at the final size.  The shape that suits ``m`` centres grows with ``m`` (the fill
        distance of the centres shrinks), which is why the final-size stage cannot be skipped; the stage-2 ranking of
        families, updates, the parameter kernel and the ``q``/``p`` ratio at a quarter of the size is what this preset
        trusts.

        Returns
        -------
        KernelSearch

        Notes
        -----
        Cost: stage 1 as the default's with ``m_star`` 100 instead of 300 and halving (about a tenth), stage 2 at 250
        instead of 1,000 centres (a sixteenth per fit on the same samples, about a fortieth on 900 instead of 2,250),
        and one to four fits per finalist to ``max_centers`` on 900 samples.  Its choice can be clearly worse than
        the default's (a flat kernel narrowed by the final-size stage on the search's samples).  Measured side by side with the default
        (``sympredict_paper/studies/search_cost.py --configs full quick``, ``docs/data/search_cost_quick.json``): see
        the defaults page, section "What the search costs".
        """
        params = dict(max_samples=1200, m_star=100, final_centers=250, halving=True, refine_sweeps=1)
        params.update(overrides)
        return cls(**params).check()

    def check(self) -> "KernelSearch":
        """Validate the settings; ``ValueError`` naming the bad one."""

        fams = list(self.families) if not isinstance(self.families, str) else None
        if not fams or any(f not in _FAMILIES for f in fams):
            raise ValueError(
                f"KernelSearch: families must be a non-empty sequence of {_FAMILIES}, got {self.families!r}"
            )
        for name in ("shapes", "parameter_shapes"):
            values = (
                np.atleast_1d(np.asarray(getattr(self, name), dtype=float))
                if not isinstance(getattr(self, name), str)
                else np.array([np.nan])
            )
            if values.size == 0 or not np.all(np.isfinite(values) & (values > 0)):
                raise ValueError(
                    f"KernelSearch: {name} must be a non-empty sequence of positive floats, got {getattr(self, name)!r}"
                )
        ups = list(self.updates) if not isinstance(self.updates, str) else None
        if not ups or any(u not in UPDATE_RULES for u in ups):
            raise ValueError(
                f"KernelSearch: updates must be a non-empty sequence of {tuple(UPDATE_RULES)}, got {self.updates!r}"
            )
        for name, lo in (("max_samples", 10), ("refine_sweeps", 0), ("seed", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"KernelSearch: {name} must be an integer >= {lo}, got {v!r}")
        v = self.final_centers
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"KernelSearch: final_centers must be a positive integer, got {v!r}")
        if self.m_star is not None and (
            isinstance(self.m_star, bool) or not isinstance(self.m_star, (int, np.integer)) or self.m_star < 1
        ):
            raise ValueError(f"KernelSearch: m_star must be a positive integer or None, got {self.m_star!r}")
        as_flag(self.structure, "KernelSearch: structure")
        as_flag(self.halving, "KernelSearch: halving")
        as_flag(self.rollout_finalists, "KernelSearch: rollout_finalists")
        as_flag(self.final_size, "KernelSearch: final_size")
        as_flag(self.early_stop, "KernelSearch: early_stop")
        if not (isinstance(self.validation_fraction, (int, float)) and 0 < self.validation_fraction < 1):
            raise ValueError(f"KernelSearch: validation_fraction must lie in (0, 1), got {self.validation_fraction!r}")
        return self

    # ------------------------------------------------------------------ the search
    def choose(
        self,
        estimator,
        data: FlowMapData,
        open_factors: dict,
        validation: Optional[FlowMapData] = None,
        rollouts: Optional[TrajectoryData] = None,
    ) -> SearchResult:
        """Choose the open settings of ``estimator`` for ``data``.

        Parameters
        ----------
        estimator : SymplecticKernelPredictor
            Unfitted; its given settings are kept.
        data : FlowMapData
            The training data.
        open_factors : dict
            ``{'state': bool, 'mu': bool, 'dt': bool, 'update': bool}``: what to choose.
        validation : FlowMapData, optional
            Held-out samples the caller gives to score the candidates (all of them; the one-step error uses the
            first 500); the candidates are then fitted to a random subsample of at most ``max_samples`` of ``data``.
            Default: a random subsample of ``data`` split by ``validation_fraction``.
        rollouts : TrajectoryData, optional
            Whole trajectories held out of ``data`` (a uniform step): with ``rollout_finalists``, their rollouts
            decide among the finalists.

        Returns
        -------
        SearchResult
        """
        self.check()
        t0, c0 = time.perf_counter(), time.process_time()
        m_star = int(self.m_star) if self.m_star is not None else min(int(estimator.max_centers), 300)
        train, val = self._subsets(data) if validation is None else (self._subsample(data), validation)
        params = {}

        # the state transform: the user's (its radial kernel searched inside it), or the symplectic normalisation
        if open_factors["state"] and estimator.state_kernel is None:
            params["state_kernel"] = Scaled(None, factors=tuple(float(a) for a in pair_factors(data)))
            _warn_unbalanced_pairs(data)
        if open_factors["mu"]:
            _warn_unbalanced_parameters(data)
        state_template = params.get("state_kernel", estimator.state_kernel)
        updates = list(self.updates) if open_factors["update"] else [estimator.update]

        def template(update):
            return without_target(clone(estimator).set_params(state_kernel=state_template, update=update))

        if open_factors["state"]:
            unit = 1.0 / _spread(template(updates[0]), train)
            fam0 = KERNEL_FAMILIES[self.families[0]]
            state_grid = [fam0(_clip(unit * s)) for s in self.shapes]
        else:
            radial = (
                estimator.state_kernel.radial
                if isinstance(estimator.state_kernel, KernelTransform)
                else estimator.state_kernel
            )
            state_grid = [radial]
        if open_factors["mu"]:
            width = float(np.mean(_widths(data.mu)))
            mu_grid = [IMQ(_clip(s / width)) for s in self.parameter_shapes]
        else:
            mu_grid = [estimator.mu_kernel] if data.mu.shape[1] else [None]
        if open_factors["dt"]:
            width = float(_widths(data.dt[:, None])[0])
            dt_grid = [IMQ(_clip(s / width)) for s in self.parameter_shapes]
        else:
            dt_grid = [estimator.dt_kernel]

        # stage 1, cheap: kernel family, update and shapes ranked by E_val(m_star), the greedy's validation residual
        table, finalists = self._first_stage(
            train, val, (state_grid, mu_grid, dt_grid), updates, template, open_factors["state"], m_star
        )
        finalists = [(r, u) for r, u in finalists if np.isfinite(r.score)]
        if not finalists:
            raise ValueError(
                "the kernel search found no candidate that trains on these data (every fit failed); "
                "see the log, or pass a state_kernel"
            )
        for r, u in finalists:
            logger.info(
                f"kernel search, stage 1 ({u}): {r.state!r}, {r.mu!r}, {r.dt!r}: E_val({m_star}) = {r.score:.3e}"
            )

        # stage 2, where the final model lives: each finalist, then a coordinate search of its shapes (and of the
        # ratio of q to p shapes under the symplectic normalisation), fitted to m_final centres and scored by the
        # one-step error on the held-out samples (what a rollout compounds; the small-m ranking favours kernels too
        # flat for the final size, which break down early)
        m_final = min(int(estimator.max_centers), int(self.final_centers))
        roll = _rollout_data(rollouts) if self.rollout_finalists and rollouts is not None else None
        if roll is not None and len(roll[0]) < MIN_ROLLOUT_TRAJECTORIES:
            logger.info(
                f"kernel search: {len(roll[0])} held-out trajectories are too few to rank the finalists by their "
                f"rollouts (at least {MIN_ROLLOUT_TRAJECTORIES}); the one-step error decides"
            )
            roll = None
        rollout_of = {}  # candidate -> its rollout score (full-size candidates, with held-out trajectories)
        scaled = open_factors["state"] and estimator.state_kernel is None
        factors = np.asarray(params["state_kernel"].factors) if scaled else None
        opened = {i for i, key in ((0, "state"), (2, "mu"), (3, "dt")) if open_factors[key]}  # shapes to search
        scores = {}
        rung_size = m_final // RUNG_FRACTION if self.halving and m_final // RUNG_FRACTION >= MIN_RUNG else None
        rungs = {}  # params' repr -> (rung score, centres, seconds, error): successive halving's first fit

        def rung_passes(p, label) -> tuple:
            """``(passes, rung result)``: the candidate ``p`` at the rung, against the smallest rung error so far."""
            if rung_size is None:
                return True, None
            key = repr(sorted(p.items(), key=lambda kv: kv[0]))
            if key not in rungs:
                rungs[key] = one_step_score(estimator, p, rung_size, train, val)
                logger.info(
                    f"kernel search, rung ({p['update']}): {label}: one-step error {rungs[key][0]:.3e} "
                    f"with {rungs[key][1]} centres"
                )
            finite = [r[0] for r in rungs.values() if np.isfinite(r[0])]
            ok = bool(finite) and rungs[key][0] <= RUNG_MARGIN * min(finite)
            return ok, rungs[key]

        def halved_score(p, label) -> tuple:
            """``(score, centres, seconds, error, extra row)``: ``one_step_score`` at ``m_final`` of a candidate
            that passes its rung; ``inf`` (``cut``) for one that does not."""
            ok, rung = rung_passes(p, label)
            if rung is None:
                sc, n, secs, err, ro, ro_s = final_size_score(estimator, p, m_final, train, val, rollouts=roll)
                return sc, n, secs, err, ({} if ro is None else {"rollout": ro, "rollout_s": ro_s})
            extra = {"rung_score": rung[0], "rung_centers": rung[1]}
            if not ok:
                return np.inf, rung[1], rung[2], rung[3], {**extra, "cut": True}
            sc, n, secs, err, ro, ro_s = final_size_score(estimator, p, m_final, train, val, rollouts=roll)
            return sc, n, secs + rung[2], err, {**extra, **({} if ro is None else {"rollout": ro, "rollout_s": ro_s})}

        def params_of(cand):
            radial, ratio, mu_k, dt_k, update = cand
            if scaled:
                state = Scaled(radial, factors=tuple(float(a) for a in factors * ratio))
            else:
                state = state_template.with_radial(radial) if isinstance(state_template, KernelTransform) else radial
            return {"state_kernel": state, "mu_kernel": mu_k, "dt_kernel": dt_k, "update": update}

        def label_of(cand):
            return " x ".join(repr(k) for k in (cand[0], cand[2], cand[3]) if k is not None) + (
                f", q/p shape ratio {cand[1]:g}" if scaled else ""
            )

        # each candidate competes with the best so far (in the coordinate search; a start, with the best of its own
        # update, so that each update's best is kept for the structure stage): at half its centres it stops where it
        # is clearly losing (EarlyStop), against that one's full-size score (the margin covers how far a score falls
        # from half to full size) or, like with like, against the half-size score of the best so far that reached
        # m_final centres (the margin covers rank reversals between half and full size)
        early = EarlyStop() if self.early_stop and roll is None and rung_size is None else None
        refining = [False]
        checks = {}  # candidate -> its checkpoint scores {centres: one-step error} (with the early stop)
        stopped = set()  # candidates the early stop gave up: losing, not too flat

        def to_beat(cand) -> tuple:
            """``(bound, reference)`` for ``cand``: the best score so far, and the checkpoint scores of the best
            candidate so far that reached ``m_final`` centres (``None``: none yet)."""
            pool = [c for c, v in scores.items() if np.isfinite(v[0]) and (refining[0] or c[4] == cand[4])]
            full = [c for c in pool if scores[c][1] >= m_final]
            bound = float(min(scores[c][0] for c in pool)) if pool else np.inf
            return bound, (checks.get(min(full, key=lambda c: scores[c][0]), {}) if full else None)

        def score(cand):
            if cand not in scores:
                label = label_of(cand)
                token = None
                if early is not None:
                    token = EARLY_STOP.set(early.start(*to_beat(cand)))
                try:
                    sc, n, secs, err, extra = halved_score(params_of(cand), label)
                finally:
                    if token is not None:
                        EARLY_STOP.reset(token)
                if early is not None:
                    checks[cand] = dict(early.scores)
                    if early.abandoned is not None:
                        stopped.add(cand)
                        extra = {
                            **extra,
                            "abandoned": early.abandoned,
                            "abandoned_score": early.scores[early.abandoned],
                        }
                scores[cand] = (sc, n, secs, err, extra.get("cut", False))
                if "rollout" in extra:
                    rollout_of[cand] = extra["rollout"]
                table.append(
                    {
                        "stage": 2,
                        "kernels": label.split(", q/p")[0],
                        "ratio": cand[1],
                        "update": cand[4],
                        "score": sc,
                        "n_centers": n,
                        "fit_s": secs,
                        **({} if refining[0] else {"start": True}),
                        **extra,
                        **({"error": err} if err else {}),
                    }
                )
                logger.info(
                    f"kernel search, stage 2 ({cand[4]}): {label}: "
                    + (
                        "cut at the rung"
                        if extra.get("cut")
                        else f"stopped at {n} centres, one-step error {extra['abandoned_score']:.3e} (clearly losing)"
                        if "abandoned" in extra
                        else f"one-step error {sc:.3e} with {n} centres"
                    )
                    + (f", held-out rollout error {extra['rollout']:.3e}" if "rollout" in extra else "")
                )
            return scores[cand][0]

        starts = [(r.state, 1.0, r.mu, r.dt, u) for r, u in finalists]
        for cand in starts:  # every finalist at the rung first, so that the margin is judged against all of them
            rung_passes(params_of(cand), label_of(cand))
        for cand in list(starts):
            # a finalist that stops before m_final (numerically singular: too flat for the final size, which the
            # small-m ranking favours) competes with its open shapes narrowed, up to three doublings; one cut at the
            # rung with the rung's centres is losing, not too flat, and so is one stopped at half its centres
            for _ in range(3):
                score(cand)
                if (
                    scores[cand][1] >= m_final
                    or scores[cand][3] is not None
                    or (scores[cand][4] and scores[cand][1] >= rung_size)
                    or cand in stopped
                ):
                    break
                cand = tuple(
                    k.set_params(eps=_clip(k.eps * 2.0)) if i in opened and k is not None else k
                    for i, k in enumerate(cand)
                )
                starts.append(cand)
        best = min(starts, key=score)
        refining[0] = True
        active = [
            i
            for i, key in ((0, "state"), (1, None), (2, "mu"), (3, "dt"))
            if (scaled if key is None else open_factors[key])
        ]
        best = coordinate_search(best, score, active, _move, factors=(0.5, 2.0), sweeps=self.refine_sweeps)
        if not np.isfinite(score(best)) and any(v[4] for v in scores.values()):
            # every candidate fitted to full size failed: those cut at the rung are fitted after all
            for cand in [c for c, v in scores.items() if v[4]]:
                sc, n, secs, err = one_step_score(estimator, params_of(cand), m_final, train, val)
                scores[cand] = (sc, n, secs, err, False)
                table.append(
                    {
                        "stage": 2,
                        "kernels": label_of(cand).split(", q/p")[0],
                        "ratio": cand[1],
                        "update": cand[4],
                        "score": sc,
                        "n_centers": n,
                        "fit_s": secs,
                        "after_cut": True,
                        **({"error": err} if err else {}),
                    }
                )
            best = min(scores, key=score)
        if not np.isfinite(score(best)):
            raise ValueError(
                f"the kernel search found no candidate that predicts the held-out samples with {m_final} "
                "centres (every fit or Newton solve failed); see the log, or pass the kernels and update"
            )
        chosen, best_score, structure = params_of(best), float(score(best)), []
        by_update = {}  # the best full-size candidate of each update (first seen first): finalists
        for cand in scores:
            if cand[4] not in by_update:
                by_update[cand[4]] = min((k for k in scores if k[4] == cand[4]), key=score)
        structured = []  # (params, one-step score, rollout score) of the structure stage's candidates
        if self.structure:  # symmetries the data show compete at m_final (sympredict.estimators.structure)

            def score_params(p):
                # at full size only: a group multiplies the centres' reach, so its error at a rung compares unevenly
                sc, n, secs, err, ro, ro_s = final_size_score(estimator, p, m_final, train, val, rollouts=roll)
                extra = {} if ro is None else {"rollout": ro, "rollout_s": ro_s}
                structured.append((p, sc, ro))
                table.append(
                    {
                        "stage": 3,
                        "kernels": repr(p["state_kernel"]),
                        "update": p["update"],
                        "score": sc,
                        "n_centers": n,
                        "fit_s": secs,
                        **extra,
                        **({"error": err} if err else {}),
                    }
                )
                return sc, n

            def refine(cand, group, value, n):  # the symmetric candidate normalised for its group
                start = cand
                cand, value = _refine_structured(estimator, cand, group, value, n, train, score_params, scaled)
                if not _shapes_unrefined(start, cand, best[4]):
                    return cand, value
                return _refine_symmetric_shapes(cand, value, score_params, open_factors, self.refine_sweeps)

            chosen, best_score, structure = _structure_stage(
                estimator,
                chosen,
                best_score,
                m_final,
                train,
                val,
                score_params,
                open_factors["state"],
                open_factors["update"],
                {u: params_of(c) for u, c in by_update.items()},
                refine=refine,
            )
        decided, rollout_score, finalists = "one-step error", None, []
        if roll is not None:  # the finalists ranked by their held-out rollouts: what the user will do with the model
            pool = [(params_of(c), scores[c][0], rollout_of.get(c)) for c in by_update.values()] + structured
            finalists = [
                {
                    "kernels": repr(p["state_kernel"]),
                    "update": p["update"],
                    "score": sc,
                    "rollout": ro,
                    "params": p,
                }
                for p, sc, ro in pool
                if np.isfinite(sc) and ro is not None
            ]
            ranked = sorted(finalists, key=lambda f: (f["rollout"], f["score"]))
            if ranked and np.isfinite(ranked[0]["rollout"]):
                win = ranked[0]
                logger.info(
                    f"kernel search, finalists by rollouts of {roll[0].shape[0]} held-out trajectories "
                    f"({roll[0].shape[1] - 1} steps): "
                    + "; ".join(f"{f['kernels']} ({f['update']}): {f['rollout']:.3e}" for f in finalists)
                    + f"; chosen: {win['kernels']} ({win['update']}), one-step error {win['score']:.3e}"
                    + f" (the one-step choice's: {best_score:.3e}); the candidates' rollouts took "
                    + f"{sum(r.get('rollout_s', 0.0) for r in table):.1f} s"
                )
                chosen, best_score = win["params"], float(win["score"])
                decided, rollout_score = "held-out rollouts", float(win["rollout"])
            for f in finalists:
                del f["params"]
        m_full = int(estimator.max_centers)
        if self.final_size and m_full > m_final:  # the shapes at the size the model will have
            # the best candidate with and without a structure both compete there (the chosen one first)
            pool = [params_of(best)] + [p for p, sc, _ in sorted(structured, key=lambda r: r[1])[:1] if np.isfinite(sc)]
            others = [p for p in pool if repr(p) != repr(chosen)] if structured else []
            chosen, best_score = _at_final_size(
                estimator, chosen, best_score, m_full, train, val, table, open_factors, others=others
            )
        for key, factor in (("state_kernel", "state"), ("mu_kernel", "mu"), ("dt_kernel", "dt"), ("update", "update")):
            if open_factors[factor]:
                params[key] = chosen[key]
        out = SearchResult(
            params,
            best_score,
            m_star,
            len(train),
            len(val),
            time.perf_counter() - t0,
            table,
            m_final=m_final,
            structure=structure,
            cpu_seconds=time.process_time() - c0,
            decided_by=decided,
            rollout_score=rollout_score,
            finalists=finalists,
            final_size=m_full if self.final_size and m_full > m_final else 0,
        )
        logger.info("kernel search: " + out.summary())
        return out

    def _first_stage(
        self, train: FlowMapData, val: FlowMapData, grids: tuple, updates: list, template, open_state: bool, m_star: int
    ) -> tuple:
        """``(table, finalists)``: per update, the grid search over ``grids = (state, mu, dt)`` at ``m_star`` centres
        and, with an open state kernel, the other families around its winner's shape; ``finalists`` holds
        ``(SelectionResult, update)`` per update and family that has one.  ``template(update)`` is the estimator the
        candidates are clones of.

        With ``early_stop``, the other families' candidates must beat the smallest ``E_val(m_star)`` of their update
        so far (the first family's grid, and the families before them: fitted on the same samples with the same
        update, their residuals compare), not only their own grid's: a family whose every candidate is clearly
        losing against it (:data:`~sympredict.estimators.search.E_VAL_STOP_MARGINS`) has no finalist of that update
        (its rows are kept, with ``abandoned``).  The first family's grid of each update is bounded by its own
        candidates only: its winner can lie beyond the grid's edge, where only the widening after the grid finds
        it."""
        state_grid, mu_grid, dt_grid = grids
        table, finalists = [], []
        best = [np.inf]  # the smallest E_val(m_star) of the update so far: the early stop's bound for its next grid

        def search(update, *candidates):
            try:
                result = grid_search(
                    train,
                    val,
                    *candidates,
                    m_star=m_star,
                    estimator=template(update),
                    rungs=rungs,
                    early_stop=self.early_stop,
                    bound=best[0],
                )
            except ValueError as exc:  # no candidate of this grid trains (or beats the update's best): others may
                table.extend({**row, "stage": 1, "update": update} for row in getattr(exc, "table", ()))
                table.append({"stage": 1, "update": update, "E_val": np.inf, "error": str(exc)})
                return None
            table.extend({**row, "stage": 1, "update": update} for row in result.table)
            finalists.append((result, update))
            best[0] = min(best[0], result.score)
            return result

        rungs = tuple(m_star // d for d in STAGE1_RUNGS if m_star // d >= MIN_RUNG) if self.halving else ()
        # the grid search's own notes (a winner on a grid's edge, m_star too small) are what stage 2 resolves
        with quiet_logs(SEARCH_LOGGER, level=logging.ERROR):
            for update in updates:
                best[0] = np.inf
                result = search(update, state_grid, mu_grid, dt_grid)
                if result is None:
                    logger.info(f"kernel search, stage 1 ({update}): no finalist ({table[-1]['error']})")
                    continue
                if open_state:  # the other families around this update's shape, with its mu and dt kernels
                    for family in self.families[1:]:
                        grid = [KERNEL_FAMILIES[family](_clip(result.state.eps * f)) for f in (0.5, 1.0, 2.0)]
                        if search(update, grid, [result.mu], [result.dt]) is None:
                            logger.info(
                                f"kernel search, stage 1 ({update}, {family}): no finalist ({table[-1]['error']})"
                            )
        return table, finalists

    def _subsample(self, data: FlowMapData) -> FlowMapData:
        """A random subsample of at most ``max_samples`` samples, all of them to train (the caller holds out)."""
        rows = np.random.default_rng(self.seed).permutation(len(data))[: min(len(data), int(self.max_samples))]
        return data.subset(np.sort(rows))

    def _subsets(self, data: FlowMapData):
        """A random subsample of at most ``max_samples`` samples, split into search training and validation parts."""
        rng = np.random.default_rng(self.seed)
        m = len(data)
        if m < 8:
            raise ValueError(
                f"the kernel search needs at least 8 samples to hold some out, got {m}: pass the kernels "
                "(state_kernel, mu_kernel, dt_kernel) and update explicitly for so few samples"
            )
        rows = rng.permutation(m)[: min(m, int(self.max_samples))]
        n_val = max(2, int(round(self.validation_fraction * len(rows))))
        return data.subset(np.sort(rows[n_val:])), data.subset(np.sort(rows[:n_val]))


def _narrowed(params: dict, open_factors: dict) -> dict:
    """``params`` with its open shapes doubled (state kernel inside its transforms, parameter and step kernels)."""
    out = dict(params)
    if open_factors["state"]:
        state = params["state_kernel"]
        radial = state.radial if isinstance(state, KernelTransform) else state
        wider = radial.set_params(eps=_clip(radial.eps * 2.0))
        out["state_kernel"] = state.with_radial(wider) if isinstance(state, KernelTransform) else wider
    for key, factor in (("mu_kernel", "mu"), ("dt_kernel", "dt")):
        if open_factors[factor] and params.get(key) is not None:
            out[key] = params[key].set_params(eps=_clip(params[key].eps * 2.0))
    return out


#: A fit that reaches this fraction of its centres is not narrowed by the final-size stage: the shape that suits ``m``
#: centres scales with their fill distance ``~ m^(-1/d)``, which at 90 % of the centres is within 11 % of the full
#: fit's for any dimension ``d >= 1``, far below the stage's step (a factor 2).
NEAR_FULL = 0.9


def _within_noise(value: float, reference: float) -> bool:
    """Whether the held-out score ``value`` is within the noise of ``reference``: at most ``reference`` plus its
    standard error over the held-out samples (:class:`~sympredict.estimators.search.HeldOutScore`; the
    "one-standard-error rule").  A plain ``float`` reference has no noise: ``value <= reference``."""
    return bool(value <= reference + standard_error(reference))


def _at_final_size(
    estimator, chosen: dict, score: float, m_full: int, train, val, table: list, open_factors: dict, others=()
):
    """``(params, score)``: ``chosen`` (and each of ``others``: the best candidates with and without a structure
    that were not chosen) fitted to ``m_full`` centres and, while such a fit stops early, with its open shapes doubled (up
    to three times); the smallest one-step error at ``m_full`` wins (``chosen`` and its ``score`` where every such
    fit fails).  Rows of ``stage`` 4 in ``table``.

    Each start narrows only where narrowing measures better: a doubled shape replaces the flatter one only where its
    held-out error is below the flatter one's beyond the noise (the flatter one's error is not within one standard
    error of the doubled one's, :func:`_within_noise`), and the doubling stops at the first that does not, at a
    failed fit, or at a fit that reaches :data:`NEAR_FULL` of ``min(m_full, capacity)`` centres.  A fit on the
    search's subsample can stop early for a shape that suits the whole data (more samples, denser centres): a flat
    kernel is kept unless a narrowed one is clearly better.

    The structure stage compares at ``m_final`` centres; a symmetric kernel reaches further per centre, so the order
    at ``m_full`` may differ: the finalist of the other kind competes there too (one to four more fits to
    ``m_full``)."""
    capacity = len(train) * train.x0.shape[1]  # the greedy cannot select more centres than functionals
    full = min(m_full, capacity)
    best, best_score = chosen, np.inf
    for start in [chosen, *others]:
        cand, kept, kept_score = start, start, np.inf
        for doubling in range(4):
            sc, n, secs, err = one_step_score(estimator, cand, m_full, train, val)
            table.append(
                {
                    "stage": 4,
                    "kernels": repr(cand["state_kernel"]),
                    "update": cand["update"],
                    "score": sc,
                    "score_se": standard_error(sc),
                    "n_centers": n,
                    "fit_s": secs,
                    **({"error": err} if err else {}),
                }
            )
            logger.info(
                f"kernel search, final size: {cand['state_kernel']!r} ({cand['update']}): "
                + (f"failed ({err})" if err else f"one-step error {sc:.3e} with {n} of {m_full} centres")
            )
            if doubling and (not np.isfinite(sc) or _within_noise(kept_score, sc)):
                break  # the narrowed shape is not clearly better: the flatter one stays
            kept, kept_score = cand, sc
            if err is not None or n >= NEAR_FULL * full or doubling == 3:
                break
            cand = _narrowed(cand, open_factors)
        if kept_score < best_score:
            best, best_score = kept, kept_score
    return (best, float(best_score)) if np.isfinite(best_score) else (chosen, score)


def _refine_structured(
    estimator, cand: dict, group: list, value: float, n: int, train: FlowMapData, score, scaled: bool
) -> tuple:
    """``(params, score)``: the structure stage's symmetric candidate ``cand`` (one-step error ``value``), or the
    same group normalised on the states it folds (:func:`~sympredict.estimators.structure.fold`) where that is
    better.  ``score(params) -> (score, centres)``.

    A symmetric kernel sees the data modulo the group.  Where the search chose the symplectic normalisation and
    folding the training states changes some pair's factor ``a_i`` by more than :data:`FOLD_CHANGE`, the group's
    images of the data lie apart from them (the three-body problem's orbits about ``L4`` and their mirror images
    about ``L5``): the unfolded spreads measure the distance between the images, which the symmetric kernel does not
    see.  A second candidate then takes the pair factors of the folded states (times the chosen ``q``/``p`` ratio)
    and the state shape rescaled by the ratio of the spreads (the shape unit is ``1 / spread``); the smaller
    held-out one-step error wins.  Where the images overlap the data (the pendulum's sign flips: the factors change
    by a few per cent), the fold only shrinks the ranges and the candidate keeps the shapes chosen on the data:
    rescaling them there chose sharper kernels whose test rollouts were 2 to 46 times worse (three training draws
    of pendulum trajectories).  Cost: ``O(|G| M 2n)`` for the fold, and one fit to ``m_final`` centres where it
    separates.
    """
    inner = cand["state_kernel"].kernel  # the Symmetric candidate's kernel: Scaled under the symplectic normalisation
    if not (scaled and isinstance(inner, Scaled) and inner.kernel is not None):
        return cand, value
    g = fold(train.x0, group)
    folded = FlowMapData(train.x0 * g, train.x1 * g, train.mu, train.dt)
    before, after = pair_factors(train), pair_factors(folded)
    change = float(np.max(np.abs(np.log(after / before))))
    if change <= np.log(FOLD_CHANGE):
        return cand, value
    factors = tuple(float(a) for a in after * (np.asarray(inner.factors) / before))
    template = without_target(clone(estimator).set_params(update=cand["update"]))
    try:
        ratio = _spread(clone(template).set_params(state_kernel=inner), train) / _spread(
            clone(template).set_params(state_kernel=Scaled(None, factors=factors)), folded
        )
    except ValueError:  # the folded states do not spread: keep the candidate
        return cand, value
    radial = inner.kernel.set_params(eps=_clip(inner.kernel.eps * ratio))
    other = {**cand, "state_kernel": Symmetric(Scaled(radial, factors=factors), group=group)}
    other_value, _ = score(other)
    logger.info(
        f"structure: folding by {group} changes the pair factors from {np.round(before, 3).tolist()} to "
        f"{np.round(after, 3).tolist()}: normalised on the folded states, held-out one-step error {other_value:.3e} "
        f"(on the data's: {value:.3e})"
    )
    return (other, other_value) if other_value < value else (cand, value)


def _shapes_unrefined(start: dict, cand: dict, second_stage_update: str) -> bool:
    """Whether the structure stage's symmetric candidate ``cand`` has shapes no coordinate search has refined: its
    update is not ``second_stage_update`` (the second stage refines the shapes of its winner's update only), or it
    is not ``start`` (:func:`_refine_structured` normalised it on the folded states and rescaled its shape)."""
    return cand is not start or cand["update"] != second_stage_update


def _refine_symmetric_shapes(cand: dict, value: float, score, open_factors: dict, sweeps: int) -> tuple:
    """``(params, score)``: the structure stage's symmetric candidate ``cand`` (held-out one-step error ``value``)
    after the second stage's coordinate search of its open shapes (the radial shape inside the ``Symmetric``
    transform, the parameter and step kernels' shapes; factors 0.5 and 2, at most ``sweeps`` sweeps) by the same
    score at ``m_final`` centres.  ``score(params) -> (score, centres)``.

    The search calls it where the candidate's shapes were never refined (:func:`_shapes_unrefined`): where its update
    is not the one the second stage chose (the symmetric candidate starts from the best kernels of its update, and
    the second stage refines the shapes of the overall best candidate only, so the midpoint kernels a reversing
    symmetry takes are then the first stage's, chosen at ``m_star`` centres), and where it was normalised on the
    folded states (its shape rescaled by the spreads' ratio, not searched; on the three-body problem a state shape
    twice too sharp, with a held-out one-step error 37 times the refined one's).  Where neither holds its shapes are
    already refined: searching them again among the symmetric candidates (several groups, each with its shape
    neighbours) chose a sharper parameter kernel on the README's pendulum whose rollouts were a hundred times worse.
    Cost: at most ``1 + 2 k sweeps`` fits to ``m_final`` centres (``k`` open shapes), the first of them already done.
    """
    if not isinstance(cand.get("state_kernel"), Symmetric) or not np.isfinite(value):
        return cand, value
    sym = cand["state_kernel"]
    inner = sym.kernel
    radial = inner.radial if isinstance(inner, KernelTransform) else inner
    if radial is None:
        return cand, value

    def params_of(t):
        state = inner.with_radial(t[0]) if isinstance(inner, KernelTransform) else t[0]
        return {**cand, "state_kernel": Symmetric(state, group=sym.group), "mu_kernel": t[1], "dt_kernel": t[2]}

    start = (radial, cand.get("mu_kernel"), cand.get("dt_kernel"))
    cache = {repr(start): value}

    def key(t):
        if repr(t) not in cache:
            cache[repr(t)] = score(params_of(t))[0]
        return cache[repr(t)]

    active = [i for i, k in ((0, "state"), (1, "mu"), (2, "dt")) if open_factors[k] and start[i] is not None]
    best = coordinate_search(start, key, active, _move_shape, factors=(0.5, 2.0), sweeps=sweeps)
    if best is not start:
        logger.info(
            f"structure: the symmetric candidate's shapes refined: {best[0]!r}, {best[1]!r}, {best[2]!r}: held-out "
            f"one-step error {key(best):.3e} (before: {value:.3e})"
        )
    return params_of(best), key(best)


def _move_shape(value, index: int, factor: float):
    """A kernel's shape times ``factor`` (kept in the accepted range): the symmetric candidate's coordinate move."""
    return value.set_params(eps=_clip(value.eps * factor))


def _rollout_data(trajectories: TrajectoryData) -> tuple:
    """``(states, mu, dt)`` of the held-out trajectories the finalists roll out: at most
    :data:`ROLLOUT_TRAJECTORIES` of them, their first :data:`ROLLOUT_HORIZON` steps."""
    k = min(trajectories.states.shape[1] - 1, ROLLOUT_HORIZON)
    p = min(len(trajectories), ROLLOUT_TRAJECTORIES)
    return trajectories.states[:p, : k + 1], trajectories.mu[:p] if trajectories.mu.shape[1] else None, trajectories.dt


def _holdout_split(data: FlowMapData, seed: int, fraction: float = 0.1, largest: int = 2000):
    """``(train, holdout)``: a random tenth of the samples (at most ``largest``, none below 20 samples) held out."""
    m = len(data)
    n_out = min(largest, int(fraction * m)) if m >= 20 else 0
    if n_out == 0:
        return data, None
    rows = np.random.default_rng(seed).permutation(m)
    return data.subset(np.sort(rows[n_out:])), data.subset(np.sort(rows[:n_out]))


def _move(value, index: int, factor: float):
    """The second stage's coordinate move: the ``q``/``p`` shape ratio (coordinate 1) times ``factor``, a kernel's
    shape times ``factor`` (kept in the accepted range)."""
    return value * factor if index == 1 else _move_shape(value, index, factor)


#: Spreads of pairs (or widths of parameter components) below this fraction of the largest draw a ScaleWarning.
SCALE_RATIO = 1e-3


def _warn_small_scales(scale: np.ndarray, label, message: str) -> None:
    """:class:`ScaleWarning` naming the entries of ``scale`` (k,) above zero but below :data:`SCALE_RATIO` times the
    largest: ``message`` with ``{names}`` (the first four, each ``label(i)``) and ``{big}`` (the largest) filled in."""
    big = float(scale.max()) if scale.size else 0.0
    small = np.flatnonzero((scale > 0) & (scale < SCALE_RATIO * big))
    if big > 0 and small.size:
        names = ", ".join(label(i) for i in small[:4])
        warnings.warn(message.format(names=names, big=f"{big:.2g}"), ScaleWarning, stacklevel=5)


def _warn_unbalanced_pairs(data: FlowMapData) -> None:
    """:class:`ScaleWarning` naming the conjugate pairs whose spread, after the symplectic normalisation, is below
    :data:`SCALE_RATIO` times the largest pair's (the normalisation balances ``q_i`` against ``p_i``, not pairs
    against each other: a symplectic linear map cannot scale one pair alone)."""
    x = np.concatenate([data.x0, data.x1])
    n = x.shape[1] // 2
    spread = np.sqrt(column_std(x[:, :n]) * column_std(x[:, n:]))  # each pair's spread after (a_i q_i, p_i / a_i)
    _warn_small_scales(
        spread,
        lambda i: f"(q{i + 1}, p{i + 1}) spread {spread[i]:.2g}",
        "the states' conjugate pairs differ in scale: {names}, against {big} for the largest; the state kernel "
        "hardly sees the small ones, which will be learned badly. Give the states in units of comparable size "
        "(divide each pair (q_i, p_i) by its amplitude), or fit the pairs apart",
    )


def _warn_unbalanced_parameters(data: FlowMapData) -> None:
    """:class:`ScaleWarning` naming the parameter components whose width is below :data:`SCALE_RATIO` times the
    widest's (the parameter kernel is isotropic: its shape comes from the mean width)."""
    width = np.ptp(data.mu, axis=0).astype(float)
    _warn_small_scales(
        width,
        lambda i: f"mu{i + 1} (width {width[i]:.2g})",
        "the parameter components differ in width: {names}, against {big} for the widest; the isotropic "
        "parameter kernel hardly sees the narrow ones. Map each component onto a range of comparable width "
        "(e.g. (mu - lo) / (hi - lo)) before fitting and querying",
    )


def _widths(values: np.ndarray) -> np.ndarray:
    """Per column: the width of the values' range (the largest magnitude where they are all equal, else 1)."""
    width = np.ptp(values, axis=0).astype(float)
    mag = np.abs(values).max(axis=0)
    return np.where(width > 0, width, np.where(mag > 0, mag, 1.0))


def _spread(template, data: FlowMapData) -> float:
    """Root of the summed variances of the mixed variable ``xi`` in the template's normalised coordinates."""

    scale = lower_state_kernel(template.state_kernel).scale_vector(data.x0.shape[1])
    xi, _ = as_update(template.update).variables(data.x0 * scale, data.x1 * scale, data.dt)

    stds = column_std(xi)
    big = float(stds.max()) if stds.size else 0.0
    spread = big * float(np.linalg.norm(stds / big)) if big > 0 else 0.0  # no underflow of the squares
    if not (np.isfinite(spread) and _EPS_RANGE[0] * 1e3 * spread < 1.0 < _EPS_RANGE[1] * 1e-3 * spread):
        raise ValueError(
            f"the training states' mixed variables spread over {spread!r}: no kernel shape fits that "
            "scale (or the states do not vary); rescale the states to units nearer one, or pass a state_kernel"
        )
    return spread


def _clip(eps: float) -> float:
    """A shape inside the kernels' accepted range."""

    return float(np.clip(eps, *_EPS_RANGE))


@dataclass
class FitDiagnostics:
    """How well a fit went, and what to try next.

    Attributes
    ----------
    n_train, n_holdout : int
        Samples trained on, and held out of the fit to score it.
    n_centers, max_centers : int
    stop_reason : str
        Why the greedy stopped: ``'tol'`` (converged), ``'max_centers'``, ``'power'`` (numerically singular), ...
    converged : bool
        Whether the greedy reached its residual tolerance.
    train_residual, holdout_residual : float
        Maximal residual of the learned gradient on the training and hold-out samples, relative to the largest
        target (``nan`` for the hold-out without hold-out samples).
    holdout_step_error : float
        Median relative one-step error ``|Phi(x0) - x1| / |x1 - x0|`` on (up to 500) hold-out samples (``nan``
        without them, ``inf`` if Newton failed on one).
    advice : list of str
        What to try next, only where the model falls short (a missed target, a residual still falling at
        the cap, hold-out far above training, the parameter box's faces, Newton failures).
    target_error : float or None
        The ``target_error`` of the estimator (``None``: no target).
    target_met : bool or None
        Whether ``holdout_step_error <= target_error`` (``None`` without a target or held-out samples).
    calibration : dict or None
        The error estimate's calibration (the model's ``error_calibration_``, computed on first use:
        scale, source, samples, median effectivity and share underestimated more than 3x on those samples).
    model
        The fitted model these diagnostics describe.
    prefix : tuple or None
        ``(kept, scored)``: the centres kept and the largest prefix the greedy scored on held-out samples
        (``kept < scored`` when a smaller prefix was better or met the target).
    holdout_coordinate_error : ndarray of shape (2n,) or None
        Per coordinate ``c``: the median of ``|Phi(x0)_c - x1_c|`` over the same hold-out samples, relative to the
        root mean square of that coordinate's increments ``x1_c - x0_c`` (``None`` without hold-out samples or
        where Newton failed).  A coordinate with small values is learned badly while the median over all of
        them looks fine; the advice names it.
    """

    n_train: int
    n_holdout: int
    n_centers: int
    max_centers: int
    stop_reason: str
    converged: bool
    train_residual: float
    holdout_residual: float
    holdout_step_error: float
    advice: list = field(default_factory=list)
    target_error: Optional[float] = None
    target_met: Optional[bool] = None
    prefix: Optional[tuple] = None
    model: object = field(default=None, repr=False, compare=False)
    holdout_coordinate_error: Optional[np.ndarray] = None

    @property
    def calibration(self) -> Optional[dict]:
        """The model's ``error_calibration_`` (computed on first use: ``O(500 2n m^2)``)."""
        return getattr(self.model, "error_calibration_", None)

    #: How :meth:`summary` words the greedy's stop reasons.
    STOPS = {
        "tol": "training residual at its tolerance",
        "max_centers": "centre budget used",
        "power": "kernel matrix numerically singular, no informative centre left",
        "target": "target met",
        "diverged": "round-off, truncated to the best step",
        "exhausted": "every candidate used",
    }

    def summary(self) -> str:
        """A few lines for a log or a terminal: size, held-out error (against the target), error estimate."""
        stop = self.STOPS.get(self.stop_reason, self.stop_reason)
        head = f"{self.n_centers} of {self.max_centers} centres (greedy stop: {stop}"
        if self.prefix is not None and self.prefix[0] < self.prefix[1] and self.stop_reason != "target":
            head += f"; best held-out prefix of {self.prefix[1]} kept"
        lines = [head + ")"]
        if self.n_holdout:
            held = f"median one-step error on {self.n_holdout} held-out samples: {self.holdout_step_error:.2e}"
            if self.target_error is not None:
                held += f" (target {self.target_error:.2e}: {'met' if self.target_met else 'NOT met'})"
            lines.append(held)
        else:
            lines.append("no held-out samples (pass validation=... to score the fit)")
        lines.append(
            f"relative gradient residual {self.train_residual:.2e} on {self.n_train} training samples"
            + (f", {self.holdout_residual:.2e} held out" if self.n_holdout else "")
        )
        cal = self.calibration
        if cal:
            lines.append(
                f"error estimate (return_error=True) calibrated on {cal['n_samples']} {cal['source']}: "
                f"median effectivity {cal['median_effectivity']:.2f}, "
                f"{cal['share_under_3x']:.0%} underestimated more than 3x"
            )
        lines += [f"  try: {a}" for a in self.advice]
        return "\n".join(lines)


def diagnose(model, train: FlowMapData, holdout: Optional[FlowMapData]) -> FitDiagnostics:
    """:class:`FitDiagnostics` of a fitted :class:`SymplecticKernelPredictor` (history, hold-out steps).

    ``O(500 m (2n)^2)`` for the hold-out steps (NumPy Newton) besides the greedy's recorded residuals; a search's
    candidate fit without a target (:data:`~sympredict.estimators.search.CANDIDATE_FIT`) skips them (``holdout_step_error`` nan).
    """

    h = model.history_
    m = model.n_centers_
    train_abs = float(h.train_max_residual[-1])
    train_start = float(h.train_max_residual[0])
    rel = train_start if train_start > 0 else 1.0  # E_train(0) is the largest target
    val_curve = h.val_max_residual
    holdout_res = float(val_curve[-1]) / rel if val_curve is not None and holdout is not None else float("nan")
    step_err = float("nan")
    coord_err = None
    # a search's candidate without a target is scored by the search itself: no held-out Newton steps here
    quick = CANDIDATE_FIT.get() and getattr(model, "target_error_", None) is None
    if holdout is not None and len(holdout) and not quick:
        rows = np.arange(len(holdout))[:500]
        sub = holdout.subset(rows)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                pred = model.step(
                    sub.x0, mu=sub.mu if model.n_mu_ else None, dt=sub.dt if model.dt_fixed_ is None else None
                )
            inc = np.linalg.norm(sub.x1 - sub.x0, axis=1)
            ok = inc > 0
            step_err = float(np.median(np.linalg.norm(pred - sub.x1, axis=1)[ok] / inc[ok])) if ok.any() else 0.0
            coord_err = _coordinate_errors(pred, sub)
        except (NewtonConvergenceError, NonFinitePredictionError):
            step_err = float("inf")
    converged = h.stop_reason in ("tol", "target")
    target = getattr(model, "target_error_", None)
    target_met = None if target is None or not np.isfinite(step_err) else bool(step_err <= target)
    # advice only where the model falls short: a missed target, or (without one) a fit the centre budget cut off
    # while it was still improving; a stop by a singular kernel matrix without a target is no shortfall (the
    # greedy used what the kernel can resolve: only a target says whether that is enough)
    short = target_met is not True
    advice = []
    if short and h.stop_reason == "max_centers" and val_curve is not None and m >= 10:
        tail = val_curve[-max(2, m // 5) :]
        if tail[-1] < 0.8 * tail[0]:
            advice.append(
                f"more centres: the hold-out residual still fell by {1 - tail[-1] / tail[0]:.0%} over the "
                f"last fifth of the {m} centres (raise max_centers)"
            )
    if h.stop_reason == "power" and target_met is False:
        advice.append(
            "the kernel matrix became numerically singular before max_centers: more data (more distinct "
            "samples), or narrower kernels (the state or parameter kernel of model.choice_ with a larger "
            "shape eps, passed to the estimator) let the greedy use more centres"
        )
    if np.isfinite(holdout_res) and train_abs > 0 and holdout_res * rel > 10 * train_abs:
        advice.append(
            f"more data: the hold-out residual is {holdout_res * rel / train_abs:.0f}x the training residual, "
            "the samples do not resolve the map between them"
        )
    train_curve = np.asarray(h.train_max_residual, dtype=float)
    if (
        h.stop_reason == "max_centers"
        and m >= 20
        and train_abs / rel > 1e-3
        and train_curve[-1] > 0.3 * train_curve[m // 4]
        and (val_curve is None or float(val_curve[-1]) > 0.3 * float(val_curve[m // 4]))
    ):
        advice.append(
            f"noisy data? the residuals stalled at {train_abs / rel:.1e} of the largest target over the last "
            f"three quarters of the {m} centres, as when the centres fit noise: if the data carry noise, pass "
            "trainer=ExactGreedy(regularization=...) of about the noise's variance, or fewer centres "
            "(max_centers); more centres will not help"
        )
    if holdout is not None and model.n_mu_ and len(holdout) >= 20 and not quick:
        advice += _edge_advice(model, holdout)
    if np.isinf(step_err):
        advice.append("Newton failed on a held-out sample: a smaller dt, the 'midpoint' update, or more centres")
    advice += _coordinate_advice(coord_err, step_err)
    scored = getattr(model, "prefix_errors_", None)
    prefix = (m, max(scored)) if scored else None
    return FitDiagnostics(
        len(train),
        0 if holdout is None else len(holdout),
        m,
        int(model.max_centers),
        str(h.stop_reason),
        converged,
        train_abs / rel,
        holdout_res,
        step_err,
        advice,
        target,
        target_met,
        prefix,
        model,
        coord_err,
    )


def _coordinate_errors(pred: np.ndarray, sub: FlowMapData) -> Optional[np.ndarray]:
    """Per coordinate: median ``|pred_c - x1_c|`` over root-mean-square ``|x1_c - x0_c|`` (nan where it does not move)."""
    rms = np.sqrt(np.mean((sub.x1 - sub.x0) ** 2, axis=0))
    err = np.median(np.abs(pred - sub.x1), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rms > 0, err / np.where(rms > 0, rms, 1.0), np.nan)


def _coordinate_advice(coord_err: Optional[np.ndarray], step_err: float) -> list:
    """Advice naming the coordinates whose hold-out error is large where the median over all of them hides it."""
    if coord_err is None or not np.isfinite(step_err):
        return []
    n = len(coord_err) // 2
    names = [f"q{i + 1}" for i in range(n)] + [f"p{i + 1}" for i in range(n)]
    bad = [i for i in np.flatnonzero(np.nan_to_num(coord_err, nan=0.0) > max(1e-3, 100 * step_err))]
    if not bad:
        return []
    listed = ", ".join(f"{names[i]} {coord_err[i]:.2g}" for i in bad[:4])
    return [
        f"the coordinates {listed} are learned badly (median one-step error relative to their increments; "
        f"{step_err:.2g} over all): if their scale is much smaller than the others', give the states in units "
        "of comparable size"
    ]


def _edge_advice(model, holdout: FlowMapData) -> list:
    """Advice when the gradient residual on hold-out samples near the parameter box's faces is much larger."""

    lo, hi = model.domain_["mu_min"], model.domain_["mu_max"]
    width = np.where(hi > lo, hi - lo, 1.0)
    u = (holdout.mu - lo) / width
    edge = np.any((u < 0.1) | (u > 0.9), axis=1)
    if edge.sum() < 5 or (~edge).sum() < 5:
        return []
    scale = model.model_.scale
    xi, y = as_update(model.update_).variables(holdout.x0 * scale, holdout.x1 * scale, holdout.dt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        res = np.linalg.norm(
            model.surrogate_.gradient(xi, model.surrogate_.weights(holdout.mu, holdout.dt)) - y, axis=1
        )
    inner, outer = float(np.median(res[~edge])), float(np.median(res[edge]))
    if inner > 0 and outer > 3 * inner:
        return [
            f"a wider parameter box: the residual near the box's faces is {outer / inner:.1f}x the interior's, "
            "so sample parameters beyond the range you will query"
        ]
    return []
