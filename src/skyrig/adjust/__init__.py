"""Layer 2: bundle block adjustment and integrated sensor orientation (papers 003 and 004)."""

from skyrig.adjust.block import AdjustConfig, BalCamera, Block, BlockError
from skyrig.adjust.config import ReliabilityOptions, SolverOptions, StatisticsOptions, Unknowns
from skyrig.adjust.adjust import AdjustmentResult, DatumDefectError, Rejection, adjust

__all__ = ["AdjustConfig", "BalCamera", "Block", "BlockError", "AdjustmentResult", "DatumDefectError", "Rejection",
           "adjust", "Unknowns", "SolverOptions", "ReliabilityOptions", "StatisticsOptions"]
