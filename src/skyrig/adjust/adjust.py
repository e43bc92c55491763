"""``adjust(block, config) -> AdjustmentResult``: the adjustment stage as one library call."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.model import Layout, Model, State, pad_actuator
from skyrig.adjust.solver import (
    SingularError,
    SolveInfo,
    assemble,
    factor_cost,
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
    critical_value,
    describe_null_space,
    row_cofactors,
)
from skyrig.errors import SkyrigError

logger = logging.getLogger(__name__)

__all__ = ["adjust", "AdjustmentResult", "Rejection", "DatumDefectError"]


class DatumDefectError(SingularError):
    """The block is rank deficient; ``reasons`` says why in words."""

    def __init__(self, reasons: list[str]) -> None:
        self.reasons = reasons
        super().__init__("; ".join(reasons) if reasons else "the normal equations are singular")


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
        non-pose reduced unknown plus ``config.statistics_images`` / ``statistics_points``), from the
        dense inverse when it was computed, otherwise by sparse solves (any block size).
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
            red = (self.layout.rpoint >= 0).all(axis=1)  # type: ignore[operator]
            qd = np.diag(self.covariance.Qcc)
            out[red] = self.sigma0 * np.sqrt(np.clip(qd[self.layout.rpoint[red]], 0, None))  # type: ignore[index]
        return out

    def point_covariance(self) -> NDArray[np.float64] | None:
        """``(P, 3, 3)`` a-posteriori covariance of the points (m²)."""
        if self.covariance is None:
            return None
        out = np.full((self.block.n_points, 3, 3), np.nan)
        free = self.layout.point >= 0
        out[free] = self.sigma0**2 * self.covariance.Qpp[self.layout.point[free]]
        if self.layout.has_rpoint:
            red = (self.layout.rpoint >= 0).all(axis=1)  # type: ignore[operator]
            c = self.layout.rpoint[red]  # type: ignore[index]
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
    if model.layout.act is not None:
        out.actuator_correction = pad_actuator(s.act, len(block.head_name), model.layout.act.shape[1])  # type: ignore[arg-type]
    if model._act_images.size:  # nominal mounting at the adjusted beta correction (without the boresight)
        out.image_rotation = out.image_rotation.copy()  # type: ignore[union-attr]
        out.image_rotation[model._act_images] = model.actuated_mounts(s)[0]  # type: ignore[index]
    return out


def _weights(model: Model) -> dict[str, NDArray[np.float64]]:
    return {"image": model.obs_weight, "control": model.control_weight, "gnss": model.gnss_weight,
            "imu": model.imu_weight, "distance": model.distance_weight}


def _label(block: Block, group: str, i: int) -> str:
    if group == "image":
        return f"point {block.point_name[block.obs_point[i]]} in image {block.image_name[block.obs_image[i]]}"
    if group == "control":
        return f"control point {block.point_name[block.control_point[i]]}"  # type: ignore[index]
    if group == "gnss":
        return f"GNSS position of station {block.station_name[block.gnss_station[i]]}"  # type: ignore[index]
    if group == "imu":
        return f"IMU attitude of station {block.station_name[block.imu_station[i]]}"  # type: ignore[index]
    if group == "distance":
        a, b = block.distance_point[i]  # type: ignore[index]
        return f"distance {block.point_name[a]} - {block.point_name[b]}"
    return f"{group}[{i}]"


def _datum_defect(layout: Layout) -> int:
    """Similarity motions removed by the inner constraints: 7, or 6 when distances fix the scale."""
    return 6 if layout.has_rpoint else 7


def _check_actuated(block: Block, cfg: AdjustConfig) -> None:
    """Name the degenerate actuated-head cases before the rank check does so in general terms."""
    if cfg.actuator == "free" or cfg.actuator_curve == "free":
        for h, head in enumerate(block.head_actuated):  # type: ignore[arg-type]
            sel = block.image_head == h
            if head is None or not sel.any():
                continue
            beta = np.asarray(block.image_beta_rad)[sel]
            # spread of beta on the circle (mean resultant length 1: all images at one angle)
            spread = 1.0 - float(np.hypot(np.cos(beta).mean(), np.sin(beta).mean()))
            if spread < 1e-10:
                raise DatumDefectError([
                    f"the actuator angle beta of head {block.head_name[h]!r} is constant over its {int(sel.sum())} "  # type: ignore[index]
                    f"images ({np.degrees(beta[0]):.4f} deg): its mounting is one fixed rotation, so the actuator "
                    "offset/scale and the boresight curve cannot be separated from the head's boresight; "
                    "fix the 'actuator' and 'actuator_curve' groups (or fly several beta)"])
            n_distinct = np.unique(np.round(np.mod(beta, 2 * np.pi), 6)).size
            need = 2 * int(cfg.actuator_fourier_order) + 1
            if cfg.actuator_curve == "free" and cfg.actuator_fourier_order and n_distinct < need:
                raise DatumDefectError([
                    f"head {block.head_name[h]!r} has images at only {n_distinct} distinct actuator angles: a Fourier "  # type: ignore[index]
                    f"boresight curve of order {cfg.actuator_fourier_order} needs at least {need}"])


def check_datum(model: Model, state: State, free_datum: bool) -> None:
    """Raise :class:`DatumDefectError` (with reasons in words) if the normal equations are singular.

    A Cholesky factorisation can succeed on an exactly singular matrix by round-off; so the factor is
    also checked on a random vector: ``S x = S r`` must give back ``x = r`` (a null space direction
    comes back amplified by ~1/eps).
    """
    lay = model.layout
    if lay.n_c == 0:
        return
    N = assemble(model.evaluate(state), lay, model.block.obs_image)
    S, rhs, _ = schur_matrix(N, 0.0)
    if free_datum:
        return
    try:
        solve_reduced(S, rhs)
        d = S.diagonal()
        if np.all(d > 0):
            r = np.random.default_rng(0).standard_normal(lay.n_c) / np.sqrt(d)
            x = solve_reduced(S, S @ r)
            err = np.linalg.norm((x - r) * np.sqrt(d)) / np.linalg.norm(r * np.sqrt(d))
            if not err < 1e-5:
                raise SingularError(f"numerically singular (round trip error {err:.1e})")
    except SingularError as e:
        reasons = describe_null_space(model, state)
        raise DatumDefectError(reasons or [f"the reduced normal matrix is {e}"]) from None


def adjust(block: Block, config: AdjustConfig | None = None,
           callback: Callable[[str, int, float], None] | None = None) -> AdjustmentResult:
    """Adjust a block.

    Parameters
    ----------
    block
        Observations and starting values (validated first; :class:`~skyrig.adjust.block.BlockError`).
    config
        How; default :class:`AdjustConfig()`.
    callback
        ``callback(stage, iteration, cost)`` after each iteration (progress display).

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
    state = State.from_block(block)
    free = cfg.datum == "free"
    if cfg.datum != "none":
        check_datum(model, state, free)
    huber = cfg.robust_k if cfg.robust == "huber" else None
    crit = critical_value(cfg.snooping_alpha)
    rejected: list[Rejection] = []
    total_info = SolveInfo()
    stage = "adjust"
    while True:
        cb = None if callback is None else (lambda i, c, lam, _s=stage: callback(_s, i, c))
        state, info = levenberg_marquardt(
            model, state, cfg.max_iterations, cfg.function_tolerance, cfg.parameter_tolerance,
            cfg.gradient_tolerance, huber, free, cb)
        if not rejected:
            total_info = info
        else:
            total_info.iterations += info.iterations
            total_info.final_cost = info.final_cost
            total_info.wall_s += info.wall_s
            total_info.converged = info.converged
            total_info.message = info.message
        model = _drop_lost_points(block, model, state, rejected)
        if huber is not None:  # freeze the final Huber weights for the statistics
            f = model.evaluate(state, jacobians=False)[0]
            root = np.sqrt((f.r ** 2).sum(axis=1))
            model.obs_weight = model.obs_weight * np.where(root <= huber, 1.0, huber / np.maximum(root, 1e-300))
            huber = None
        res = _statistics(block, model, state, cfg if cfg.datum != "none" else cfg.with_(statistics=False), free)
        if not cfg.snooping or len(rejected) >= cfg.max_rejections or res[0] is None:
            break
        # data snooping: the largest normalised residual among active observations
        best = (0.0, "", -1)
        for g, gr in res[1].items():
            if gr.normalised is None or g.startswith("prior"):
                continue
            act = gr.weight > 0
            if not act.any():
                continue
            w = np.abs(gr.normalised).max(axis=1)
            w[~act] = 0.0
            i = int(np.argmax(w))
            if w[i] > best[0]:
                best = (float(w[i]), g, i)
        if cfg.snooping_familywise:
            n_tests = sum(int((gr.weight > 0).sum()) * gr.residual.shape[1] for g, gr in res[1].items()
                          if gr.normalised is not None and not g.startswith("prior"))
            crit = critical_value(cfg.snooping_alpha / max(n_tests, 1))
        if best[0] <= crit:
            break
        g, i = best[1], best[2]
        _weights(model)[g][i] = 0.0
        rejected.append(Rejection(g, i, _label(block, g, i), best[0]))
        logger.info("data snooping rejects %s (|w| = %.2f)", rejected[-1].label, best[0])
        if g == "image":
            model = _drop_undetermined_point(block, model, int(block.obs_point[i]), rejected)
        stage = f"snooping {len(rejected)}"
    cov, residuals, groups, sigma0, n_obs, n_unk, warnings, selected, total_info.final_cost = res
    return AdjustmentResult(
        _block_from_state(block, model, state), block, total_info, sigma0, n_obs, n_unk, n_obs - n_unk
        + (_datum_defect(model.layout) if free else 0), groups, residuals, rejected, cov, warnings, model.layout, cfg,
        selected=selected)


