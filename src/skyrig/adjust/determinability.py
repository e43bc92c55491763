"""Determinability of self-calibrated camera parameters: can the block tell them, or does it only repeat the prior
(or contradict it)?

For each self-calibrated intrinsic of one camera, from an adjustment that estimated it with a weighted prior
(``AdjustConfig(unknowns=Unknowns(intrinsics="weighted"))``), :func:`determinability` gives:

- the prior (value, sigma) and the estimate with its a-posteriori sigma (``sigma0 * sqrt(q)``);
- the *formal* sigma ``sqrt(q)`` over the prior sigma: the share of the prior's uncertainty the block leaves.  The
  prior's own row is in the normal equations, so this ratio is at most 1; near 1 the block adds nothing;
- the prior test ``z = (estimate - prior) / sqrt(prior_sigma^2 - formal_sigma^2)``: the difference between a prior and
  the estimate it enters has exactly that variance when the prior and the model are right, so ``|z| > 3`` says the
  block contradicts the camera's metadata -- the metadata is wrong, or (far more often on real flights) the model is:
  unmodelled rolling shutter, a flat block's focal/height valley, barometric heights;
- its correlation with the **ground height** (the mean height of the block's object points relative to the datum the
  block's other observations give) and with the other calibration parameters above 0.7.

**Rule** (stated, configurable): a parameter is *determined* when ``formal sigma <= ratio_max x prior sigma``
(default 0.5: the block at least halves the prior's sigma) and ``|z| <= z_max`` (default 3).  Otherwise:

- ratio above ``ratio_max``: *not determinable*, held at its prior;
- ``|z| > z_max`` with a weak geometry (ratio above ``strong_ratio``, default 0.3): *contradicts its prior*, held at its
  prior -- a block that barely determines the parameter and still pulls it many sigmas away is following a model error
  more likely than correcting the metadata (brighton: ratio 0.44, z +10.4, the ground then 8-10 m low);
- ``|z| > z_max`` with a strong geometry (ratio at most ``strong_ratio``): *overrules its prior*, left free with a
  warning that the metadata is contradicted -- a block that determines the parameter several times better than the
  prior is believed over metadata that is often wrong (lund's phone: EXIF 35-mm value 995 px, the block 683 +- 12 px
  with ratio 0.27, pycolmap agreeing).

The caller holds the held ones at their prior and says so in words with the geometry that would determine them
(:func:`remedy`).

Layer 2b: arrays and adjustment results in, plain data out.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["ParameterVerdict", "determinability", "hold_undetermined", "rule_words", "OVERRULES_PRIOR", "remedy", "ground_height_correlation", "DETERMINED",
           "NOT_DETERMINABLE", "CONTRADICTS_PRIOR"]

DETERMINED = "determined"
NOT_DETERMINABLE = "not determinable"
CONTRADICTS_PRIOR = "contradicts its prior"
OVERRULES_PRIOR = "overrules its prior"

#: what would determine each kind of parameter, in words
_REMEDY = {
    "focal_mm": ("a flat block georeferenced by GNSS alone cannot separate the focal length from the ground's height: "
                 "fly cross strips at a second altitude, add oblique images, or measure control points with heights"),
    "pp": ("the principal point trades with the camera positions and attitudes: fly strips in opposite and crossing "
           "directions, or measure control points"),
    "dist": ("distortion needs tie points spread to the image corners over varied depths: more overlap, cross strips, "
             "or a calibration on a test field"),
}


def rule_words(ratio_max: float, z_max: float, strong_ratio: float) -> str:
    """The determinability rule in words (reports)."""
    return (f"determined when the formal sigma <= {ratio_max:g} x the prior sigma and the prior test |z| <= {z_max:g}; "
            f"otherwise held at the prior, unless the formal sigma is <= {strong_ratio:g} x the prior's (then it "
            "overrules the prior, with a warning)")


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:]


def remedy(name: str) -> str:
    """The geometry that would determine intrinsic ``name``, in words."""
    if name == "focal_mm":
        return _REMEDY["focal_mm"]
    if name in ("ppx_mm", "ppy_mm"):
        return _REMEDY["pp"]
    return _REMEDY["dist"]


@dataclass(frozen=True)
class ParameterVerdict:
    """One calibration parameter's determinability (units: the camera's, e.g. mm for focal_mm; ``*_px`` in pixels
    where the parameter is a length in the image)."""

    name: str
    prior: float
    prior_sigma: float
    estimate: float
    sigma: float
    formal_sigma: float
    ratio: float
    z_prior: float
    corr_ground_height: float
    correlations: dict[str, float] = field(default_factory=dict)
    verdict: str = DETERMINED
    held: bool = False
    freed_on_request: bool = False
    pixel_size_mm: float | None = None

    def words(self) -> str:
        px = self.pixel_size_mm if self.name in ("focal_mm", "ppx_mm", "ppy_mm") and self.pixel_size_mm else None

        def v(x: float) -> str:
            return f"{x / px:.1f} px" if px else f"{x:.4g}"

        base = (f"{self.name}: estimate {v(self.estimate)} +- {v(self.sigma)}, prior {v(self.prior)} +- "
                f"{v(self.prior_sigma)} (formal sigma {self.ratio:.2f} x the prior's, prior test z = {self.z_prior:+.1f}, "
                f"correlation with the ground height {self.corr_ground_height:+.2f})")
        if self.verdict == DETERMINED:
            return base + ": determined by the block"
        if self.verdict == OVERRULES_PRIOR:
            return base + (": overrules its prior (the block determines it several times better than the prior and "
                           "contradicts the camera's metadata: the metadata is probably wrong; the block's value is "
                           "kept. Check it with a calibrated camera or control points)")
        if self.freed_on_request:
            return base + f": {self.verdict}, but left free on request (explicit option); treat it with care"
        why = ("the block barely improves on the prior" if self.verdict == NOT_DETERMINABLE else
               "the block contradicts the camera's metadata (a model error such as rolling shutter, a flat block's "
               "focal/height valley, or wrong metadata)")
        return base + f": {self.verdict} ({why}); held at its prior. {_sentence(remedy(self.name))}"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["words"] = self.words()
        return d


def ground_height_correlation(res: Any, labels: Sequence[tuple[str, str, str]]) -> np.ndarray:
    """Correlation of each reduced unknown in ``labels`` with the mean height (z) of the block's free object points.

    With ``Q`` the reduced cofactors, ``V_p`` the inverse point blocks and ``M = Q W`` (``Covariance.M``), the
    cross cofactor of column ``c`` with point ``p`` is ``-(M_p V_p)[c, :]``; the mean height's cofactor is
    ``(sum_p V_p[z, z] + g^T Q g) / n^2`` with ``Q g = h = sum_p M_p V_p[:, z]``.  NaN when the covariance or its cross
    terms are not available."""
    out = np.full(len(labels), np.nan)
    cov, lay = getattr(res, "covariance", None), res.layout
    if cov is None or cov.M is None:
        return out
    free = np.flatnonzero(lay.point >= 0)
    if len(free) == 0:
        return out
    pi = lay.point[free]
    Vz = cov.Vinv[pi][:, :, 2]  # (n, 3)  V_p[:, z]
    if isinstance(cov.M, np.ndarray):
        cols3 = 3 * pi[:, None] + np.arange(3)[None, :]  # (n, 3)
        h = np.einsum("cna,na->c", cov.M[:, cols3], Vz)  # Q g
    elif getattr(cov, "W", None) is not None:  # M on the pattern only: h = Q (W z), z the points' V_p[:, z]
        z = np.zeros(cov.W.shape[1])
        z[(3 * pi[:, None] + np.arange(3)[None, :]).reshape(-1)] = Vz.reshape(-1)
        h = cov.Qcc @ np.asarray(cov.W @ z).reshape(-1)
    else:
        return out
    try:
        g = np.linalg.solve(cov.Qcc, h)
    except np.linalg.LinAlgError:
        return out
    n = len(pi)
    var_mean = (float(np.sum(cov.Vinv[pi][:, 2, 2])) + float(g @ h)) / n**2
    col = {lab: j for j, lab in enumerate(lay.labels)}
    for k, lab in enumerate(labels):
        j = col.get(tuple(lab))
        if j is None:
            continue
        cov_cz = -h[j] / n
        var_c = cov.Qcc[j, j]
        if var_c > 0 and var_mean > 0:
            out[k] = cov_cz / np.sqrt(var_c * var_mean)
    return out


def determinability(res: Any, camera_name: str, names: Sequence[str], prior: Mapping[str, float],
                    prior_sigma: Mapping[str, float], *, ratio_max: float = 0.5, z_max: float = 3.0,
                    free_anyway: Sequence[str] = (), pixel_size_mm: float | None = None,
                    corr_limit: float = 0.7, strong_ratio: float = 0.3) -> list[ParameterVerdict]:
    """Verdicts of the self-calibrated intrinsics ``names`` of camera ``camera_name`` (see the module docstring).

    Parameters
    ----------
    res
        :class:`~skyrig.adjust.AdjustmentResult` computed with statistics (covariance) and weighted intrinsics.
    prior, prior_sigma
        Prior value and sigma per intrinsic name (the camera's units).
    free_anyway
        Names left free whatever the verdict (the explicit option); their verdict still says what the block shows.
    """
    lay = res.layout
    col = {lab: j for j, lab in enumerate(lay.labels)}
    labels = [("intrinsics", camera_name, nm) for nm in names]
    idx = [col.get(lab) for lab in labels]
    cov = getattr(res, "covariance", None)
    Q = None
    if cov is not None:
        Q = cov.Qcc
    elif getattr(res, "selected", None) is not None:
        sel = res.selected
        scol = {lab: j for j, lab in enumerate(sel.labels)}
        idx = [scol.get(lab) for lab in labels]
        Q = sel.Qcc
    corr_h = ground_height_correlation(res, labels)
    cam = next(c for c in res.block.cameras if c.name == camera_name)
    values = dict(zip(cam.intrinsic_names, np.asarray(cam.intrinsics, float)))
    s0 = float(res.sigma0) if np.isfinite(res.sigma0) else float("nan")
    out: list[ParameterVerdict] = []
    for k, nm in enumerate(names):
        j = idx[k]
        q = float(Q[j, j]) if (Q is not None and j is not None) else float("nan")
        formal = float(np.sqrt(max(q, 0.0)))
        ps = float(prior_sigma[nm])
        est = float(values[nm])
        ratio = formal / ps if ps > 0 else float("nan")
        denom = np.sqrt(max(ps**2 - formal**2, (0.05 * ps) ** 2))
        z = (est - float(prior[nm])) / denom
        corrs: dict[str, float] = {}
        if Q is not None and j is not None:
            for m, other in enumerate(names):
                jm = idx[m]
                if m == k or jm is None:
                    continue
                r = Q[j, jm] / np.sqrt(Q[j, j] * Q[jm, jm]) if Q[j, j] > 0 and Q[jm, jm] > 0 else np.nan
                if np.isfinite(r) and abs(r) >= corr_limit:
                    corrs[other] = float(r)
        if not np.isfinite(ratio) or ratio > ratio_max:
            verdict = NOT_DETERMINABLE
        elif abs(z) > z_max:
            verdict = CONTRADICTS_PRIOR if ratio > strong_ratio else OVERRULES_PRIOR
        else:
            verdict = DETERMINED
        freed = verdict not in (DETERMINED, OVERRULES_PRIOR) and nm in free_anyway
        out.append(ParameterVerdict(nm, float(prior[nm]), ps, est, s0 * formal, formal, float(ratio), float(z),
                                    float(corr_h[k]), corrs, verdict,
                                    held=verdict not in (DETERMINED, OVERRULES_PRIOR) and not freed,
                                    freed_on_request=freed, pixel_size_mm=pixel_size_mm))
    return out


def hold_undetermined(res: Any, nominal: Any, names_cal: tuple[str, ...], prior_sigma: Mapping[str, float],
                      readjust: Callable[[Any, tuple[str, ...], Any], Any], *, ratio_max: float = 0.5,
                      z_max: float = 3.0, free_anyway: Sequence[str] = (), strong_ratio: float = 0.3
                      ) -> tuple[Any, list[ParameterVerdict], tuple[str, ...]]:
    """Judge the self-calibrated intrinsics ``names_cal`` of ``res`` (one camera, priors centred on ``nominal``) and
    hold those not determined at their prior: ``readjust(res, names_left_free, start_camera)`` re-adjusts the block
    with only ``names_left_free`` self-calibrated, from the estimate with the held ones reset to their prior values.
    Each held parameter is a warning in words (:meth:`ParameterVerdict.words`).  Holding one can change what the
    others show, so the re-adjustment is judged once more.

    Returns the final result, every verdict (held ones first, with the estimate that was refused) and the names left
    free."""
    cam_name = res.block.cameras[0].name
    prior = dict(zip(nominal.intrinsic_names, np.asarray(nominal.intrinsics, float)))
    pix = nominal.pixel_size_mm

    def judge(r: Any, names: tuple[str, ...]) -> list[ParameterVerdict]:
        return determinability(r, cam_name, names, prior, prior_sigma, ratio_max=ratio_max, z_max=z_max,
                               free_anyway=free_anyway, pixel_size_mm=pix, strong_ratio=strong_ratio)

    verdicts = judge(res, names_cal)
    held: dict[str, ParameterVerdict] = {}
    for _ in range(2):
        new = [v for v in verdicts if v.held and v.name not in held]
        if not new:
            break
        for v in new:
            held[v.name] = v
            logger.warning("self-calibration: %s", v.words())
        names_cal = tuple(nm for nm in names_cal if nm not in held)
        cam_est = res.block.cameras[0]
        vals = dict(zip(cam_est.intrinsic_names, np.asarray(cam_est.intrinsics, float)))
        vals.update({nm: prior[nm] for nm in held})
        start_cam = cam_est.with_intrinsics(np.array([vals[nm] for nm in cam_est.intrinsic_names]))
        res = readjust(res, names_cal, start_cam)
        verdicts = judge(res, names_cal) if names_cal else []
    for v in verdicts:
        if v.verdict == OVERRULES_PRIOR or v.freed_on_request:
            logger.warning("self-calibration: %s", v.words())
    return res, [*held.values(), *verdicts], names_cal
