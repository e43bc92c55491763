"""``adjust(block, config) -> AdjustmentResult``: the adjustment stage as one library call."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from skyrig.adjust.block import AdjustConfig, Block, BlockError
from skyrig.adjust.factors import observation_type, observation_types
from skyrig.adjust.model import Factor, Layout, Model, State, pad_actuator
from skyrig.adjust.solver import (
    SingularError,
    SolveInfo,
    assemble,
    factor_cost,
    inner_constraint_basis,
    levenberg_marquardt,
    schur_matrix,
    solve_reduced,
)
from skyrig.adjust.stats import (
    Covariance,
    GroupStats,
    SelectedCovariance,
    chosen_unknowns,
    selected_covariance,
    selected_from_dense,
    correlation_warnings,
    covariance,
    point_datum_covariance,
    critical_value,
    describe_null_space,
    row_cofactors,
)
from skyrig.errors import DatumDefectError  # noqa: F401 - re-exported (defined in skyrig.errors)

logger = logging.getLogger(__name__)

__all__ = ["adjust", "AdjustmentResult", "Rejection", "DatumDefectError"]


@dataclass
class Rejection:
    """An observation rejected by data snooping."""

    group: str
    index: int
    label: str
    normalised_residual: float


@dataclass
class GroupResiduals:
    """Residuals of one observation group in observation units (computed minus observed)."""

    residual: NDArray[np.float64]
    normalised: NDArray[np.float64] | None
    redundancy: NDArray[np.float64] | None
    weight: NDArray[np.float64]
    #: ``(n,)`` rows that depend on no unknown (e.g. control on fixed points, GNSS of fixed poses): not
    #: observations of this adjustment (not counted, not in sigma0, not tested)
    constant: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))

    def __post_init__(self) -> None:
        if self.constant.shape != self.weight.shape:
            self.constant = np.zeros(self.weight.shape, bool)


@dataclass
class AdjustmentResult:
    """Everything an adjustment produced.

    Attributes
    ----------
    block
        The adjusted block (a copy: stations, points, intrinsics, lever arm... at their adjusted values).
    initial
        The block as given.
    info
        Optimiser record (iterations, costs, wall time).
    sigma0
        A-posteriori standard deviation of unit weight.
    n_observations, n_unknowns, redundancy
        Scalar observations used, unknowns, and their difference (plus datum defect for a free network).
    groups
        Per observation group statistics (variance components).
    residuals
        Per group residuals, normalised residuals and redundancy numbers.
    rejected
        Observations rejected by data snooping, in rejection order.
    covariance
        Cofactors (None when not computed); :meth:`sigma_reduced`, :attr:`point_sigma`.
    warnings
        Near-singularities and other remarks in words.
    layout
        Column labels of the reduced unknowns.
    selected
        Covariance of the chosen unknowns (:class:`~skyrig.adjust.stats.SelectedCovariance`: every
        non-pose reduced unknown plus ``config.statistics.images`` / ``statistics_points``), from the
        dense inverse when it was computed, otherwise by sparse solves (any block size).
    failures
        Why the result must not be trusted, in words (empty when it can): no convergence, sigma0 not
        finite, no redundancy, a single image with points to intersect, data snooping at its cap or
        rejecting an implausible share of a GNSS / IMU / control group (a probable model error).
        :attr:`ok` is True when empty; ``skyrig adjust`` exits non-zero otherwise.
    """

    block: Block
    initial: Block
    info: SolveInfo
    sigma0: float
    n_observations: int
    n_unknowns: int
    redundancy: int
    groups: dict[str, GroupStats]
    residuals: dict[str, GroupResiduals]
    rejected: list[Rejection]
    covariance: Covariance | None
    warnings: list[str]
    layout: Layout
    config: AdjustConfig
    _point_free: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    selected: SelectedCovariance | None = None
    failures: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when nothing in :attr:`failures` speaks against the result."""
        return not self.failures

    def sigma_reduced(self) -> dict[tuple[str, str, str], float]:
        """A-posteriori sigma of every reduced unknown ``{(group, owner, component): sigma}``
        (only the chosen ones, :attr:`selected`, when the full covariance was skipped for size)."""
        if self.covariance is None:
            return self.selected.sigma(self.sigma0) if self.selected is not None else {}
        s = self.sigma0 * np.sqrt(np.clip(np.diag(self.covariance.Qcc), 0, None))
        return dict(zip(self.layout.labels, s.tolist()))

    @property
    def pose_sigma(self) -> NDArray[np.float64] | None:
        """``(S, 6)`` sigma of station centres (m) and rotations (rad); NaN for fixed ones."""
        if self.covariance is None:
            return None
        d = np.concatenate([np.diag(self.covariance.Qcc), [np.nan]])
        return self.sigma0 * np.sqrt(np.clip(d[np.where(self.layout.pose >= 0, self.layout.pose, -1)], 0, None))

    @property
    def point_sigma(self) -> NDArray[np.float64] | None:
        """``(P, 3)`` sigma of the object points (m); NaN for fixed points."""
        if self.covariance is None:
            return None
        out = np.full((self.block.n_points, 3), np.nan)
        free = self.layout.point >= 0
        q = np.diagonal(self.covariance.Qpp, axis1=1, axis2=2)
        out[free] = self.sigma0 * np.sqrt(np.clip(q[self.layout.point[free]], 0, None))
        if self.layout.has_rpoint:
            red = (self.layout.rpoint_cols >= 0).all(axis=1)
            qd = np.diag(self.covariance.Qcc)
            out[red] = self.sigma0 * np.sqrt(np.clip(qd[self.layout.rpoint_cols[red]], 0, None))
        return out

    def point_covariance(self) -> NDArray[np.float64] | None:
        """``(P, 3, 3)`` a-posteriori covariance of the points (m²)."""
        if self.covariance is None:
            return None
        out = np.full((self.block.n_points, 3, 3), np.nan)
        free = self.layout.point >= 0
        out[free] = self.sigma0**2 * self.covariance.Qpp[self.layout.point[free]]
        if self.layout.has_rpoint:
            red = (self.layout.rpoint_cols >= 0).all(axis=1)
            c = self.layout.rpoint_cols[red]
            out[red] = self.sigma0**2 * self.covariance.Qcc[c[:, :, None], c[:, None, :]]
        return out


