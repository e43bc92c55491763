"""Rig files: YAML, ``format: skyrig-rig``, ``version: 1`` (documented in ``docs/formats/rig_file.md``).

Every quantity carries its unit in its key (``lever_arm_m``, ``focal_mm``, ``pixel_size_um``,
``*_deg``).  Unknown keys are errors; every error names the file, the line and the key path
(e.g. ``heads[1].camera.focal_mm``).  Writing goes to a temporary file renamed into place.

A *calibrated* rig file adds optional ``calibration`` sections (top level and per head): sigma and
correlations of the lever arms, boresights, interior orientations and actuator curve, and provenance.
:func:`read_rig` checks them and returns the :class:`~skyrig.rig.rig.Rig` (so every command that takes a
rig takes a calibrated one); :func:`read_calibrated_rig` returns the
:class:`~skyrig.calibrate.rig_calibration.RigCalibration` as well.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any

import numpy as np
import yaml

from skyrig.calibrate.rig_calibration import (
    BORESIGHT_PARAMETERS,
    LEVER_ARM_PARAMETERS,
    CovarianceBlock,
    HeadCalibration,
    Provenance,
    RigCalibration,
)
from skyrig.camera.aspect import fx_fy_px, with_fx_fy
from skyrig.camera.distortion import NoDistortion
from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.io._text import atomic_write, read_text
from skyrig.io._yaml_lines import _LineLoader, _Map, _Seq, load_yaml_lines  # noqa: F401 - re-exported
from skyrig.rig.boresight_curve import BoresightCurve
from skyrig.rig.rig import ActuatedHead, Head, Rig, boresight_from_opk, mounting_from_rpy

logger = logging.getLogger(__name__)

FORMAT = "skyrig-rig"
VERSION = 1
_DEG = 180.0 / np.pi
#: Writers fall back to ``mounting_matrix`` when |pitch| of the view is this close to 90 deg (gimbal lock).
_GIMBAL_LOCK_COS = 1e-6


# YAML with line numbers: skyrig.io._yaml_lines (shared with the scanner records and the project file)


class _Ctx:
    """Where we are in the file, for error messages."""

    def __init__(self, path: str) -> None:
        self.path = path

    def error(self, message: str, m: _Map | None, key_path: str, key: str | None = None) -> InputFormatError:
        line = None
        if m is not None:
            line = m.key_lines.get(key, m.line) if key is not None else m.line
        return InputFormatError(message, self.path, line, key_path)

    def mapping(self, value: Any, parent: _Map | None, key_path: str, key: str | None,
                allowed: set[str], required: set[str]) -> _Map:
        if not isinstance(value, _Map):
            raise self.error(f"expected a mapping, got {type(value).__name__}", parent, key_path, key)
        for k in value:
            if k not in allowed:
                sub = f"{key_path}.{k}" if key_path else k
                raise self.error(f"unknown key {k!r} (allowed: {', '.join(sorted(allowed))})", value, sub, k)
        for k in sorted(required):
            if k not in value:
                sub = f"{key_path}.{k}" if key_path else k
                raise self.error(f"missing key {k!r}", value, sub)
        return value

    def number(self, m: _Map, key: str, key_path: str, positive: bool = False) -> float:
        v = m[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise self.error(f"expected a finite number, got {v!r}", m, key_path, key)
        if positive and v <= 0:
            raise self.error(f"must be positive, got {v!r}", m, key_path, key)
        return float(v)

    def integer(self, m: _Map, key: str, key_path: str) -> int:
        v = m[key]
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise self.error(f"expected a positive integer, got {v!r}", m, key_path, key)
        return int(v)

    def text(self, m: _Map, key: str, key_path: str) -> str:
        v = m[key]
        if not isinstance(v, str) or not v.strip():
            raise self.error(f"expected non-empty text, got {v!r}", m, key_path, key)
        return v

    def numbers(
        self, m: _Map, key: str, key_path: str, shape: tuple[int, ...] | None = None, allow_null: bool = False
    ) -> np.ndarray:
        """A (nested) list of finite numbers as an array; ``null`` entries become NaN if allowed."""
        v = m[key]
        try:
            if not isinstance(v, list):
                raise TypeError
            flat = list(np.ravel(np.array(v, dtype=object)))
            if any(isinstance(x, (bool, str)) or (x is None and not allow_null) for x in flat):
                raise TypeError
            arr = np.array(_nulls_to_nan(v), dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(f"expected a list of numbers, got {v!r}", m, key_path, key) from None
        if shape is not None and arr.shape != shape:
            raise self.error(f"expected shape {shape}, got {arr.shape}", m, key_path, key)
        if np.any(np.isinf(arr)) or (not allow_null and np.any(np.isnan(arr))):
            raise self.error("values must be finite numbers", m, key_path, key)
        return arr


def _nulls_to_nan(v: Any) -> Any:
    if isinstance(v, list):
        return [_nulls_to_nan(x) for x in v]
    return np.nan if v is None else v


# ---------------------------------------------------------------------- distortion hooks
def _distortion_from_dict() -> Callable[[dict[str, Any]], Any] | None:
    for module in ("skyrig.camera.distortion", "skyrig.camera"):
        try:
            mod = __import__(module, fromlist=["distortion_from_dict"])
        except ImportError:  # pragma: no cover - the package always has these modules
            continue
        fn = getattr(mod, "distortion_from_dict", None)
        if fn is not None:
            return fn  # type: ignore[no-any-return]
    return None


def _distortion_registry() -> dict[str, Any] | None:
    try:
        from skyrig.camera import distortion as mod
    except ImportError:  # pragma: no cover
        return None
    fn = getattr(mod, "distortion_models", None)
    return None if fn is None else {str(k).lower(): v for k, v in fn().items()}


def _plain(value: Any) -> Any:
    """numpy containers/scalars -> plain Python for YAML."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def _unplain(value: Any) -> Any:
    """Our line-annotated containers -> plain dict/list (for distortion_from_dict)."""
    if isinstance(value, dict):
        return {k: _unplain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_unplain(v) for v in value]
    return value


