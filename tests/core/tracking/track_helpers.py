"""A bone's poses in smooth, walking-like motion with registration noise, shared by the trajectory
check's tests (test_flags_post) and the silent-failure candidate checks' (test_silent_checks): the
trajectory-gaps study's track (:func:`core.studies.tracking.trajectory_gaps.walking_track`), about ``C``."""

from __future__ import annotations

from core.studies.tracking.trajectory_gaps import CENTER as C
from core.studies.tracking.trajectory_gaps import walking_track

__all__ = ["C", "walking_track"]