def _drop_undetermined_point(block: Block, model: Model, p: int, rejected: list[Rejection]) -> Model:
    """After rejecting an image observation of point ``p``: if ``p`` is left with fewer than two active
    rays (from at least two stations) and is not active control, its other observations cannot be checked either (a two-ray point's
    normalised residuals are equal, the blunder cannot be located), so the point leaves the adjustment."""
    rows = np.flatnonzero(block.obs_point == p)
    active = rows[model.obs_weight[rows] > 0]
    ctrl = np.flatnonzero((block.control_point == p) & (model.control_weight > 0))  # type: ignore[operator]
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
    new.obs_weight, new.control_weight, new.gnss_weight, new.imu_weight, new.distance_weight = (
        model.obs_weight, model.control_weight, model.gnss_weight, model.imu_weight, model.distance_weight)
    return new


def _drop_lost_points(block: Block, model: Model, state: State, rejected: list[Rejection]) -> Model:
    """Points that ended behind one of their cameras (a mismatch pulled through infinity) carry no
    information (zero Jacobian rows) and would make the normal matrix singular: their observations are
    rejected and the points leave the adjustment (control points stay, only the bad rays go)."""
    f = model.evaluate(state, jacobians=False)[0]
    bad = getattr(f, "bad", None)
    if bad is None:
        return model
    bad = bad & (model.obs_weight > 0)
    if not bad.any():
        return model
    ctrl = set(block.control_point[model.control_weight > 0].tolist())  # type: ignore[index, operator]
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


