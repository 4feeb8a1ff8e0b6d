"""The calibration wizard (File → Calibrate…): a calibration session, step by step, into a study."""

from .wizard import CalibrationWizard

__all__ = ["CalibrationWizard"]
