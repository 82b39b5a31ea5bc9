"""rfir calibrate: camera poses from photos with pycolmap, in metres, in the scene's frame.

`run(CalibrateInputs(images, out, poses=...), CalibrateOptions.from_config(...), progress)` runs
structure from motion (or imports a COLMAP model), aligns it to metric references (known camera
centres, known 3D points or ArUco markers), and writes a `calib` artifact plus a top-view PNG.
"""
from .align import Alignment
from .pipeline import CalibrateInputs, CalibrateOptions, CalibResult, run
from .sfm import SfmOptions

__all__ = ["Alignment", "CalibResult", "CalibrateInputs", "CalibrateOptions", "SfmOptions", "run"]
