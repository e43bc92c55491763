"""Every error class skyrig defines lives in :mod:`skyrig.errors` (DESIGN.md convention 8), derives from
:class:`~skyrig.errors.SkyrigError`, and stays importable from the module that raised it before."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import skyrig
from skyrig import errors

# (old module, name): the classes that lived there before issue 30
OLD_HOMES = [("skyrig.adjust.factors.base", "BlockError"), ("skyrig.adjust.block", "BlockError"),
             ("skyrig.adjust.solver", "SingularError"), ("skyrig.adjust.adjust", "DatumDefectError"),
             ("skyrig.adjust", "DatumDefectError"), ("skyrig.adjust.linalg", "NotPositiveDefinite"),
             ("skyrig.rig.presets", "UnknownPresetError"), ("skyrig.rig.rig", "HeadNotFoundError"),
             ("skyrig.trajectory.events", "EventOutOfSpanError"), ("skyrig.georef.transfer", "TransferError"),
             ("skyrig.orient.gnss_block", "UavAdjustError"), ("skyrig.orient.incremental", "OrientError"),
             ("skyrig.calibrate.camera", "CalibrationError"), ("skyrig.calibrate.gnss_imu", "CalibrationFailed"),
             ("skyrig.calibrate.calqc", "CalqcFailed"), ("skyrig.dense.ortho", "EmptyMosaicError"),
             ("skyrig.io.trajectory_csv", "ImplausibleAngleError"), ("skyrig.io.table_meta", "SideCarMismatchWarning"),
             ("skyrig.pipeline.executor", "TaskError"), ("skyrig.pipeline.run", "StageError"),
             ("skyrig.pipeline.facades", "NoBuildingsError"), ("skyrig.web.tiles", "TileNotFound")]


def _modules() -> list[str]:
    return [m.name for m in pkgutil.walk_packages(skyrig.__path__, "skyrig.")]


def test_every_error_class_is_defined_in_errors() -> None:
    elsewhere = []
    for name in _modules():
        mod = importlib.import_module(name)
        for cname, cls in vars(mod).items():
            if (inspect.isclass(cls) and issubclass(cls, BaseException | Warning) and cls.__module__ == name
                    and name != "skyrig.errors" and not cname.startswith("_")):
                elsewhere.append(f"{name}.{cname}")
    assert not elsewhere, elsewhere


def test_errors_derive_from_the_root() -> None:
    for cname, cls in vars(errors).items():
        if (inspect.isclass(cls) and issubclass(cls, Exception) and not issubclass(cls, Warning)
                and cls.__module__ == "skyrig.errors"):
            assert issubclass(cls, errors.SkyrigError), cname
    # the option errors are ValueErrors: callers that catch ValueError keep working
    assert issubclass(errors.ConfigError, ValueError) and issubclass(errors.OptionError, errors.ConfigError)


@pytest.mark.parametrize("module,name", OLD_HOMES)
def test_old_names_still_importable(module: str, name: str) -> None:
    assert getattr(importlib.import_module(module), name) is getattr(errors, name)


def test_a_bad_option_is_a_named_error() -> None:
    from skyrig.adjust import AdjustConfig
    from skyrig.adjust.config import Unknowns
    from skyrig.geodesy.frame import WorldFrame
    from skyrig.match.features import FeatureConfig

    with pytest.raises(errors.ConfigError, match="points must be 'free' or 'fixed'"):
        AdjustConfig(unknowns=Unknowns(points="loose"))  # type: ignore[arg-type]
    with pytest.raises(errors.ConfigError, match="max_size"):
        FeatureConfig(max_size=8)
    with pytest.raises(errors.CRSError, match="local <lat_deg>"):
        WorldFrame.from_fields("local 45 7")
