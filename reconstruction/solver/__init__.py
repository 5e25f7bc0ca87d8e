"""The MLE / MAP pose solver (paper section 3.3): the public entry is re-exported here.

Entry: :class:`MAPReconstruction`, :class:`MLEReconstruction`, :class:`MLEMAPReconstruction` (the
``configs/reconstruction/*.yaml`` stages) and :func:`solve_poses` (in ``map_solver``). Internals:
``map_estimation`` (the pose problem: residuals, priors), ``lm_solver`` (Levenberg-Marquardt),
``block_solver`` (block-sparse normal equations), ``compiled_solver`` and ``pose_kernels`` (the numba
path), ``pose_init`` (the starting poses), ``person_prior`` (bone-length prior), ``side_swaps``
(left/right swap repair). Layer 3: may import ``data`` (layers 1-2) and the other stages' lower helpers,
never ``evaluation`` or the entry points.
"""

from reconstruction.solver.map_solver import MAPReconstruction, MLEMAPReconstruction, MLEReconstruction, solve_poses

__all__ = ["MAPReconstruction", "MLEMAPReconstruction", "MLEReconstruction", "solve_poses"]