def _block_from_state(block: Block, model: Model, s: State) -> Block:
    out = block.copy()
    out.station_rotation = s.R.copy()
    out.station_centre = s.C.copy()
    out.cameras = model.cameras(s)
    out.head_boresight = s.bore.copy()
    out.lever_arm = s.lever.copy()
    out.datum_shift = s.shift.copy()
    out.strip_shift = s.sshift.copy()
    out.strip_drift = s.sdrift.copy()
    out.point_xyz = s.X.copy()
    for name, v in s.groups.items():  # the parameter groups factor modules declare
        out.parameters[name] = v.copy()
    if s.grid is not None and out.observations.get("image_grid") is not None:  # estimated correction grids
        out.observations["image_grid"] = out.observations["image_grid"].with_values(s.grid)
    if model.layout.act is not None:
        out.actuator_correction = pad_actuator(s.act, len(block.head_name), model.layout.act.shape[1])
    if model._act_images.size:  # nominal mounting at the adjusted beta correction (without the boresight)
        out.image_rotation = out.image_rotation.copy()
        out.image_rotation[model._act_images] = model.actuated_mounts(s)[0]
    return out


def _weights(model: Model) -> dict[str, NDArray[np.float64]]:
    return model.weights


def _label(block: Block, group: str, i: int) -> str:
    t = observation_type(group)
    return t.label(block, i) if t is not None else f"{group}[{i}]"


def _datum_defect(layout: Layout) -> int:
    """Similarity motions removed by the inner constraints: 7, or 6 when distances fix the scale."""
    return 6 if layout.has_rpoint else 7


def _check_actuated(block: Block, cfg: AdjustConfig) -> None:
    """Name the degenerate actuated-head cases before the rank check does so in general terms."""
    if cfg.unknowns.actuator == "free" or cfg.unknowns.actuator_curve == "free":
        for h, head in enumerate(block.head_actuated):
            sel = block.image_head == h
            if head is None or not sel.any():
                continue
            beta = np.asarray(block.image_beta_rad)[sel]
            # spread of beta on the circle (mean resultant length 1: all images at one angle)
            spread = 1.0 - float(np.hypot(np.cos(beta).mean(), np.sin(beta).mean()))
            if spread < 1e-10:
                raise DatumDefectError([
                    f"the actuator angle beta of head {str(block.head_name[h])!r} is constant over its {int(sel.sum())} "
                    f"images ({np.degrees(beta[0]):.4f} deg): its mounting is one fixed rotation, so the actuator "
                    "offset/scale and the boresight curve cannot be separated from the head's boresight; "
                    "fix the 'actuator' and 'actuator_curve' groups (or fly several beta)"])
            n_distinct = np.unique(np.round(np.mod(beta, 2 * np.pi), 6)).size
            need = 2 * int(cfg.unknowns.actuator_fourier_order) + 1
            if cfg.unknowns.actuator_curve == "free" and cfg.unknowns.actuator_fourier_order and n_distinct < need:
                raise DatumDefectError([
                    f"head {str(block.head_name[h])!r} has images at only {n_distinct} distinct actuator angles: a Fourier "
                    f"boresight curve of order {cfg.unknowns.actuator_fourier_order} needs at least {need}"])


def _check_free_datum(model: Model, state: State, S) -> None:
    """A free network's inner constraints remove the similarity motions that no observation fixes; raise
    :class:`BlockError` naming them when the block's observations (control, GNSS, IMU, pose priors) fix some
    (the inner constraints would then be wrong, the redundancy off by the defect, and the covariance garbage)."""
    from skyrig.adjust.stats import _MOTIONS

    lay = model.layout
    d = S.diagonal()
    if not np.all(d > 0):
        return  # unknowns without observations: named by the solver / covariance
    G = inner_constraint_basis(state, lay)
    on = np.flatnonzero(np.linalg.norm(G, axis=0) > 0)
    sc = 1.0 / np.sqrt(d)
    H = G[:, on] / sc[:, None]  # the motions in the Jacobi-scaled space (unit diagonal)
    H /= np.linalg.norm(H, axis=0)
    r = np.linalg.norm(sc[:, None] * np.asarray(S @ (sc[:, None] * H)), axis=0)  # |D S D h|
    fixed = [_MOTIONS[j] for j, v in zip(on, r) if v > 1e-6]
    if not fixed:
        return
    what = [t.datum_words for t in observation_types() if t.datum_words and t.fixes_datum(model)]
    if model.config.unknowns.poses == "weighted":
        what.append("pose priors (poses='weighted')")
    if model.config.unknowns.points == "fixed":
        what.append("fixed object points (points='fixed')")
    raise BlockError(f"datum='free' takes the datum from inner constraints, but the block's observations "
                     f"({', '.join(what) or 'some observations'}) already fix {', '.join(fixed)}: use datum='auto' "
                     "(the datum from those observations), or leave them out for a free network")


