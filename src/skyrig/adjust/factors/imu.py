"""IMU attitudes of the stations (integrated sensor orientation, paper 003).

Data (:class:`ImuRows` in ``block.observations['imu']``;
the Block's keywords): ``imu_station (M,)``, ``imu_rotation (M, 3, 3)`` observed ``world_from_station``,
``imu_sigma_rad (M, 3)`` rad about the station axes and optional ``imu_cov_rad2 (M, 3, 3)`` rad².
Residual: the rotation vector ``e = log(R_imu^T R_station)`` (station axes), with the inverse right
Jacobian of SO(3) (to first order) on the station rotation.
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
from skyrig.geometry.rotations import rotvec_from_matrix, skew

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State


@dataclass
class ImuRows:
    """IMU attitudes of stations: the rows of the ``imu`` type (``block.observations['imu']``; the block's keywords
    ``imu_*`` route here).

    Attributes
    ----------
    station
        ``(M,)`` station index.
    rotation
        ``(M, 3, 3)`` observed ``world_from_station``.
    sigma_rad
        ``(M, 3)`` sigma about the station axes, rad.
    cov_rad2
        optional ``(M, 3, 3)`` covariance, rad².
    """

    station: NDArray[np.int64]
    rotation: NDArray[np.float64]
    sigma_rad: NDArray[np.float64]
    cov_rad2: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.station)


class Imu(ObservationType):
    name = "imu"
    words = "IMU"
    components = ("rx", "ry", "rz")
    units = "rad"
    order = 30.0
    hints = (("boresight", "an uncalibrated boresight misalignment"),)
    datum_words = "IMU attitudes"
    vce_split = ((0, 1, 2),)
    sigma_field = "sigma_rad"
    cov_field = "cov_rad2"
    rows = ImuRows
    keywords = (('imu_station', 'station', None), ('imu_rotation', 'rotation', None), ('imu_sigma_rad', 'sigma_rad', 1e-4), ('imu_cov_rad2', 'cov_rad2', None))

    def data(self, block: "Block") -> ImuRows:
        return block.observations[self.name]

    def count(self, block: "Block") -> int:
        return len(self.data(block).station)

    def normalise(self, block: "Block") -> None:
        indexed_rows(self.data(block), "station", "rotation", (3, 3), "sigma_rad", "cov_rad2", "imu_cov_rad2")

    def validate(self, block: "Block") -> None:
        d = self.data(block)
        check_index("imu_station", d.station, block.n_stations, "station")
        check_finite("imu_rotation", d.rotation)
        check_finite("imu_sigma_rad", d.sigma_rad)
        check_positive("imu_sigma_rad", d.sigma_rad)
        check_covariance("imu_cov_rad2", d.cov_rad2)

    def prepare(self, model: "Model") -> NDArray[np.float64] | None:
        b = model.block
        d = self.data(b)
        return None if d.cov_rad2 is None else whitening_matrices(d.cov_rad2)

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        b, lay = model.block, model.layout
        d = self.data(b)
        st = d.station
        e = rotvec_from_matrix(np.swapaxes(d.rotation, 1, 2) @ s.R[st])
        sig = d.sigma_rad
        Wm = model.cache[self.name]  # full 3x3 covariance about the station axes, or None
        r = e / sig if Wm is None else np.einsum("nij,nj->ni", Wm, e)
        f = Factor(self.name, r, sig, weight=model.weights[self.name], whiten=Wm)
        if not jac:
            return [f]
        n = len(st)
        jinv = np.eye(3)[None] + 0.5 * skew(e)  # inverse right Jacobian of SO(3) to first order
        j = np.zeros((n, 3, 6))
        j[:, :, 3:] = jinv
        f.jc = j / sig[:, :, None] if Wm is None else Wm @ j
        f.cols = lay.pose[st]
        return [f]

    def varying(self, model: "Model", factor: Factor) -> NDArray[np.bool_]:
        return any_on(model.layout.pose)[self.data(model.block).station]

    def label(self, block: "Block", i: int) -> str:
        return f"IMU attitude of station {block.station_name[self.data(block).station[i]]}"


IMU = register(Imu())
