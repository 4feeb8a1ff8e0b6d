"""Evaluation of the library: studies, acceptance runs and benchmarks, one sub-package per topic.

Nothing here is part of what a user calls; the library packages (``core.geometry`` …
``core.tracking``) never import it (an import-linter contract in ``pyproject.toml``). Studies
and benchmarks may read the ground truth of :mod:`core.synthetic`. Each runs as
``python -m core.studies.<topic>.<module>`` and prints JSON (``--help`` lists its options);
``talus bench <name>`` runs the benchmarks. Their results and figures are under
``resources/benchmarks`` and ``resources/figures``.

* :mod:`core.studies.render` — DRR speed (``benchmark``; ``talus bench drr``).
* :mod:`core.studies.io` — reading speed of sequences and volumes (``benchmark``).
* :mod:`core.studies.imaging` — thesis Chapter 3: the distortion study (``acceptance``) and
  image-correction speed (``benchmark``).
* :mod:`core.studies.markers` — thesis Chapter 4: localizer study (``study``, ``motion_study``,
  ``plots``) and localisation speed (``benchmark``).
* :mod:`core.studies.calibration` — thesis Chapter 5: DLT / bundle / sensitivity study
  (``study``), labelling on rendered frames (``labelling_study``), figures (``plots``), speed
  (``benchmark``).
* :mod:`core.studies.similarity` — thesis §6.2–6.4: metric response (``cases``, ``study``,
  ``study_report``), edge operators (``edge_study``), batched-metric speed (``benchmark``).
* :mod:`core.studies.tracking` — thesis Chapter 6: tracking acceptance on a synthetic walking
  trial (``acceptance``), the wrist sample check (``wrist_check``), speed (``benchmark``).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["sample_data_dir"]


def sample_data_dir() -> Path:
    """The real-data folder the studies read: ``$TALUS_SAMPLE_DATA``, else ``../shared/data``
    next to the repository (as the tests' ``sample_data`` fixture)."""
    env = os.environ.get("TALUS_SAMPLE_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "data"