def _reduced_at(model: Model, state: State):
    """``(S (CSR), rhs, engine)`` of the undamped reduced system at ``state``: the compiled Schur engine (no
    scipy BSR products; returned, linearised at ``state``, for the solver to start from), else / on a
    singular point block the reference path (whose error names the points; engine None)."""
    from skyrig.adjust import solver as _solver

    factors = model.evaluate(state)
    lay = model.layout
    if _solver.HAVE_NUMBA:
        eng = _solver.SchurEngine(factors, lay, model.block.obs_image, dense_limit=_solver.ENGINE_DENSE_LIMIT)
        eng.linearize(factors)
        try:
            vals, rhs, _ = eng.reduced_system(0.0)
            return sp.csr_matrix((vals, eng.indices, eng.indptr), shape=(lay.n_c, lay.n_c)), rhs, eng
        except SingularError:
            pass
        del eng
    S, rhs, _ = schur_matrix(assemble(factors, lay, model.block.obs_image), 0.0)
    return S, rhs, None


def _round_trip(S, b: NDArray[np.float64], eng) -> NDArray[np.float64]:
    """``S^-1 b``: above the engine's dense limit with the engine's own sparse direct solver when it is
    exact (its ordering and symbolic factorisation are then the solver's: analysed once per adjustment),
    else :func:`solve_reduced`."""
    from skyrig.adjust import linalg as _linalg
    from skyrig.adjust import solver as _solver

    if eng is not None and eng.linear_solver == "auto" and S.shape[0] > eng.dense_limit:
        if eng._rs is None:
            eng._rs = _linalg.ReducedSolver(eng.indptr, eng.indices, "auto", dense_limit=eng.dense_limit)
        if eng._rs.method in ("cholmod", "splu"):  # (PCG is inexact: no round trip test)
            return eng._solve_csr(S.data, b, None)
    return solve_reduced(S, b)


def check_datum(model: Model, state: State, free_datum: bool):
    """Raise :class:`DatumDefectError` (with reasons in words) if the normal equations are singular.

    Returns the compiled Schur engine linearised at ``state`` (without robust weights), for
    :func:`~skyrig.adjust.solver.levenberg_marquardt` to start from (``engine_at_start``), or None.

    A Cholesky factorisation can succeed on an exactly singular matrix by round-off; so the factor is
    also checked on a random vector: ``S x = S r`` must give back ``x = r`` (a null space direction
    comes back amplified by ~1/eps).
    """
    lay = model.layout
    if lay.n_c == 0:
        return None
    try:
        S, rhs, eng = _reduced_at(model, state)
    except SingularError as e:
        b = model.block
        pts = np.flatnonzero(lay.point >= 0)[getattr(e, "points", np.zeros(0, np.int64))]
        reasons = []
        for p in pts[:10]:
            rows = np.flatnonzero((b.obs_point == p) & (model.obs_weight > 0))
            imgs = ", ".join(str(b.image_name[i]) for i in b.obs_image[rows][:5])
            reasons.append(f"point {b.point_name[p]!s} is not determined: {rows.size} ray(s) from "
                           f"{np.unique(b.image_station[b.obs_image[rows]]).size} station(s) ({imgs or 'none'})")
        raise DatumDefectError(reasons or [str(e)]) from None
    if free_datum:
        _check_free_datum(model, state, S)
        return eng
    try:
        d = S.diagonal()
        if not np.all(d > 0):
            solve_reduced(S, rhs)  # raises (names the unknowns without observations)
        # one factorisation: the round trip S x = S r (the right-hand side itself is not needed here)
        r = np.random.default_rng(0).standard_normal(lay.n_c) / np.sqrt(d)
        x = _round_trip(S, S @ r, eng)
        err = np.linalg.norm((x - r) * np.sqrt(d)) / np.linalg.norm(r * np.sqrt(d))
        if not err < 1e-5:
            raise SingularError(f"numerically singular (round trip error {err:.1e})")
    except SingularError as e:
        eng = None
        reasons = describe_null_space(model, state)
        raise DatumDefectError(reasons or [f"the reduced normal matrix is {e}"]) from None
    return eng


