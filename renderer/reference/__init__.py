"""The Monte Carlo ground truth (embree ray casting) and the error metrics measured against it."""

from .envsampling import EnvironmentSampler
from .metrics import NoiseFloor, mean_flip, noise_floor, relative_rmse, relative_squared_errors
from .montecarlo import ReferenceFrame, primary_rays, render_reference

__all__ = ["EnvironmentSampler", "NoiseFloor", "ReferenceFrame", "mean_flip", "noise_floor", "primary_rays",
           "relative_rmse", "relative_squared_errors", "render_reference"]
