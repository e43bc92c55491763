"""Rig presets with the published figures of the systems in ``shared/papers``.

Lever arms are *not* published for any of these systems; the presets put every projection centre
and the GNSS antenna at the body origin (zeros).  Replace them with surveyed values (and calibrated
interior orientations and boresights) for real work.  Image orientations on the mounts are not
published either; the choices made here are stated per preset.

=================  ==========================================================================
preset             figures and source
=================  ==========================================================================
``midas``          paper 004 (Sanborn / Track'Air MIDAS): 1 nadir + 4 obliques tilted 45 deg, 5
                   Canon EOS 1Ds Mark III, 5616 x 3744 px, 6.4 um; configuration "28/50": 28 mm
                   nadir, 50 mm obliques (``midas-50``: 50 mm nadir, the "50/50" configuration).
``dlr-3k``         paper 001 (DLR 3K): 3 Canon EOS 1Ds Mark II with 50 mm lenses, nadir + two
                   sideward obliques tilted about 35 deg.  The paper gives neither pixel pitch nor
                   sensor size; the Canon specification is a 36 x 24 mm full-frame sensor with
                   4992 x 3328 px, i.e. 7.2 um pixels.
``macs-tumblecam`` paper 000 Tab. 1: 2 cameras 3296 x 2472 px, 5.5 um, 35 mm; 1 nadir + 1 tumbling
                   oblique with gamma = 30 deg (no boresight curve: Fig. 8 is not tabulated).
``uav-single``     one DJI Phantom 3 camera (FC300S / FC300X): 4000 x 3000 px, 1/2.3" sensor
                   6.17 mm wide (1.5425 um pixels), 3.61 mm focal length (manufacturer figures).
=================  ==========================================================================
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import UnknownPresetError  # noqa: F401 - re-exported (defined in skyrig.errors)
from skyrig.geometry.rotations import rot_x, rot_z
from skyrig.rig.rig import NADIR_BODY_FROM_CAMERA, ActuatedHead, Head, Rig, oblique_mounting

_DEG = np.pi / 180.0


def _canon_1ds_mk3(name: str, focal_mm: float) -> FrameCamera:
    """Canon EOS 1Ds Mark III as quoted in paper 004: 5616 x 3744 px, 6.4 um."""
    return FrameCamera(name, 5616, 3744, 0.0064, float(focal_mm))


def midas(nadir_focal_mm: float = 28.0, oblique_focal_mm: float = 50.0) -> Rig:
    """MIDAS penta camera (paper 004): nadir + forward, backward, left, right obliques at 45 deg.

    Paper 004 flew the configurations "28 mm nadir / 50 mm obliques" (default) and "50 mm / 50 mm".
    Image orientation (assumed): nadir image x to the right, image top forward; obliques with the
    image x axis horizontal and the image top towards the far field (:func:`oblique_mounting`).
    """
    nadir = Head(
        "nadir", _canon_1ds_mk3(f"midas-nadir-{nadir_focal_mm:g}mm", nadir_focal_mm), mounting=oblique_mounting(0, 0)
    )
    heads = [nadir]
    for name, azimuth in (("forward", 0.0), ("right", 90.0), ("backward", 180.0), ("left", -90.0)):
        cam = _canon_1ds_mk3(f"midas-{name}-{oblique_focal_mm:g}mm", oblique_focal_mm)
        heads.append(Head(name, cam, mounting=oblique_mounting(azimuth, 45.0)))
    return Rig(
        "midas" if nadir_focal_mm == 28.0 else f"midas-{nadir_focal_mm:g}",
        heads,
        description=(
            f"MIDAS penta camera, {nadir_focal_mm:g} mm nadir / {oblique_focal_mm:g} mm obliques at 45 deg, "
            "Canon EOS 1Ds Mark III 5616 x 3744 px 6.4 um (paper 004); lever arms not published (zeros)"
        ),
    )


def dlr_3k(tilt_deg: float = 35.0) -> Rig:
    """DLR 3K camera (paper 001): nadir + left and right sideward obliques, 50 mm lenses.

    The 110 deg across-track field of view quoted in paper 001 needs the long image side across the
    track (2 x 35 deg + 2 x 19.8 deg), so every image has x to the right and its top forward; the
    obliques are the nadir camera rolled by ``tilt_deg`` about the flight axis.
    """
    base = rot_z(np.pi / 2) @ NADIR_BODY_FROM_CAMERA  # image x right, image top forward

    def cam(name: str) -> FrameCamera:
        return FrameCamera(f"3k-{name}-canon-1ds-mk2-50mm", 4992, 3328, 0.0072, 50.0)

    t = tilt_deg * _DEG
    heads = [
        Head("left", cam("left"), mounting=rot_x(t) @ base),  # +x rotation tilts the view to the left
        Head("nadir", cam("nadir"), mounting=base),
        Head("right", cam("right"), mounting=rot_x(-t) @ base),
    ]
    return Rig(
        "dlr-3k",
        heads,
        description=(
            f"DLR 3K: 3 x Canon EOS 1Ds Mark II (4992 x 3328 px, 7.2 um, 50 mm), nadir + 2 x {tilt_deg:g} deg "
            "sideward (paper 001); lever arms not published (zeros)"
        ),
    )


def macs_tumblecam(gamma_deg: float = 30.0) -> Rig:
    """MACS-TumbleCam (paper 000): a fixed nadir camera and a tumbling oblique camera (gamma = 30 deg).

    Both cameras: 3296 x 2472 px, 5.5 um, 35 mm (Tab. 1).  The sensor head frame is the body frame;
    the nadir camera has the standard nadir mount (image x forward), and so has the untilted
    tumbling camera.  No boresight correction curve (Fig. 8 is not tabulated in the paper).
    """
    def cam(name: str) -> FrameCamera:
        return FrameCamera(f"tumblecam-{name}-35mm", 3296, 2472, 0.0055, 35.0)

    nadir = Head("nadir", cam("nadir"))
    oblique = ActuatedHead("oblique", cam("oblique"), gamma_rad=gamma_deg * _DEG, law="paper")
    return Rig(
        "macs-tumblecam",
        [nadir, oblique],
        description=(
            f"MACS-TumbleCam: nadir + tumbling oblique (gamma {gamma_deg:g} deg), 3296 x 2472 px, 5.5 um, 35 mm "
            "(paper 000 Tab. 1); lever arms not published (zeros)"
        ),
    )


def uav_single() -> Rig:
    """A single nadir camera of a small UAV: DJI Phantom 3 (FC300S), 4000 x 3000 px, 1.5425 um, 3.61 mm.

    Nominal manufacturer figures, not a calibration.  The camera is on a stabilising gimbal in reality;
    here it is modelled as rigidly mounted looking down with image x to the right and top forward.
    """
    cam = FrameCamera("dji-fc300s", 4000, 3000, 6.17 / 4000.0, 3.61)
    return Rig(
        "uav-single",
        [Head("camera", cam, mounting=oblique_mounting(0, 0))],
        description="single UAV camera: DJI Phantom 3 FC300S nominal figures; lever arms zeros",
    )


#: Preset name -> factory.
PRESETS: dict[str, Callable[[], Rig]] = {
    "midas": midas,
    "midas-50": partial(midas, nadir_focal_mm=50.0, oblique_focal_mm=50.0),
    "dlr-3k": dlr_3k,
    "macs-tumblecam": macs_tumblecam,
    "uav-single": uav_single,
}


def preset(name: str) -> Rig:
    """The preset rig called ``name`` (case-insensitive, ``_`` and ``-`` alike); see :data:`PRESETS`."""
    key = str(name).strip().lower().replace("_", "-")
    if key not in PRESETS:
        raise UnknownPresetError(f"unknown rig preset {name!r}; presets: {', '.join(PRESETS)}")
    return PRESETS[key]()


__all__ = ["PRESETS", "UnknownPresetError", "dlr_3k", "macs_tumblecam", "midas", "preset", "uav_single"]
