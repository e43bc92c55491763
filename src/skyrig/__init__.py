"""skyrig: aerial and UAV photogrammetry for multi-head camera rigs with GNSS/IMU.

Layers (imports point down only; within a row only to a package listed before it):

0. :mod:`skyrig.geometry`, :mod:`skyrig.geodesy`
1. :mod:`skyrig.camera`, :mod:`skyrig.rig`, :mod:`skyrig.trajectory`
2. a: :mod:`skyrig.georef`; b: ``match``, ``adjust``, ``orient``, ``lidar``, ``plan``;
   c: ``dense``, ``simulate``, ``calibrate``
3. :mod:`skyrig.io`, ``report``, ``pipeline``, ``cli``

The repository's ``.importlinter`` states them as import-linter contracts (checked by ``tests/test_layers.py``).
"""

__version__ = "0.1.0"
