"""Layer 2: seeded procedural worlds, ray-cast rendering, sensor errors and the papers' scenarios.

* :mod:`skyrig.simulate.world`: :class:`Scene` (terrain, town, textures, targets), :func:`make_scene`.
* :mod:`skyrig.simulate.render`: :func:`render_image`, :func:`cast_rays`, :func:`ray_hits_at_pixels`.
* :mod:`skyrig.simulate.errors`: :class:`SensorErrors` and the error generators.
* :mod:`skyrig.simulate.scenarios`: :func:`scenario_spec`, :func:`build_survey` (in memory; files are
  written by :mod:`skyrig.pipeline.simulate`).
* :mod:`skyrig.simulate.lidar`: the ``uav-bridge-lidar`` scenario (paper 002): :func:`make_bridge`,
  :class:`LidarErrors`, :func:`lidar_scenario_spec`, :func:`build_lidar_survey`.
"""
