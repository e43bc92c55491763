"""skyrig: aerial and UAV photogrammetry for multi-head camera rigs with GNSS/IMU.

Layers (imports point down only):

0. :mod:`skyrig.geometry`, :mod:`skyrig.geodesy`
1. :mod:`skyrig.camera`, :mod:`skyrig.rig`, :mod:`skyrig.trajectory`
2. :mod:`skyrig.georef` (and later adjust, calibrate, match, dense, lidar, simulate, plan)
3. :mod:`skyrig.io`, :mod:`skyrig.cli`, :mod:`skyrig.demo`
"""

__version__ = "0.1.0"
