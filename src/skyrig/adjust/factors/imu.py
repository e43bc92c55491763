"""IMU attitudes of the stations (integrated sensor orientation, paper 003).

Data (``Block`` fields): ``imu_station (M,)``, ``imu_rotation (M, 3, 3)`` observed ``world_from_station``,
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
    covariance_rows,
    rows_of,
    sigma_rows,
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
    sigma_field = "imu_sigma_rad"
    cov_field = "imu_cov_rad2"
    rows = ImuRows
    keywords = (('imu_station', 'station', None), ('imu_rotation', 'rotation', None), ('imu_sigma_rad', 'sigma_rad', 1e-4), ('imu_cov_rad2', 'cov_rad2', None))

    def count(self, block: "Block") -> int:
        return len(block.imu_station)

    def normalise(self, block: "Block") -> None:
        if block.imu_station is None:
            block.imu_station = np.zeros(0, np.int64)
            block.imu_rotation = np.zeros((0, 3, 3))
        m = len(np.asarray(block.imu_station).reshape(-1))
        block.imu_station = rows_of(block.imu_station, (), np.int64, m)
        block.imu_rotation = rows_of(block.imu_rotation, (3, 3), n=m)
        block.imu_sigma_rad = sigma_rows(block.imu_sigma_rad, m, 3)
        covariance_rows(block, "imu_cov_rad2", "imu_sigma_rad", m, 3)

    def validate(self, block: "Block") -> None:
        check_index("imu_station", block.imu_station, block.n_stations, "station")
        check_finite("imu_rotation", block.imu_rotation)
        check_finite("imu_sigma_rad", block.imu_sigma_rad)
        check_positive("imu_sigma_rad", block.imu_sigma_rad)
        check_covariance("imu_cov_rad2", block.imu_cov_rad2)

    def prepare(self, model: "Model") -> NDArray[np.float64] | None:
        b = model.block
        return None if b.imu_cov_rad2 is None else whitening_matrices(b.imu_cov_rad2)

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        b, lay = model.block, model.layout
        st = b.imu_station
        e = rotvec_from_matrix(np.swapaxes(b.imu_rotation, 1, 2) @ s.R[st])
        sig = b.imu_sigma_rad
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
        return any_on(model.layout.pose)[model.block.imu_station]

    def label(self, block: "Block", i: int) -> str:
        return f"IMU attitude of station {block.station_name[block.imu_station[i]]}"


IMU = register(Imu())
