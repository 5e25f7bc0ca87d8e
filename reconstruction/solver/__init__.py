"""The MLE / MAP pose solver (paper Sec. 3.3): the stages of ``configs/reconstruction/*.yaml`` and the solve."""

from reconstruction.solver.compiled_solver import solve_poses
from reconstruction.solver.map_solver import MAPReconstruction, MLEMAPReconstruction, MLEReconstruction

__all__ = ["MAPReconstruction", "MLEMAPReconstruction", "MLEReconstruction", "solve_poses"]
