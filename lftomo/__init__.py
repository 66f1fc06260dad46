"""lftomo: plenoptic (light-field) camera simulation and flame temperature tomography.

Public API (re-exported names only; see the README for a walk-through).
"""

from .version import __version__

from .errors import LftomoError

from .forward.camera import Camera, MainLens, MicrolensArray, Sensor, thick_lens_focal_length, spherical_aberration
from .forward.pose import Pose
from .forward.scene import PlanarEmitter, Scene, checkerboard, uniform
from .forward.render import render
from .forward.media_render import render_forward
from .forward.scattering import slab_collimated, hg_phase
from .lightfield import LightField, calibrate_centers, geometric_centers, alpha_of_depth, depth_of_alpha
from .radiation import planck, planck_inverse, dplanck_dT, gray_intensity, gray_inverse, blackbody_intensity
from .forward.grid import Grid
from .forward.medium import Medium, SootRule, load_field
from .forward import phantoms, reference_cases
from .forward.weights import WeightMatrix, RaySegments, RefocusWeights, weights, ray_segments, weights_refocus
from .inverse.measurement import SensorModel, add_noise, saturated_mask, Measurement
from .inverse.problem import LinearProblem
from .inverse.fitproblem import Problem
from .inverse.reconstruct import Reconstruction, reconstruct
from .inverse.solvers import solve_temperature, solve_linear_baseline
from .inverse.regularizers import Prior, GradientPrior, LaplacianPrior, CurvaturePrior, TotalVariationPrior
from .inverse.lambdarules import (LambdaRule, Discrepancy, DiscrepancyBracket, GCV, LCurve, LCurveDecades, Fixed,
                                  Evidence)
from .inverse.unknowns import Unknowns, Temperature, TemperatureAbsorption
from .inverse.solverchoice import Solver, LevenbergMarquardt, GaussNewton, DenseLM, AutoSolver
from .inverse.posterior import Posterior, build_log_posterior, sample_posterior, laplace_approximation
from .inverse.ensemble import EnsembleChain
from .inverse.fieldposterior import FieldPosterior, LaplaceCovariance, laplace_posterior
from .inverse.design import (Design, design, compare_designs, design_table, rig_around, standard_configurations,
                             SimulatedCamera, simulate_camera)
from .inverse.basis import DCTBasis, BSplineBasis, ParametricFlame
from .inverse.subvoxel import interpolate_field, interpolation_matrix
from .inverse.symmetry import RingGrid, ring_grid
from .inverse.parameterize import Parameterization, Voxels, Splines, SubVoxel
from .rawio import RawFrame, read_raw, write_raw, subtract_dark, CameraDescription, load_camera_description
from .calibration import (MicrolensGrid, calibrate_grid, decode_operator, decode_views, refocus_views,
                          RadiometricCalibration, radiometric_calibration, save_calibration, load_calibration)
from .rawdata import lightfield_from_raw, check_grid_matches_camera
from .series import FrameResult, SeriesResult, reconstruct_series
from .inverse.compare import (Comparison, compare_refocus_subaperture, effective_truth, monte_carlo_std,
                              with_monte_carlo_noise)

__all__ = [
    "__version__",
    "LftomoError",
    "Camera",
    "Pose",
    "MainLens",
    "MicrolensArray",
    "Sensor",
    "thick_lens_focal_length",
    "spherical_aberration",
    "PlanarEmitter",
    "Scene",
    "checkerboard",
    "uniform",
    "render",
    "render_forward",
    "slab_collimated",
    "hg_phase",
    "LightField",
    "calibrate_centers",
    "geometric_centers",
    "alpha_of_depth",
    "depth_of_alpha",
    "planck",
    "planck_inverse",
    "dplanck_dT",
    "gray_intensity",
    "gray_inverse",
    "blackbody_intensity",
    "Grid",
    "Medium",
    "SootRule",
    "load_field",
    "phantoms",
    "reference_cases",
    "WeightMatrix",
    "RaySegments",
    "RefocusWeights",
    "weights",
    "ray_segments",
    "weights_refocus",
    "SensorModel",
    "add_noise",
    "saturated_mask",
    "Measurement",
    "LinearProblem",
    "Problem",
    "Prior",
    "GradientPrior",
    "LaplacianPrior",
    "CurvaturePrior",
    "TotalVariationPrior",
    "LambdaRule",
    "Discrepancy",
    "DiscrepancyBracket",
    "GCV",
    "LCurve",
    "LCurveDecades",
    "Unknowns",
    "Temperature",
    "TemperatureAbsorption",
    "Fixed",
    "Solver",
    "LevenbergMarquardt",
    "GaussNewton",
    "DenseLM",
    "AutoSolver",
    "Reconstruction",
    "reconstruct",
    "solve_temperature",
    "solve_linear_baseline",
    "Posterior",
    "sample_posterior",
    "build_log_posterior",
    "EnsembleChain",
    "laplace_approximation",
    "FieldPosterior",
    "laplace_posterior",
    "LaplaceCovariance",
    "Evidence",
    "Design",
    "design",
    "compare_designs",
    "design_table",
    "rig_around",
    "standard_configurations",
    "SimulatedCamera",
    "simulate_camera",
    "DCTBasis",
    "BSplineBasis",
    "ParametricFlame",
    "RingGrid",
    "ring_grid",
    "Parameterization",
    "Voxels",
    "Splines",
    "SubVoxel",
    "interpolation_matrix",
    "interpolate_field",
    "Comparison",
    "compare_refocus_subaperture",
    "effective_truth",
    "monte_carlo_std",
    "with_monte_carlo_noise",
    "RawFrame",
    "read_raw",
    "write_raw",
    "subtract_dark",
    "CameraDescription",
    "load_camera_description",
    "MicrolensGrid",
    "calibrate_grid",
    "decode_operator",
    "decode_views",
    "refocus_views",
    "RadiometricCalibration",
    "radiometric_calibration",
    "save_calibration",
    "load_calibration",
    "lightfield_from_raw",
    "check_grid_matches_camera",
    "reconstruct_series",
    "SeriesResult",
    "FrameResult",
]