def _start_state(initial: State, start: Block) -> State:
    """The unknowns of ``start`` as a :class:`State` in place of the block's own ``initial`` ones (ValueError when
    they do not correspond)."""
    a, b = initial, State.from_block(start)
    for name in ("R", "C", "bore", "lever", "shift", "sshift", "sdrift", "X", "act", "grid"):
        u, v = getattr(a, name), getattr(b, name)
        if (u is None) != (v is None) or (u is not None and np.shape(u) != np.shape(v)):
            raise BlockError(f"start: its {name} unknowns do not correspond to the block's "
                             f"({None if u is None else np.shape(u)} vs {None if v is None else np.shape(v)})")
    for name, u in a.groups.items():
        if name not in b.groups or np.shape(u) != np.shape(b.groups[name]):
            raise BlockError(f"start: its {name} unknowns do not correspond to the block's")
    if len(a.intr) != len(b.intr) or any(np.shape(u) != np.shape(v) for u, v in zip(a.intr, b.intr)):
        raise BlockError("start: its cameras' intrinsics do not correspond to the block's")
    if not all(np.isfinite(v).all() for v in (b.R, b.C, b.X, *b.intr)):
        raise BlockError("start: non-finite starting values")
    return b


def _left_out_at_start(block: Block, rejected: list[Rejection]) -> list[str]:
    """The warning (logged) about points that start behind a camera and were left out with their rays."""
    start_warnings = []
    if rejected:
        pts = sorted({str(block.point_name[block.obs_point[r.index]]) for r in rejected})
        start_warnings.append(f"{len(pts)} point(s) start behind a camera and were left out of the adjustment "
                              f"({len(rejected)} image observation(s) rejected): "
                              + "; ".join(r.label for r in rejected[:5]) + (" ..." if len(rejected) > 5 else ""))
        for w in start_warnings:
            logger.warning(w)
    return start_warnings


def _add_round(total: SolveInfo, info: SolveInfo) -> None:
    """Fold a later round's solver info (after a rejection) into the adjustment's total."""
    total.iterations += info.iterations
    total.final_cost = info.final_cost
    total.wall_s += info.wall_s
    total.converged = info.converged
    total.message = info.message


def _largest_normalised(groups: dict[str, GroupResiduals]) -> tuple[float, str, int]:
    """``(|w|, group, row)`` of the largest normalised residual among the active, tested observations
    (``(0.0, "", -1)`` when there is none)."""
    best = (0.0, "", -1)
    for g, gr in groups.items():
        if gr.normalised is None or not _tested(g):
            continue
        act = (gr.weight > 0) & ~gr.constant
        if not act.any():
            continue
        w = np.abs(gr.normalised).max(axis=1)
        w[~act] = 0.0
        i = int(np.argmax(w))
        if w[i] > best[0]:
            best = (float(w[i]), g, i)
    return best


def _n_tests(groups: dict[str, GroupResiduals]) -> int:
    """How many residual components data snooping tests (for the family-wise level)."""
    return sum(int((gr.weight > 0).sum()) * gr.residual.shape[1] for g, gr in groups.items()
               if gr.normalised is not None and _tested(g))


def _others_above(groups: dict[str, GroupResiduals], crit: float) -> bool:
    """Whether a tested observation of another group than the images is above the critical value (then only one
    rejection per round: its spill into the images of its station would look like blunders there)."""
    return any(
        gr.normalised is not None and _tested(g) and g != "image"
        and (np.abs(gr.normalised).max(axis=1)[(gr.weight > 0) & ~gr.constant] > crit).any()
        for g, gr in groups.items())


def _snooping_picks(block: Block, model: Model, groups: dict[str, GroupResiduals], snooped: list[Rejection],
                    cfg: AdjustConfig, crit: float) -> tuple[list[tuple[float, str, int]], str | None]:
    """One data-snooping round's rejections ``(|w|, group, index)``; none (with why, when it failed) ends the snooping."""
    msg = _implausible_rejections(model, snooped, cfg)
    if msg:
        return [], msg
    # data snooping: the largest normalised residual among active observations
    best = _largest_normalised(groups)
    if cfg.reliability.familywise:
        crit = critical_value(cfg.reliability.alpha / max(_n_tests(groups), 1))
    if best[0] <= crit:
        return [], None
    n_obs = sum(len(gr.weight) for g, gr in groups.items() if gr.normalised is not None and _tested(g))
    cap = max(int(cfg.reliability.max_rejections), int(np.ceil(cfg.reliability.max_share * n_obs)))
    if len(snooped) >= cap:
        counts = ", ".join(f"{n} {_words(g)}" for g, n in _counts(snooped).items())
        return [], (
            f"data snooping stopped at its cap of {cap} rejections (the larger of max_rejections "
            f"{cfg.reliability.max_rejections} and snooping_max_share {cfg.reliability.max_share:g} of {n_obs} observations; "
            f"{counts}) with observations "
            f"still above the critical value (|w| = {best[0]:.1f} > {crit:.1f}, {_label(block, best[1], best[2])}): "
            "so many blunders mean the functional model is probably wrong - " + _what_to_free(
                cfg, [g for g, _ in sorted(_counts(snooped).items(), key=lambda kv: -kv[1])]))
    picks = [(best[0], best[1], best[2])]
    # several per round only among image observations, and only while no GNSS / IMU / control / ... one is
    # above the critical value (its spill into the images of its station would look like blunders there)
    per_round = max(int(cfg.reliability.per_round), int(np.ceil(cfg.reliability.per_round_share * n_obs)))
    if best[1] == "image" and per_round > 1 and not _others_above(groups, crit):
        room = min(per_round, cap - len(snooped)) - 1
        picks += [(w, "image", j) for w, j in
                  _further_image_rejections(block, groups["image"], best[2], crit, room)]
    return picks, None


