"""Layer 2: bundle block adjustment and integrated sensor orientation (papers 003 and 004).

The house
---------
* :mod:`~skyrig.adjust.block` - the data (:class:`Block`: stations, images, heads, points, observation rows,
  ``observations[name]`` rows of further types, ``parameters[name]`` values of module-declared unknowns);
* :mod:`~skyrig.adjust.config` - :class:`AdjustConfig` in four frozen parts, each read where it is used:
  ``unknowns`` (what is free / fixed / weighted, the datum), ``solver``, ``reliability`` (data snooping),
  ``statistics``;
* :mod:`~skyrig.adjust.factors` - one module per observation type (residual, Jacobian, sigma, labels) and the
  parameter groups a module declares for itself; how to add either is in that package's docstring;
* :mod:`~skyrig.adjust.model` - unknowns (``State``), their columns (``Layout``), the camera poses;
* :mod:`~skyrig.adjust.solver` (Levenberg-Marquardt, reference scipy path), :mod:`~skyrig.adjust.schur_engine`
  (the compiled Schur complement), :mod:`~skyrig.adjust.linalg` (sparse factorisations);
* :mod:`~skyrig.adjust.adjust` (the adjustment with data snooping), :mod:`~skyrig.adjust.stats`,
  :mod:`~skyrig.adjust.vce`, :mod:`~skyrig.adjust.report`.
"""

from skyrig.adjust.block import AdjustConfig, BalCamera, Block, BlockError
from skyrig.adjust.config import ReliabilityOptions, SolverOptions, StatisticsOptions, Unknowns
from skyrig.adjust.adjust import AdjustmentResult, DatumDefectError, Rejection, adjust

__all__ = ["AdjustConfig", "BalCamera", "Block", "BlockError", "AdjustmentResult", "DatumDefectError", "Rejection",
           "adjust", "Unknowns", "SolverOptions", "ReliabilityOptions", "StatisticsOptions"]