# ---------------------------------------------------------------------- reading
_CAMERA_KEYS = {"name", "width_px", "height_px", "pixel_size_um", "focal_mm", "ppx_mm", "ppy_mm", "distortion"}
_HEAD_KEYS = {"name", "camera", "lever_arm_m", "mounting_rpy_deg", "mounting_matrix", "boresight_opk_deg", "actuator",
              "calibration"}
_ACTUATOR_KEYS = {"type", "gamma_deg", "law", "boresight_curve"}
_CURVE_KEYS = {"interpolation", "beta_deg", "droll_deg", "dpitch_deg", "dyaw_deg", "std_deg", "count"}
_STD_KEYS = {"droll_deg", "dpitch_deg", "dyaw_deg"}
_TOP_KEYS = {"format", "version", "name", "description", "antenna_lever_arm_m", "heads", "calibration", "scanners"}
_BLOCK_KEYS = {"parameters", "sigma", "correlation", "values"}
_PROV_KEYS = {"recipe", "flight", "date", "software", "statistics", "notes"}
_HEAD_CAL_KEYS = {"lever_arm_m", "boresight_opk_deg", "interior", "actuator", "provenance"}
_TOP_CAL_KEYS = {"antenna_lever_arm_m", "provenance"}


def _read_block(ctx: _Ctx, value: Any, parent: _Map, kp: str, key: str, fixed: tuple[str, ...] | None = None,
                allowed_names: tuple[str, ...] | None = None, need_values: bool = False) -> CovarianceBlock:
    """A covariance block ``{parameters, sigma, correlation[, values]}``."""
    required = {"sigma"} | ({"parameters"} if fixed is None else set()) | ({"values"} if need_values else set())
    m = ctx.mapping(value, parent, kp, key, _BLOCK_KEYS if need_values else _BLOCK_KEYS - {"values"}, required)
    if "parameters" in m:
        names = m["parameters"]
        if not isinstance(names, list) or not names or not all(isinstance(n, str) and n.strip() for n in names):
            raise ctx.error(f"expected a non-empty list of names, got {names!r}", m, f"{kp}.parameters", "parameters")
        if len(set(names)) != len(names):
            raise ctx.error("parameter names must be distinct", m, f"{kp}.parameters", "parameters")
        if fixed is not None and tuple(names) != fixed:
            raise ctx.error(f"expected {list(fixed)}, got {list(names)}", m, f"{kp}.parameters", "parameters")
        if allowed_names is not None:
            bad = [n for n in names if n not in allowed_names]
            if bad:
                raise ctx.error(f"{bad} are not parameters of this camera ({', '.join(allowed_names)})", m,
                                f"{kp}.parameters", "parameters")
        names_t = tuple(str(n) for n in names)
    else:
        names_t = fixed  # type: ignore[assignment]
    p = len(names_t)
    sigma = ctx.numbers(m, "sigma", f"{kp}.sigma", (p,))
    if np.any(sigma < 0):
        raise ctx.error("standard deviations must be >= 0", m, f"{kp}.sigma", "sigma")
    corr = ctx.numbers(m, "correlation", f"{kp}.correlation", (p, p)) if "correlation" in m else np.eye(p)
    values = ctx.numbers(m, "values", f"{kp}.values", (p,)) if "values" in m else None
    try:
        return CovarianceBlock(names_t, sigma, corr, values)
    except SkyrigError as exc:
        field = f"{kp}.correlation" if "correlation" in str(exc) else kp
        raise ctx.error(str(exc), m, field, "correlation" if "correlation" in str(exc) else None) from None