def _reject(block: Block, model: Model, picks: list[tuple[float, str, int]], rejected: list[Rejection]) -> Model:
    """Weight the snooped observations out (recorded in ``rejected``); a point left undetermined goes with its rays."""
    for w_, g, i in picks:
        _weights(model)[g][i] = 0.0
        rejected.append(Rejection(g, i, _label(block, g, i), w_))
        logger.info("data snooping rejects %s (|w| = %.2f)", rejected[-1].label, w_)
        if g == "image":
            model = _drop_undetermined_point(block, model, int(block.obs_point[i]), rejected)
    return model


def adjust(block: Block, config: AdjustConfig | None = None,
           callback: Callable[[str, int, float], None] | None = None, start: Block | None = None) -> AdjustmentResult:
    """Adjust a block.

    Parameters
    ----------
    block
        Observations and starting values (validated first; :class:`~skyrig.adjust.block.BlockError`).
    config
        How; default :class:`AdjustConfig()`.
    callback
        ``callback(stage, iteration, cost)`` after each iteration (progress display).
    start
        Optional: a block with the same stations, cameras, heads, strips and points (its observations are not
        used) whose unknowns are the starting values instead of ``block``'s.  ``block``'s own values stay the
        centres of the ``"weighted"`` priors: a self-calibration restarted from its last estimate keeps its
        prior at the nominal camera instead of walking back from it.

    Returns
    -------
    AdjustmentResult

    Raises
    ------
    DatumDefectError
        The block is rank deficient (e.g. no datum); the message says which motions or unknowns.
    """
    cfg = config or AdjustConfig()
    block.validate()
    _check_actuated(block, cfg)
    model = Model(block, cfg)
    state = model.initial.copy() if start is None else _start_state(model.initial, start)
    free = cfg.unknowns.datum == "free"
    if cfg.unknowns.inner_constraints == "points":
        _datum_point_mask(block, model, cfg)  # unknown names / too few points: ValueError before any work
    rejected: list[Rejection] = []
    # points that start behind one of their cameras give no Jacobian there: left out with their rays
    model = _drop_lost_points(block, model, state, rejected)
    start_warnings = _left_out_at_start(block, rejected)
    # the datum check's engine, linearised at the start: the solver's first linearisation
    eng0 = check_datum(model, state, free) if cfg.unknowns.datum != "none" else None
    opt = cfg.solver
    huber = opt.robust_k if opt.robust == "huber" else None
    crit = critical_value(cfg.reliability.alpha)  # familywise: recomputed per round in _snooping_picks
    n_start = len(rejected)
    failures: list[str] = []
    total_info = SolveInfo()
    stage = "adjust"
    first = True
    while True:
        cb = None if callback is None else (lambda i, c, lam, _s=stage: callback(_s, i, c))
        state, info = levenberg_marquardt(
            model, state, opt.max_iterations, opt.function_tolerance, opt.parameter_tolerance,
            opt.gradient_tolerance, huber, free, cb, engine_at_start=eng0)
        eng0 = None
        if first:
            total_info = info
            first = False
        else:
            _add_round(total_info, info)
        model = _drop_lost_points(block, model, state, rejected)
        if free and cfg.unknowns.inner_constraints == "points":
            state = _to_point_datum(block, model, state, _datum_point_mask(block, model, cfg))
        if huber is not None:  # freeze the final Huber weights for the statistics
            f = model.evaluate(state, jacobians=False)[0]
            root = np.sqrt((f.r ** 2).sum(axis=1))
            model.obs_weight = model.obs_weight * np.where(root <= huber, 1.0, huber / np.maximum(root, 1e-300))
            huber = None
        res = _statistics(block, model, state, cfg if cfg.unknowns.datum != "none" else cfg.with_statistics(compute=False), free)
        if not cfg.reliability.snooping or res[0] is None:
            break
        snooped = [r for r in rejected[n_start:] if np.isfinite(r.normalised_residual)]
        picks, msg = _snooping_picks(block, model, res[1], snooped, cfg, crit)
        if msg:
            failures.append(msg)
        if not picks:
            break
        model = _reject(block, model, picks, rejected)
        stage = f"snooping {len(rejected)}"
    cov, residuals, groups, sigma0, n_obs, n_unk, warnings, selected, total_info.final_cost = res
    redundancy = n_obs - n_unk + (_datum_defect(model.layout) if free else 0)
    failures = _failures(block, model, total_info, sigma0, redundancy) + failures
    for w in _variance_component_warnings(groups, cfg):
        logger.warning(w)
        warnings.append(w)
    for why in failures:
        logger.warning("adjustment failed: %s", why)
    return AdjustmentResult(
        _block_from_state(block, model, state), block, total_info, sigma0, n_obs, n_unk, redundancy, groups,
        residuals, rejected, cov, start_warnings + warnings, model.layout, cfg, selected=selected, failures=failures)


