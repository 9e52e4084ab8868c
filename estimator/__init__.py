"""3D gaze estimators from view lines: geometry, triangulation, likelihood and voxel methods.

Pure numpy/scipy maths (Open3D holds the voxel densities); no file, device or network I/O.
Frames and units: see ``estimator.frames``.
"""

from .api import METHODS, PooledEstimate, batch_options, density_point_cloud, estimate, make_estimator, run_estimator
from .likelihood import (
    MLConfig,
    angular_log_likelihood,
    cramer_rao_bound,
    fisher_information,
    ml_point,
    perturb_directions,
)
from .lines import (
    BinocularSample,
    BinocularSamples,
    ViewLines,
    calibration_plane_points,
    view_lines_in_camera,
    view_lines_to_camera,
    view_lines_to_world,
)
from .paper_voxel import PaperVoxelConfig, PaperVoxelEstimator
from .result import NEAR_POINT_MM, Ellipsoid, GazeEstimate, Status, near_point_check
from .triangulation import PairStatus, closest_point_two_lines, lse_point, nearest_point_to_lines
from .voxel import VoxelConfig, VoxelEstimator

__all__ = [
    "METHODS", "NEAR_POINT_MM", "near_point_check",
    "BinocularSample", "BinocularSamples", "Ellipsoid", "GazeEstimate", "MLConfig",
    "PairStatus", "PaperVoxelConfig", "PooledEstimate", "PaperVoxelEstimator", "Status", "ViewLines", "VoxelConfig",
    "VoxelEstimator", "angular_log_likelihood", "batch_options", "calibration_plane_points", "closest_point_two_lines",
    "cramer_rao_bound",
    "density_point_cloud", "estimate", "fisher_information", "lse_point", "make_estimator",
    "ml_point", "nearest_point_to_lines", "perturb_directions", "run_estimator",
    "view_lines_in_camera", "view_lines_to_camera", "view_lines_to_world",
]
