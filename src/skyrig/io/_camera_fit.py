"""Writers of other programs' camera files: a camera whose distortion model the program lacks, fitted to one it has.

Shared by the exchange writers (COLMAP, OpenSfM, ...): :func:`fit_or_refuse` fits the target model over the
whole frame with :func:`skyrig.camera.convert.convert_camera` (principal distance, principal point and
coefficients) and refuses the result when its RMS over the frame exceeds the tolerance, so that no writer
silently writes a different camera.
"""

from __future__ import annotations

import logging
from typing import Any

from skyrig.camera.distortion import Distortion
from skyrig.camera.frame import FrameCamera
from skyrig.errors import OptionError

logger = logging.getLogger(__name__)

#: largest RMS (px) over the frame accepted for a camera fitted to another model by a writer
FIT_TOLERANCE_PX = 0.01


def fit_or_refuse(camera: FrameCamera, target: Distortion, tolerance_px: float = FIT_TOLERANCE_PX,
                  program: str = "the format", hold: tuple[str, ...] = ()) -> tuple[FrameCamera, Any]:
    """``(camera fitted to target's model, ConversionReport)``; :class:`OptionError` (option ``fit_tolerance_px``)
    when the fit's RMS over the frame is above ``tolerance_px``.  ``hold``: target parameters kept at the target's
    values (terms the program's model lacks)."""
    from skyrig.camera.convert import convert_camera

    out, rep = convert_camera(camera, target, hold=hold)
    if not rep.rms_px <= tolerance_px:
        raise OptionError("fit_tolerance_px", f"camera {camera.name!r} ({camera.distortion.name}): its {target.name} "
                          f"fit for {program} departs from it by {rep.rms_px:.4f} px RMS ({rep.max_px:.4f} px max) "
                          f"over the frame, more than {tolerance_px} px")
    logger.info("camera %s (%s) written to %s as %s: fit RMS %.2e px, max %.2e px", camera.name,
                camera.distortion.name, program, target.name, rep.rms_px, rep.max_px)
    return out, rep
