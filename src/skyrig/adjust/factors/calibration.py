"""Priors on the calibration unknowns, for the groups configured ``"weighted"`` (papers 000, 003, 004).

Interior orientation (per camera, the sigma of each intrinsic by name from ``intrinsic_sigma``), head
boresights, the GNSS lever arm, datum shift, per-strip shift and drift, and the actuator offset / scale
and Fourier correction curve of actuated heads, and the parameter groups factor modules declare
(``unknowns.groups`` / ``group_sigma``): each ``(current - start) / sigma`` on the group's
estimated columns, a factor ``prior:<group>`` (``prior:intrinsics:<camera>`` per camera).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from skyrig.adjust.factors import parameter_groups, register
from skyrig.adjust.factors.base import Factor, pad_actuator
from skyrig.adjust.factors.prior import PriorType, prior_factor
from skyrig.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.model import Model, State


class CalibrationPrior(PriorType):
    name = "calibration"
    order = 101.0

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        cfg, lay, s0, b = model.config, model.layout, model.initial, model.block
        out: list[Factor] = []
        if cfg.unknowns.intrinsics == "weighted":
            sig_of = dict(cfg.unknowns.intrinsic_sigma)
            for j, cam in enumerate(b.cameras):
                on = lay.intr[j] >= 0
                if not on.any():
                    continue
                names = [n for n, o in zip(cam.intrinsic_names, on) if o]
                missing = [n for n in names if n not in sig_of]
                if missing:
                    raise ConfigError(f"intrinsics are 'weighted' but intrinsic_sigma lacks {missing}")
                out.append(prior_factor(f"intrinsics:{cam.name}", (s.intr[j] - s0.intr[j])[on][None],
                                        lay.intr[j][on][None], np.array([sig_of[n] for n in names]), jac))
        for grp, cur, ini, cols, sig in (
            ("boresight", s.bore, s0.bore, lay.bore, cfg.unknowns.boresight_sigma_rad),
            ("lever_arm", s.lever, s0.lever, lay.lever, cfg.unknowns.lever_arm_sigma_m),
            ("datum_shift", s.shift, s0.shift, lay.shift, cfg.unknowns.datum_shift_sigma_m),
            ("strip_shift", s.sshift, s0.sshift, lay.sshift, cfg.unknowns.strip_shift_sigma_m),
            ("strip_drift", s.sdrift, s0.sdrift, lay.sdrift, cfg.unknowns.strip_drift_sigma_m_s),
        ):
            if getattr(cfg.unknowns, grp) == "weighted" and (cols >= 0).any():
                out.append(prior_factor(grp, (cur - ini).reshape(-1, 3), cols.reshape(-1, 3), np.array(sig), jac))
        if lay.act is not None and (lay.act >= 0).any():
            H, W = lay.act.shape
            d = pad_actuator(s.act, H, W) - pad_actuator(s0.act, H, W)
            on_a = (lay.act[:, :2] >= 0).all(axis=1)
            if cfg.unknowns.actuator == "weighted" and on_a.any():
                out.append(prior_factor("actuator", d[on_a, :2], lay.act[on_a, :2],
                                        np.array(cfg.unknowns.actuator_sigma, float), jac))
            on_a = (lay.act[:, 2:] >= 0).all(axis=1) & (W > 2)
            if cfg.unknowns.actuator_curve == "weighted" and on_a.any():
                out.append(prior_factor("actuator_curve", d[on_a, 2:], lay.act[on_a, 2:],
                                        np.array(cfg.unknowns.actuator_curve_sigma_rad), jac))
        for pg in parameter_groups():  # the parameter groups factor modules declare
            gcols = lay.groups.get(pg.name)
            if cfg.unknowns.group_mode(pg.name) == "weighted" and gcols is not None and (gcols >= 0).any():
                gsig = np.broadcast_to(np.asarray(cfg.unknowns.group_prior_sigma(pg.name), float), gcols.shape[1:])
                g_on = (gcols >= 0).all(axis=1)
                out.append(prior_factor(pg.name, (s.groups[pg.name] - s0.groups[pg.name])[g_on], gcols[g_on], gsig,
                                        jac))
        return out


CALIBRATION_PRIOR = register(CalibrationPrior())