def _tested(group: str) -> bool:
    """True for a group of observations proper (tested by data snooping), False for priors."""
    t = observation_type(group)
    return t is None or t.snooped


def _words(group: str) -> str:
    """An observation group in words (its type's ``words``)."""
    t = observation_type(group)
    return t.words if t is not None and t.words else group


def _further_image_rejections(block: Block, gr, first: int, crit: float, room: int) -> list[tuple[float, int]]:
    """Image observations to reject beside ``first`` in one snooping round (``room`` at most): those above
    ``crit`` that are the largest normalised residual of their point and of their image among the
    observations above it, and share neither with a larger one (``first`` included).  Largest first."""
    if room <= 0:
        return []
    act = (gr.weight > 0) & ~gr.constant
    w = np.abs(gr.normalised).max(axis=1)
    w[~act] = 0.0
    cand = np.flatnonzero(w > crit)
    cand = cand[np.argsort(-w[cand], kind="stable")]
    images: set[int] = set()
    points: set[int] = set()
    out: list[tuple[float, int]] = []
    for j in (first, *[int(c) for c in cand if c != first]):
        im, pt = int(block.obs_image[j]), int(block.obs_point[j])
        free = im not in images and pt not in points
        images.add(im)  # a larger residual touched them: what follows there may be its spill
        points.add(pt)
        if free and j != first:
            out.append((float(w[j]), j))
            if len(out) >= room:
                break
    return out


def _counts(rejected: list[Rejection]) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in rejected:
        out[r.group] = out.get(r.group, 0) + 1
    return out


def _what_to_free(cfg: AdjustConfig, groups: list[str]) -> str:
    """Words: which unmodelled effects would make these observation groups disagree, and what to free."""
    hints = []
    for g in groups:
        t = observation_type(g)
        cand = list(t.hints) if t is not None else []
        fix = [(k, why) for k, why in cand if getattr(cfg.unknowns, k) == "fixed"]
        if fix:
            hints.append(f"{_words(g)} observations: probably " + " or ".join(w for _, w in fix)
                         + " (free " + ", ".join(repr(k) for k, _ in fix) + ", e.g. skyrig block --free "
                         + ",".join(k.replace("_", "-") for k, _ in fix) + ")")
        elif cand:
            hints.append(f"{_words(g)} observations: their sigmas or the data themselves")
    return "; ".join(hints) if hints else "check the observations' sigmas and the model"


def _variance_component_warnings(groups: dict[str, GroupStats], cfg: AdjustConfig) -> list[str]:
    """Words for observation groups whose residuals are significantly larger than their sigmas say
    (chi-square test of the group's variance factor ``s^2 r ~ chi2(r)`` at ``cfg.reliability.alpha``, and
    ``s > 1.5``): a model error that data snooping does not show as blunders (e.g. a datum shift between
    GNSS and control spread over all control points), named with what to free."""
    from scipy.stats import chi2

    out = []
    for g, st in groups.items():
        if not _tested(g) or not (st.redundancy > 0.5) or not np.isfinite(st.sigma0):
            continue
        p = float(chi2.sf(st.sigma0**2 * st.redundancy, st.redundancy))
        if p < cfg.reliability.alpha and st.sigma0 > 1.5:
            out.append(f"the {_words(g)} observations fit {st.sigma0:.1f} times worse than their sigmas "
                       f"say (variance factor {st.sigma0:.2f}, redundancy {st.redundancy:.1f}, chi-square test p = "
                       f"{p:.1g}): a probable model error, or sigmas too optimistic - " + _what_to_free(cfg, [g]))
    return out


def _implausible_rejections(model: Model, snooped: list[Rejection], cfg: AdjustConfig) -> str | None:
    """Words when data snooping has rejected more of a GNSS / IMU / control / distance group than blunders
    explain (more than ``cfg.reliability.max_group_share`` of its observations, at least 3)."""
    n_all = {t.name: t.tested_count(model.block) for t in observation_types() if t.share_checked and t.snooped}
    for g, k in _counts(snooped).items():
        n = n_all.get(g, 0)
        if n and k >= 3 and k > cfg.reliability.max_group_share * n:
            others = ", ".join(f"{m} {_words(h)}" for h, m in _counts(snooped).items() if h != g)
            return (f"data snooping rejected {k} of {n} {_words(g)} observations ({100.0 * k / n:.0f} %, more "
                    f"than the {100 * cfg.reliability.max_group_share:.0f} % that blunders explain"
                    + (f"; also {others}" if others else "") + "): the functional model is probably wrong - "
                    + _what_to_free(cfg, [g]) + "; snooping stopped")
    return None