def _statistics(block: Block, model: Model, state: State, cfg: AdjustConfig, free: bool):  # type: ignore[no-untyped-def]
    lay = model.layout
    # without statistics only the cost is needed: no Jacobians, no normal equations
    factors = model.evaluate(state, jacobians=cfg.statistics)
    N = assemble(factors, lay, block.obs_image) if cfg.statistics else None
    cost = N.cost if N is not None else factor_cost(factors)
    n_obs = int(sum(((f.weight if f.weight is not None else np.ones(len(f))) > 0).sum() * f.r.shape[1]
                    for f in factors))
    n_unk = lay.n_c + 3 * lay.n_p
    red = n_obs - n_unk + (_datum_defect(lay) if free else 0)
    sigma0 = float(np.sqrt(2.0 * cost / red)) if red > 0 else float("nan")
    cov = None
    warnings: list[str] = []
    if red <= 0:
        warnings.append(f"no redundancy ({n_obs} observations for {n_unk} unknowns): sigma0 is undefined")
    if cfg.statistics and lay.n_c <= cfg.max_statistics_parameters:
        try:
            cov = covariance(N, lay, state, free)
        except SingularError as e:
            warnings.append(f"covariance not available: {e}")
        if cov is not None:
            warnings.extend(correlation_warnings(cov, lay))
    elif cfg.statistics:
        warnings.append(f"full covariance, redundancy numbers, normalised residuals, variance components and "
                        f"data snooping skipped: they need the dense inverse of the reduced system ({lay.n_c} "
                        f"reduced unknowns > max_statistics_parameters = {cfg.max_statistics_parameters})")
    selected = None
    if cfg.statistics and red > 0:
        cols, pts = chosen_unknowns(model, cfg.statistics_images, cfg.statistics_points)
        if cov is not None:
            selected = selected_from_dense(cov, lay, cols, pts)
        if selected is None and free:
            warnings.append("covariance of the chosen unknowns skipped: a free network above the dense size "
                            "limit needs the pseudo-inverse (use a datum by observations)")
        elif selected is None:
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
        v = f.unwhitened()
        wn = rr = None
        if cov is not None:
            H = row_cofactors(f, cov)
            if H is not None:
                with np.errstate(divide="ignore", invalid="ignore"):
                    qvv = np.where(w[:, None] > 0, 1.0 / np.where(w > 0, w, 1.0)[:, None] - H, 1.0 + H)
                    rr = np.where(w[:, None] > 0, 1.0 - w[:, None] * H, 0.0)
                    wn = np.where(qvv > 1e-12, f.r / np.sqrt(np.clip(qvv, 1e-300, None)), 0.0)
        residuals[f.name] = GroupResiduals(v, wn, rr, w)
        act = w > 0
        r_g = float(rr.sum()) if rr is not None else float("nan")
        vtpv = float((f.r[act] ** 2 * w[act, None]).sum())
        if not f.name.startswith("prior"):
            data_cost += 0.5 * vtpv
        rms = np.sqrt(np.mean(v[act] ** 2, axis=0)).tolist() if act.any() else [float("nan")] * f.r.shape[1]
        groups[f.name] = GroupStats(f.name, int(act.sum()), int(act.sum() * f.r.shape[1]), r_g,
                                    float(np.sqrt(vtpv / r_g)) if r_g and r_g > 0 else float("nan"), rms)
    return cov, residuals, groups, sigma0, n_obs, n_unk, warnings, selected, data_cost
