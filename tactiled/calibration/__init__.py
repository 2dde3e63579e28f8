"""Calibration: lookup-table linearisation, drift/hysteresis zeroing, contact detection.

Pure numpy; the calibration and press files are :mod:`tactiled.io`'s.  See
``docs/howto/calibration.md`` for the lab procedure, ``docs/reference/file-formats.md`` for the
files and ``docs/concepts/calibration.md`` for the estimation and the time constants.
"""

from tactiled.calibration.builder import CalibrationReport, build_table, format_report
from tactiled.calibration.detection import ContactDetector, detection_threshold, filter_matrices
from tactiled.calibration.isotonic import isotonic_increasing
from tactiled.calibration.lut import LookupTable
from tactiled.calibration.presses import (
    PressSet,
    SyntheticResponse,
    synthesize_presses,
)
from tactiled.calibration.stage import CalibrationStage
from tactiled.calibration.zeroing import Zeroer

__all__ = [
    "CalibrationReport",
    "CalibrationStage",
    "ContactDetector",
    "LookupTable",
    "PressSet",
    "SyntheticResponse",
    "Zeroer",
    "build_table",
    "detection_threshold",
    "filter_matrices",
    "format_report",
    "isotonic_increasing",
    "synthesize_presses",
]