def _failures(block: Block, model: Model, info: SolveInfo, sigma0: float, redundancy: int) -> list[str]:
    """The reasons (in words) why an adjustment result must not be trusted."""
    out = []
    if not info.converged:
        out.append(f"the adjustment did not converge ({info.message or 'no iterations'}, {info.iterations} "
                   "iterations)")
    if redundancy <= 0:
        out.append(f"no redundancy (redundancy {redundancy}): nothing checks the observations and sigma0 is undefined")
    elif not np.isfinite(sigma0):
        out.append(f"sigma0 is {sigma0} (not finite)")
    used = np.unique(block.obs_image[model.obs_weight > 0])
    lay = model.layout
    free = lay.point >= 0
    if lay.has_rpoint:
        free |= (lay.rpoint_cols >= 0).any(axis=1)
    free[block.control_point[model.control_weight > 0]] = False
    if used.size == 1 and free[block.obs_point[model.obs_weight > 0]].any():
        out.append(f"a single image ({block.image_name[used[0]]!s}) cannot intersect object points: give more "
                   "images, or fix the points (points='fixed') for a space resection")
    return out


def _datum_point_mask(block: Block, model: Model, cfg: AdjustConfig) -> NDArray[np.bool_]:
    """``(P,)`` the estimated points that carry the inner constraints (``cfg.unknowns.datum_points``, or all).
    Unknown names and fewer than 3 usable points (or all on one line) raise :class:`BlockError` in words."""
    lay = model.layout
    est = lay.point >= 0
    if lay.has_rpoint:
        est = est | (lay.rpoint_cols >= 0).all(axis=1)
    if not cfg.unknowns.datum_points:
        mask = est.copy()
    else:
        idx = {str(n): k for k, n in enumerate(block.point_name)}
        bad = [n for n in cfg.unknowns.datum_points if n not in idx]
        if bad:
            raise BlockError(f"datum_points names unknown points {bad[:5]}")
        mask = np.zeros(block.n_points, bool)
        mask[[idx[n] for n in cfg.unknowns.datum_points]] = True
        gone = [str(block.point_name[k]) for k in np.flatnonzero(mask & ~est)]
        if gone:
            logger.warning("datum points not estimated (fixed or left out of the adjustment): %s", gone[:5])
        mask &= est
    if mask.sum() < 3:
        raise BlockError(f"inner constraints on points need at least 3 estimated datum points, got {int(mask.sum())}")
    X = model.block.point_xyz[mask]
    if np.linalg.matrix_rank(X - X.mean(axis=0), tol=1e-9 * max(1.0, float(np.abs(X).max()))) < 2:
        raise BlockError("the datum points lie on one line: inner constraints on them leave a rotation about that "
                         "line undetermined")
    return mask


def _to_point_datum(block: Block, model: Model, state: State, mask: NDArray[np.bool_]) -> State:
    """The adjusted block moved by the similarity (without scale when distances fix it) that brings its
    datum points closest to their starting coordinates (least squares): the nonlinear form of inner
    constraints on those points (at the optimum ``B^T (X - X0) = 0``)."""
    X, X0 = state.X[mask], block.point_xyz[mask]
    mx, m0 = X.mean(axis=0), X0.mean(axis=0)
    A, A0 = X - mx, X0 - m0
    U, sv, Vt = np.linalg.svd(A0.T @ A)  # rotation R maximising sum (R a) . a0
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = 1.0 if model.layout.has_rpoint else float((sv * np.diag(D)).sum() / (A**2).sum())
    t = m0 - s * R @ mx
    out = state.copy()
    out.C = s * state.C @ R.T + t
    out.R = R[None] @ state.R
    out.X = s * state.X @ R.T + t
    return out


def _drop_undetermined_point(block: Block, model: Model, p: int, rejected: list[Rejection]) -> Model:
    """After rejecting an image observation of point ``p``: if ``p`` is left with fewer than two active
    rays (from at least two stations) and is not active control, its other observations cannot be checked either (a two-ray point's
    normalised residuals are equal, the blunder cannot be located), so the point leaves the adjustment."""
    rows = np.flatnonzero(block.obs_point == p)
    active = rows[model.obs_weight[rows] > 0]
    ctrl = np.flatnonzero((block.control_point == p) & (model.control_weight > 0))
    # two rays from one station (heads of one rig exposure share a projection centre) have no base
    if np.unique(block.image_station[block.obs_image[active]]).size >= 2 or ctrl.size:
        return model
    for j in active:
        model.obs_weight[j] = 0.0
        rejected.append(Rejection("image", int(j), _label(block, "image", int(j)) + " (point left with one ray)",
                                  float("nan")))
    act = model.point_active.copy()
    act[p] = False
    return _with_points(block, model, act)


def _with_points(block: Block, model: Model, point_active: NDArray[np.bool_]) -> Model:
    """``model`` rebuilt for another set of active points, keeping its (snooping / Huber) weights."""
    new = Model(block, model.config, point_active)
    new.weights = model.weights
    return new


def _drop_lost_points(block: Block, model: Model, state: State, rejected: list[Rejection]) -> Model:
    """Points that ended behind one of their cameras (a mismatch pulled through infinity) carry no
    information (zero Jacobian rows) and would make the normal matrix singular: their observations are
    rejected and the points leave the adjustment (control points stay, only the bad rays go)."""
    f = model.evaluate(state, jacobians=False)[0]
    bad = f.bad
    if bad is None:
        return model
    bad = bad & (model.obs_weight > 0)
    if not bad.any():
        return model
    ctrl = set(block.control_point[model.control_weight > 0].tolist())
    act = model.point_active.copy()
    for p in np.unique(block.obs_point[bad]):
        rows = np.flatnonzero(block.obs_point == p)
        rows = rows[(model.obs_weight[rows] > 0) & (bad[rows] | (int(p) not in ctrl))]
        for j in rows:
            model.obs_weight[j] = 0.0
            rejected.append(Rejection("image", int(j), _label(block, "image", int(j)) + " (point behind a camera)",
                                      float("nan")))
        if int(p) not in ctrl:
            act[p] = False
    return _with_points(block, model, act)


