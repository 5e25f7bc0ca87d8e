"""The MLE / MAP pose solver (paper Sec. 3.3): the stages of ``configs/reconstruction/*.yaml`` and the solve.

``map_solver`` (the stages), ``compiled_solver`` and ``pose_kernels`` (the problem and its compiled
Levenberg-Marquardt), ``pose_init`` (start poses), ``person_prior`` and ``prior_kernels`` (each person's noise scale
and bone prior), ``side_swaps`` and ``side_labels`` (left / right repair). Layer 3: may import ``data`` and the other
stages' lower helpers, never ``evaluation`` or the entry points.
"""

from reconstruction.solver.compiled_solver import solve_poses
from reconstruction.solver.map_solver import MAPReconstruction, MLEMAPReconstruction, MLEReconstruction

__all__ = ["MAPReconstruction", "MLEMAPReconstruction", "MLEReconstruction", "solve_poses"]
