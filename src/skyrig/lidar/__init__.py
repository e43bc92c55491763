"""Laser scanning: scanner models, per-pulse georeferencing, registration, cloud comparison, boresight.

* :mod:`skyrig.lidar.scanner` -- polar measurements <-> scanner frame (paper 002 eq. 1), 2D and airborne scanners.
* :mod:`skyrig.lidar.georef` -- scanner -> body -> NED -> ECEF -> any frame, per pulse (eqs. 2-4), and back.
* :mod:`skyrig.lidar.register` -- coarse alignment from homologous points, ICP (Open3D, or scipy).
* :mod:`skyrig.lidar.compare` -- cloud-to-cloud distances, M3C2 (CloudCompare / PDAL), statistics.
* :mod:`skyrig.lidar.boresight` -- boresight / yaw-correction estimation against a reference cloud.
* :mod:`skyrig.lidar.strips` -- strip adjustment on planar patches: scanner boresight, lever arm, range offset and
  scale, per-strip trajectory offsets and drifts (import it from its module).
"""

from skyrig.lidar.compare import (
    C2CResult,
    DistanceStatistics,
    M3C2Params,
    M3C2Result,
    cloud_to_cloud,
    distance_statistics,
    histogram,
    m3c2,
)
from skyrig.lidar.georef import (
    GeoreferencedPoints,
    PulseGeoreferencer,
    ScannerMount,
    georeference_scan,
    invert_points,
    rotation_from_angles,
    with_barometric_height,
    with_yaw_correction,
)
from skyrig.lidar.scanner import HOKUYO_UTM_30LX_EW, AirborneLineScanner, RawScan, Scanner2D, polar_from_sensor, sensor_from_polar

__all__ = [
    "AirborneLineScanner",
    "C2CResult",
    "DistanceStatistics",
    "GeoreferencedPoints",
    "HOKUYO_UTM_30LX_EW",
    "M3C2Params",
    "M3C2Result",
    "PulseGeoreferencer",
    "RawScan",
    "Scanner2D",
    "ScannerMount",
    "cloud_to_cloud",
    "distance_statistics",
    "georeference_scan",
    "histogram",
    "invert_points",
    "m3c2",
    "polar_from_sensor",
    "rotation_from_angles",
    "sensor_from_polar",
    "with_barometric_height",
    "with_yaw_correction",
]