def _statistics(block: Block, model: Model, state: State, cfg: AdjustConfig, free: bool):
    lay = model.layout
    # without statistics only the cost is needed: no Jacobians, no normal equations
    factors = model.evaluate(state, jacobians=cfg.statistics.compute)
    N = assemble(factors, lay, block.obs_image) if cfg.statistics.compute else None
    # rows that depend on no unknown (control of fixed points, GNSS/IMU of fixed poses...) are constants,
    # not observations: they count neither as observations nor in the cost behind sigma0
    varying = {f.name: model.varying_rows(f) for f in factors}
    cost = factor_cost([Factor(f.name, f.r * varying[f.name][:, None], f.sigma, weight=f.weight) for f in factors])
    n_obs = int(sum((((f.weight if f.weight is not None else np.ones(len(f))) > 0) & varying[f.name]).sum()
                    * f.r.shape[1] for f in factors))
    n_obs += int(sum(f.n_extra for f in factors))  # observations reduced to fewer square-root rows
    n_unk = lay.n_c + 3 * lay.n_p
    red = n_obs - n_unk + (_datum_defect(lay) if free else 0)
    sigma0 = float(np.sqrt(2.0 * cost / red)) if red > 0 else float("nan")
    cov = None
    warnings: list[str] = []
    if red <= 0:
        warnings.append(f"no redundancy ({n_obs} observations for {n_unk} unknowns): sigma0 is undefined")
    if N is not None and lay.n_c <= cfg.statistics.max_parameters:  # (N: statistics.compute)
        try:
            cov = covariance(N, lay, state, free)
            if free and cfg.unknowns.inner_constraints == "points":
                cov = point_datum_covariance(cov, N, lay, state, _datum_point_mask(block, model, cfg))
        except (SingularError, ValueError) as e:
            warnings.append(f"covariance not available: {e}")
        if cov is not None:
            warnings.extend(correlation_warnings(cov, lay))
    elif cfg.statistics.compute:
        warnings.append(f"full covariance, redundancy numbers, normalised residuals, variance components and "
                        f"data snooping skipped: they need the dense inverse of the reduced system ({lay.n_c} "
                        f"reduced unknowns > max_statistics_parameters = {cfg.statistics.max_parameters})")
    selected = None
    if cfg.statistics.compute and red > 0:
        cols, pts = chosen_unknowns(model, cfg.statistics.images, cfg.statistics.points)
        if cov is not None:
            selected = selected_from_dense(cov, lay, cols, pts)
        if selected is None and free:
            warnings.append("covariance of the chosen unknowns skipped: a free network above the dense size "
                            "limit needs the pseudo-inverse (use a datum by observations)")
        elif selected is None and N is not None:
            try:
                selected = selected_covariance(N, lay, cols, pts)
                warnings.append(f"covariance computed for {len(cols)} chosen reduced unknowns and {len(pts)} "
                                f"chosen points by sparse solves (statistics_images / statistics_points)")
            except SingularError as e:
                warnings.append(f"covariance of the chosen unknowns not available: {e}")
    residuals: dict[str, GroupResiduals] = {}
    groups: dict[str, GroupStats] = {}
    data_cost = 0.0  # cost of the observations, priors left out
    for f in factors:
        w = f.weight if f.weight is not None else np.ones(len(f))
        const = ~varying[f.name]
        v = f.unwhitened()
        wn = rr = None
        if cov is not None:
            H = row_cofactors(f, cov)
            if H is not None:
                with np.errstate(divide="ignore", invalid="ignore"):
                    qvv = np.where(w[:, None] > 0, 1.0 / np.where(w > 0, w, 1.0)[:, None] - H, 1.0 + H)
                    rr = np.where((w > 0)[:, None] & ~const[:, None], 1.0 - w[:, None] * H, 0.0)
                    wn = np.where((qvv > 1e-12) & ~const[:, None], f.r / np.sqrt(np.clip(qvv, 1e-300, None)), 0.0)
        residuals[f.name] = GroupResiduals(v, wn, rr, w, const)
        act = (w > 0) & ~const
        r_g = float(rr.sum()) if rr is not None else float("nan")
        vtpv = float((f.r[act] ** 2 * w[act, None]).sum())
        if _tested(f.name):
            data_cost += 0.5 * vtpv
        rms = np.sqrt(np.mean(v[act] ** 2, axis=0)).tolist() if act.any() else [float("nan")] * f.r.shape[1]
        groups[f.name] = GroupStats(f.name, int(act.sum()), int(act.sum() * f.r.shape[1]), r_g,
                                    float(np.sqrt(vtpv / r_g)) if r_g and r_g > 0 else float("nan"), rms)
    return cov, residuals, groups, sigma0, n_obs, n_unk, warnings, selected, data_cost