def _read_provenance(ctx: _Ctx, value: Any, parent: _Map, kp: str) -> Provenance:
    m = ctx.mapping(value, parent, kp, "provenance", _PROV_KEYS, {"recipe"})
    text = {}
    for k in ("recipe", "flight", "date", "software", "notes"):
        if k in m:
            v = m[k]
            if k == "date" and not isinstance(v, str) and v is not None:
                v = str(v)  # YAML reads 2011-05-12 as a date
            if v is not None and not isinstance(v, str):
                raise ctx.error(f"expected text, got {v!r}", m, f"{kp}.{k}", k)
            text[k] = v or ""
    stats: dict[str, float] = {}
    if m.get("statistics") is not None:
        st = m["statistics"]
        if not isinstance(st, _Map):
            raise ctx.error("expected a mapping name: number", m, f"{kp}.statistics", "statistics")
        for k in st:
            v = st[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ctx.error(f"expected a finite number, got {v!r}", st, f"{kp}.statistics.{k}", k)
            stats[k] = v
    if not text.get("recipe", "").strip():
        raise ctx.error("expected non-empty text", m, f"{kp}.recipe", "recipe")
    return Provenance(statistics=stats, **text)


def _read_head_calibration(ctx: _Ctx, value: Any, parent: _Map, kp: str, camera: FrameCamera) -> HeadCalibration:
    m = ctx.mapping(value, parent, kp, "calibration", _HEAD_CAL_KEYS, set())
    kw: dict[str, Any] = {}
    if m.get("lever_arm_m") is not None:
        kw["lever_arm_m"] = _read_block(ctx, m["lever_arm_m"], m, f"{kp}.lever_arm_m", "lever_arm_m",
                                        LEVER_ARM_PARAMETERS)
    if m.get("boresight_opk_deg") is not None:
        kw["boresight_opk_deg"] = _read_block(ctx, m["boresight_opk_deg"], m, f"{kp}.boresight_opk_deg",
                                              "boresight_opk_deg", BORESIGHT_PARAMETERS)
    if m.get("interior") is not None:
        kw["interior"] = _read_block(ctx, m["interior"], m, f"{kp}.interior", "interior",
                                     allowed_names=camera.intrinsic_names)
    if m.get("actuator") is not None:
        kw["actuator"] = _read_block(ctx, m["actuator"], m, f"{kp}.actuator", "actuator", need_values=True)
    if m.get("provenance") is not None:
        kw["provenance"] = _read_provenance(ctx, m["provenance"], m, f"{kp}.provenance")
    return HeadCalibration(**kw)


def _read_camera(ctx: _Ctx, value: Any, parent: _Map, kp: str) -> FrameCamera:
    m = ctx.mapping(value, parent, kp, "camera", _CAMERA_KEYS,
                    {"name", "width_px", "height_px", "pixel_size_um", "focal_mm"})
    distortion: Any = NoDistortion()
    d = m.get("distortion")
    if d is not None:
        if not isinstance(d, _Map):
            raise ctx.error("expected a mapping or null", m, f"{kp}.distortion", "distortion")
        fn = _distortion_from_dict()
        if fn is None:
            raise ctx.error("this skyrig cannot read distortion models (no distortion_from_dict)", m,
                            f"{kp}.distortion", "distortion")
        try:
            distortion = fn(_unplain(d))
        except (KeyError, TypeError, ValueError) as exc:
            sub = getattr(exc, "field", None)
            msg = exc.reason if isinstance(exc, InputFormatError) else str(exc)
            line = d.key_lines.get(sub, d.line) if sub else d.line
            field = f"{kp}.distortion.{sub}" if sub else f"{kp}.distortion"
            raise InputFormatError(f"bad distortion: {msg}", ctx.path, line, field) from None
    if isinstance(m["focal_mm"], list):  # [fx, fy] (mm): fx != fy is the Brown affinity b1 (skyrig.camera.aspect)
        fxy = ctx.numbers(m, "focal_mm", f"{kp}.focal_mm", (2,))
        if not np.all(fxy > 0):
            raise ctx.error(f"must be positive, got {fxy.tolist()}", m, f"{kp}.focal_mm", "focal_mm")
        try:
            focal, distortion = with_fx_fy(float(fxy[0]), float(fxy[1]), distortion)
        except ValueError as exc:
            raise ctx.error(str(exc), m, f"{kp}.focal_mm", "focal_mm") from None
    else:
        focal = ctx.number(m, "focal_mm", f"{kp}.focal_mm", positive=True)
    try:
        return FrameCamera(
            ctx.text(m, "name", f"{kp}.name"),
            ctx.integer(m, "width_px", f"{kp}.width_px"),
            ctx.integer(m, "height_px", f"{kp}.height_px"),
            ctx.number(m, "pixel_size_um", f"{kp}.pixel_size_um", positive=True) / 1000.0,
            focal,
            ctx.number(m, "ppx_mm", f"{kp}.ppx_mm") if "ppx_mm" in m else 0.0,
            ctx.number(m, "ppy_mm", f"{kp}.ppy_mm") if "ppy_mm" in m else 0.0,
            distortion,
        )
    except InputFormatError:
        raise
    except (ValueError, TypeError) as exc:
        raise InputFormatError(str(exc), ctx.path, m.line, kp) from None


def _read_curve(ctx: _Ctx, value: Any, parent: _Map, kp: str) -> BoresightCurve:
    required = {"beta_deg", "droll_deg", "dpitch_deg", "dyaw_deg"}
    m = ctx.mapping(value, parent, kp, "boresight_curve", _CURVE_KEYS, required)
    beta = ctx.numbers(m, "beta_deg", f"{kp}.beta_deg")
    if beta.ndim != 1 or beta.size == 0:
        raise ctx.error("expected a non-empty list of numbers", m, f"{kp}.beta_deg", "beta_deg")
    k = beta.size
    corr = np.stack([ctx.numbers(m, a, f"{kp}.{a}", (k,)) for a in ("droll_deg", "dpitch_deg", "dyaw_deg")], axis=1)
    std = None
    if m.get("std_deg") is not None:
        s = ctx.mapping(m["std_deg"], m, f"{kp}.std_deg", "std_deg", _STD_KEYS, _STD_KEYS)
        std = np.stack([ctx.numbers(s, a, f"{kp}.std_deg.{a}", (k,), allow_null=True)
                        for a in ("droll_deg", "dpitch_deg", "dyaw_deg")], axis=1)
    count = None
    if m.get("count") is not None:
        c = ctx.numbers(m, "count", f"{kp}.count", (k,))
        if np.any(c < 1) or np.any(c != np.round(c)):
            raise ctx.error("expected positive integers", m, f"{kp}.count", "count")
        count = c.astype(np.int64)
    interp = m.get("interpolation", "cubic")
    if interp not in ("cubic", "linear"):
        raise ctx.error(f"expected 'cubic' or 'linear', got {interp!r}", m, f"{kp}.interpolation", "interpolation")
    try:
        return BoresightCurve(beta / _DEG, corr / _DEG, None if std is None else std / _DEG, count, interp)
    except SkyrigError as exc:
        raise InputFormatError(str(exc), ctx.path, m.line, kp) from None


def _read_head(ctx: _Ctx, value: Any, parent: _Seq, index: int) -> tuple[Head, HeadCalibration | None]:
    head = _read_head_only(ctx, value, parent, index)
    m = value
    cal = None
    if m.get("calibration") is not None:
        cal = _read_head_calibration(ctx, m["calibration"], m, f"heads[{index}].calibration", head.camera)
        if cal.actuator is not None and not head.is_actuated:
            raise ctx.error("an actuator block for a head without an actuator", m["calibration"],
                            f"heads[{index}].calibration.actuator", "actuator")
    return head, cal


def _read_head_only(ctx: _Ctx, value: Any, parent: _Seq, index: int) -> Head:
    kp = f"heads[{index}]"
    if not isinstance(value, _Map):
        raise InputFormatError(f"expected a mapping, got {type(value).__name__}", ctx.path, parent.line, kp)
    m = ctx.mapping(value, None, kp, None, _HEAD_KEYS, {"name", "camera"})
    name = ctx.text(m, "name", f"{kp}.name")
    camera = _read_camera(ctx, m["camera"], m, f"{kp}.camera")
    lever = ctx.numbers(m, "lever_arm_m", f"{kp}.lever_arm_m", (3,)) if "lever_arm_m" in m else np.zeros(3)
    if "lever_arm_m" in m:
        from skyrig.io.plausibility import check_lever_arm

        check_lever_arm(lever, ctx.path, m.key_lines.get("lever_arm_m", m.line), f"{kp}.lever_arm_m")
    if "mounting_rpy_deg" in m and "mounting_matrix" in m:
        raise ctx.error("give either mounting_rpy_deg or mounting_matrix, not both", m, f"{kp}.mounting_matrix",
                        "mounting_matrix")
    if "mounting_matrix" in m:
        mounting = ctx.numbers(m, "mounting_matrix", f"{kp}.mounting_matrix", (3, 3))
    else:
        rpy = np.zeros(3)
        if "mounting_rpy_deg" in m:
            rpy = ctx.numbers(m, "mounting_rpy_deg", f"{kp}.mounting_rpy_deg", (3,))
        mounting = mounting_from_rpy(*rpy, unit="deg")
    opk = np.zeros(3)
    if "boresight_opk_deg" in m:
        opk = ctx.numbers(m, "boresight_opk_deg", f"{kp}.boresight_opk_deg", (3,))
    boresight = boresight_from_opk(*opk, unit="deg")
    try:
        if m.get("actuator") is None:
            return Head(name, camera, lever, mounting, boresight)
        akp = f"{kp}.actuator"
        a = ctx.mapping(m["actuator"], m, akp, "actuator", _ACTUATOR_KEYS, {"type", "gamma_deg"})
        if a["type"] != "tumbling":
            raise ctx.error(f"unknown actuator type {a['type']!r}; supported: tumbling", a, f"{akp}.type", "type")
        gamma = ctx.number(a, "gamma_deg", f"{akp}.gamma_deg") / _DEG
        law = a.get("law", "paper")
        if law not in ("paper", "cardan"):
            raise ctx.error(f"expected 'paper' or 'cardan', got {law!r}", a, f"{akp}.law", "law")
        curve = None
        if a.get("boresight_curve") is not None:
            curve = _read_curve(ctx, a["boresight_curve"], a, f"{akp}.boresight_curve")
        return ActuatedHead(name, camera, lever, mounting, boresight, gamma, curve, law)
    except InputFormatError:
        raise
    except SkyrigError as exc:  # e.g. a mounting_matrix that is not a rotation
        raise InputFormatError(str(exc), ctx.path, m.line, kp) from None


def read_rig(path: str | os.PathLike[str]) -> Rig:
    """Read a rig file (``format: skyrig-rig``, ``version: 1``), calibrated or not.

    The ``calibration`` sections of a calibrated rig file are checked like the rest and left out of the
    returned rig (its values already hold the calibrated figures); :func:`read_calibrated_rig` returns them.

    Raises
    ------
    InputFormatError
        For anything the format does not allow, naming the file, line and key path.
    """
    return read_calibrated_rig(path)[0]


def read_calibrated_rig(path: str | os.PathLike[str]) -> tuple[Rig, RigCalibration | None]:
    """Read a rig file and its calibration: ``(rig, calibration)``, ``calibration`` None when the file has no
    ``calibration`` section at all.

    Raises
    ------
    InputFormatError
        For anything the format does not allow, naming the file, line and key path.
    """
    p = os.fspath(path)
    ctx = _Ctx(p)
    text = read_text(p)
    doc = load_yaml_lines(text, p)
    if not isinstance(doc, _Map):
        raise InputFormatError("a rig file is a YAML mapping", p, 1)
    for key in ("format", "version"):
        if key not in doc:
            raise InputFormatError(f"missing key {key!r} (is this a skyrig rig file?)", p, doc.line, key)
    if doc["format"] != FORMAT:
        raise ctx.error(f"expected {FORMAT!r}, got {doc['format']!r}", doc, "format", "format")
    v = doc["version"]
    if isinstance(v, bool) or not isinstance(v, int):
        raise ctx.error(f"expected an integer, got {v!r}", doc, "version", "version")
    if v != VERSION:
        raise ctx.error(f"unsupported version {v} (this skyrig reads version {VERSION})", doc, "version", "version")
    ctx.mapping(doc, None, "", None, _TOP_KEYS, {"format", "version", "name"} | ({"heads"} if "scanners" not in doc
                                                                                else set()))
    if "scanners" in doc:  # laser scanner records (skyrig.io.scanner_record): checked here, read there
        from skyrig.io.scanner_record import parse_scanners

        parse_scanners(doc["scanners"], doc, p, _Map, _Seq)
        if "heads" not in doc:
            raise InputFormatError("this rig file holds laser scanners only (no camera 'heads'); read it with "
                                   "skyrig.io.scanner_record.read_rig_scanners", p, doc.line, "heads")
    name = ctx.text(doc, "name", "name")
    description = doc.get("description") or ""
    if not isinstance(description, str):
        raise ctx.error("expected text", doc, "description", "description")
    antenna = ctx.numbers(doc, "antenna_lever_arm_m", "antenna_lever_arm_m", (3,)) if "antenna_lever_arm_m" in doc \
        else np.zeros(3)
    if "antenna_lever_arm_m" in doc:
        from skyrig.io.plausibility import check_lever_arm

        check_lever_arm(antenna, ctx.path, doc.key_lines.get("antenna_lever_arm_m", doc.line), "antenna_lever_arm_m")
    heads_v = doc["heads"]
    if not isinstance(heads_v, _Seq) or not heads_v:
        raise ctx.error("expected a non-empty list of heads", doc, "heads", "heads")
    read = [_read_head(ctx, h, heads_v, i) for i, h in enumerate(heads_v)]
    heads = [h for h, _ in read]
    seen: dict[str, int] = {}
    for i, h in enumerate(heads):
        if h.name in seen:
            raise InputFormatError(f"duplicate head name {h.name!r} (also heads[{seen[h.name]}])", p,
                                   heads_v[i].line, f"heads[{i}].name")
        seen[h.name] = i
    rig = Rig(name, heads, antenna, description)
    head_cal = {h.name: c for h, c in read if c is not None}
    calibration = None
    if doc.get("calibration") is not None or head_cal:
        kw: dict[str, Any] = {}
        if doc.get("calibration") is not None:
            c = ctx.mapping(doc["calibration"], doc, "calibration", "calibration", _TOP_CAL_KEYS, set())
            if c.get("antenna_lever_arm_m") is not None:
                kw["antenna_lever_arm_m"] = _read_block(ctx, c["antenna_lever_arm_m"], c,
                                                        "calibration.antenna_lever_arm_m", "antenna_lever_arm_m",
                                                        LEVER_ARM_PARAMETERS)
            if c.get("provenance") is not None:
                kw["provenance"] = _read_provenance(ctx, c["provenance"], c, "calibration.provenance")
        calibration = RigCalibration(head_cal, **kw)
    return rig, calibration


# ---------------------------------------------------------------------- writing
class _Dumper(yaml.SafeDumper):
    pass


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    def scalar(x: Any) -> bool:
        return not isinstance(x, (dict, list))

    # lists of numbers and lists of lists of numbers (matrices) go in flow style: [1.0, 2.0, 3.0]
    flow = all(scalar(x) or (isinstance(x, list) and all(scalar(y) for y in x)) for x in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def _deg(values: Any) -> Any:
    """Radians -> degrees for writing, rounded to 1e-12 deg (about 2e-14 rad) so that 30 deg does
    not come out as 29.999999999999996, and without negative zeros."""
    return _plain(np.round(np.asarray(values, dtype=np.float64) * _DEG, 12) + 0.0)


def _camera_dict(cam: FrameCamera) -> dict[str, Any]:
    out: dict[str, Any] = {
        "name": cam.name,
        "width_px": int(cam.width),
        "height_px": int(cam.height),
        "pixel_size_um": float(cam.pixel_size_mm) * 1000.0,
        "focal_mm": float(cam.focal_mm),
        "ppx_mm": float(cam.ppx_mm),
        "ppy_mm": float(cam.ppy_mm),
    }
    d = cam.distortion
    fxy = fx_fy_px(cam)  # a camera entered with fx != fy is written the same way
    if fxy is not None:
        out["focal_mm"] = [float(fxy[0]) * float(cam.pixel_size_mm), float(fxy[1]) * float(cam.pixel_size_mm)]
        out["distortion"] = None
    elif d is None or isinstance(d, NoDistortion):
        out["distortion"] = None
    elif hasattr(d, "to_dict"):
        registry = _distortion_registry()
        if registry is not None and str(getattr(d, "name", "")).lower() not in registry:
            raise SkyrigError(
                f"camera {cam.name!r}: cannot write distortion model {type(d).__name__} "
                f"({getattr(d, 'name', '?')!r} is not a registered model, so it could not be read back)"
            )
        out["distortion"] = _plain(d.to_dict())
    else:
        raise SkyrigError(f"camera {cam.name!r}: cannot write distortion model {type(d).__name__} (no to_dict)")
    return out


def _curve_dict(c: BoresightCurve) -> dict[str, Any]:
    out: dict[str, Any] = {"interpolation": c.interpolation, "beta_deg": _deg(c.beta_rad)}
    for i, a in enumerate(("droll_deg", "dpitch_deg", "dyaw_deg")):
        out[a] = _deg(c.corrections_rad[:, i])
    if c.std_rad is not None:
        std = np.asarray(_deg(c.std_rad), dtype=np.float64)
        out["std_deg"] = {a: [None if not np.isfinite(x) else float(x) for x in std[:, i]]
                          for i, a in enumerate(("droll_deg", "dpitch_deg", "dyaw_deg"))}
    if c.count is not None:
        out["count"] = [int(x) for x in c.count]
    return out


def _head_dict(h: Head) -> dict[str, Any]:
    out: dict[str, Any] = {"name": h.name, "camera": _camera_dict(h.camera), "lever_arm_m": _plain(h.lever_arm_m)}
    r, p, y = h.mounting_rpy("rad")
    if abs(np.cos(p)) < _GIMBAL_LOCK_COS:
        out["mounting_matrix"] = _plain(h.mounting)
    else:
        out["mounting_rpy_deg"] = _deg([r, p, y])
    out["boresight_opk_deg"] = _deg(h.boresight_opk("rad"))
    if isinstance(h, ActuatedHead):
        act: dict[str, Any] = {"type": "tumbling", "gamma_deg": _deg(h.gamma_rad), "law": h.law}
        if h.curve is not None:
            act["boresight_curve"] = _curve_dict(h.curve)
        out["actuator"] = act
    return out


def _block_dict(b: CovarianceBlock, with_names: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if with_names:
        out["parameters"] = list(b.parameters)
    if b.values is not None:
        out["values"] = _plain(b.values)
    out["sigma"] = _plain(b.sigma)
    out["correlation"] = _plain(np.round(b.correlation, 12) + 0.0)
    return out


def _provenance_dict(p: Provenance) -> dict[str, Any]:
    out: dict[str, Any] = {"recipe": p.recipe}
    for k in ("flight", "date", "software", "notes"):
        if getattr(p, k):
            out[k] = getattr(p, k)
    if p.statistics:
        out["statistics"] = _plain(dict(p.statistics))
    return out


def _head_calibration_dict(c: HeadCalibration) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if c.provenance is not None:
        out["provenance"] = _provenance_dict(c.provenance)
    for key, b in c.groups.items():
        out[key] = _block_dict(b, key in ("interior", "actuator"))
    return out


def rig_to_dict(rig: Rig, calibration: RigCalibration | None = None) -> dict[str, Any]:
    """The YAML document of a rig (and its calibration) as plain Python (what :func:`write_rig` writes)."""
    heads = [_head_dict(h) for h in rig]
    out: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "name": rig.name,
        "description": rig.description,
        "antenna_lever_arm_m": _plain(rig.antenna_lever_arm_m),
    }
    if calibration is not None:
        unknown = [n for n in calibration.heads if n not in rig]
        if unknown:
            raise SkyrigError(f"calibration names heads {unknown} that rig {rig.name!r} does not have")
        top: dict[str, Any] = {}
        if calibration.provenance is not None:
            top["provenance"] = _provenance_dict(calibration.provenance)
        if calibration.antenna_lever_arm_m is not None:
            top["antenna_lever_arm_m"] = _block_dict(calibration.antenna_lever_arm_m, False)
        if top:
            out["calibration"] = top
        for h, d in zip(rig, heads):
            c = calibration.heads.get(h.name)
            if c is None:
                continue
            if c.interior is not None:
                bad = [n for n in c.interior.parameters if n not in h.camera.intrinsic_names]
                if bad:
                    raise SkyrigError(f"head {h.name!r}: interior block names {bad}, not intrinsics of its camera")
            if c.actuator is not None and not h.is_actuated:
                raise SkyrigError(f"head {h.name!r}: an actuator block for a head without an actuator")
            d["calibration"] = _head_calibration_dict(c)
    out["heads"] = heads
    return out


def write_rig(rig: Rig, path: str | os.PathLike[str], calibration: RigCalibration | None = None) -> None:
    """Write ``rig`` (and its ``calibration``) as a version-1 rig file (temporary file, then ``os.replace``)."""
    text = yaml.dump(rig_to_dict(rig, calibration), Dumper=_Dumper, sort_keys=False, allow_unicode=True, width=120)
    with atomic_write(path) as fh:
        fh.write("# skyrig rig file; format described in docs/formats/rig_file.md\n")
        fh.write(text)
    logger.debug("wrote rig %s with %d heads to %s", rig.name, len(rig), os.fspath(path))
