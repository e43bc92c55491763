"""Layer 2c: the papers' calibration recipes on top of :mod:`skyrig.adjust`.

* :mod:`skyrig.calibrate.rig_calibration`: what a calibration adds to a rig (sigma and correlations of lever
  arms, boresights, interior orientations and actuator curve; provenance), written into the rig file.
* :mod:`skyrig.calibrate.camera`: the ``camera`` recipe (paper 004 section 2.5): test-field (cage)
  calibration with fixed object points and fixed or free stations, self-calibration of a chosen model.

The recipes (which import the adjustment) load on first use, so reading a calibrated rig file stays light.
"""

from __future__ import annotations

from typing import Any

from skyrig.calibrate.rig_calibration import (
    BORESIGHT_PARAMETERS,
    LEVER_ARM_PARAMETERS,
    CovarianceBlock,
    HeadCalibration,
    Provenance,
    RigCalibration,
)

__all__ = ["BORESIGHT_PARAMETERS", "LEVER_ARM_PARAMETERS", "CovarianceBlock", "HeadCalibration", "Provenance",
           "RigCalibration", "CameraCalibration", "calibrate_camera"]

_LAZY = {"CameraCalibration": "skyrig.calibrate.camera", "calibrate_camera": "skyrig.calibrate.camera"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'skyrig.calibrate' has no attribute {name!r}")
