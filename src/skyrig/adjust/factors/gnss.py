"""GNSS antenna positions of the stations (papers 003 and 004).

Data (:class:`GnssRows` in ``block.observations['gnss']``;
the Block's keywords): ``gnss_station (G,)``, ``gnss_xyz (G, 3)`` m, ``gnss_sigma (G, 3)`` m per axis and
optional ``gnss_cov_m2 (G, 3, 3)`` m².  Residual (computed minus observed)::

    C_station + R_station @ lever_arm + datum_shift + strip_shift[s] + strip_drift[s] * (t - t0[s]) - xyz

with the Jacobian with respect to the station pose (centre, rotation on the right), the lever arm, the
datum shift and the strip's shift and drift (each estimated or fixed by the configuration).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register
from skyrig.adjust.factors.base import (
    Factor,
    ObservationType,
    any_on,
    check_covariance,
    check_finite,
    check_index,
    check_positive,
    indexed_rows,
    whitening_matrices,
)
from skyrig.geometry.rotations import skew

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State


@dataclass
class GnssRows:
    """GNSS antenna positions of stations: the rows of the ``gnss`` type (``block.observations['gnss']``; the block's keywords
    ``gnss_*`` route here).

    Attributes
    ----------
    station
        ``(G,)`` station index.
    xyz
        ``(G, 3)`` positions, m.
    sigma
        ``(G, 3)`` sigma per axis, m.
    cov_m2
        optional ``(G, 3, 3)`` covariance, m².
    """

    station: NDArray[np.int64]
    xyz: NDArray[np.float64]
    sigma: NDArray[np.float64]
    cov_m2: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.station)


class Gnss(ObservationType):
    name = "gnss"
    words = "GNSS"
    components = ("X", "Y", "Z")
    units = "m"
    order = 20.0
    hints = (("lever_arm", "a wrong GNSS lever arm"), ("datum_shift", "a GNSS datum shift"),
             ("strip_shift", "per-strip GNSS shifts"))
    parameters = ("lever_arm", "datum_shift", "strip_shift", "strip_drift")
    datum_words = "GNSS positions"
    vce_split = ((0, 1), (2,))
    sigma_field = "sigma"
    cov_field = "cov_m2"
    rows = GnssRows
    keywords = (('gnss_station', 'station', None), ('gnss_xyz', 'xyz', None), ('gnss_sigma', 'sigma', 0.05), ('gnss_cov_m2', 'cov_m2', None))

    def data(self, block: "Block") -> GnssRows:
        return block.observations[self.name]

    def count(self, block: "Block") -> int:
        return len(self.data(block).station)

    def normalise(self, block: "Block") -> None:
        indexed_rows(self.data(block), "station", "xyz", (3,), "sigma", "cov_m2", "gnss_cov_m2")

    def validate(self, block: "Block") -> None:
        d = self.data(block)
        check_index("gnss_station", d.station, block.n_stations, "station")
        check_finite("gnss_xyz", d.xyz)
        check_finite("gnss_sigma", d.sigma)
        check_positive("gnss_sigma", d.sigma)
        check_covariance("gnss_cov_m2", d.cov_m2)

    def prepare(self, model: "Model") -> NDArray[np.float64] | None:
        b = model.block
        d = self.data(b)
        return None if d.cov_m2 is None else whitening_matrices(d.cov_m2)

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        b, lay = model.block, model.layout
        d = self.data(b)
        st = d.station
        R = s.R[st]
        strip = b.station_strip[st]
        has = strip >= 0
        sk = np.where(has, strip, 0)
        dt = np.where(has, b.station_time[st] - (b.strip_t0[sk] if b.n_strips else 0.0), 0.0)
        pred = s.C[st] + np.einsum("nij,j->ni", R, s.lever) + s.shift
        if b.n_strips:
            pred = pred + has[:, None] * (s.sshift[sk] + s.sdrift[sk] * dt[:, None])
        sig = d.sigma
        Wm = model.cache[self.name]
        if Wm is None:
            r = (pred - d.xyz) / sig
        else:
            r = np.einsum("nij,nj->ni", Wm, pred - d.xyz)
        f = Factor(self.name, r, sig, weight=model.weights[self.name], whiten=Wm)
        if not jac:
            return [f]
        n = len(st)
        isig = (1.0 / sig)[:, :, None]
        eye = np.broadcast_to(np.eye(3), (n, 3, 3))
        blocks = [np.concatenate([eye, -(R @ skew(s.lever))], axis=2), R, eye]
        cols = [lay.pose[st], np.broadcast_to(lay.lever, (n, 3)), np.broadcast_to(lay.shift, (n, 3))]
        if b.n_strips:
            neg = np.full(3, -1, np.int64)
            blocks += [eye, eye * dt[:, None, None]]
            cols += [np.where(has[:, None], lay.sshift[sk], neg), np.where(has[:, None], lay.sdrift[sk], neg)]
        f.jc = np.concatenate(blocks, axis=2) * isig if Wm is None else Wm @ np.concatenate(blocks, axis=2)
        f.cols = np.concatenate(cols, axis=1)
        return [f]

    def varying(self, model: "Model", factor: Factor) -> NDArray[np.bool_]:
        b, lay = model.block, model.layout
        d = self.data(b)
        st = d.station
        on = any_on(lay.pose)[st] | bool((lay.lever >= 0).any() or (lay.shift >= 0).any())
        if b.n_strips:
            strip = b.station_strip[st]
            on |= (strip >= 0) & (any_on(lay.sshift) | any_on(lay.sdrift))[np.where(strip >= 0, strip, 0)]
        return on

    def label(self, block: "Block", i: int) -> str:
        return f"GNSS position of station {block.station_name[self.data(block).station[i]]}"


GNSS = register(Gnss())
