"""Image similarity metrics for DRR-to-fluoroscope registration (thesis §6.2–6.3).

* Numpy references (ground truth, any image size): :func:`similarity` by name, or the functions
  :func:`sid`, :func:`lad`, :func:`ncc`, :func:`mutual_information`,
  :func:`regional_mutual_information`, :func:`pattern_intensity`, :func:`gradient_difference`,
  :func:`gradient_correlation`, :func:`gradient_information`, :func:`gradient_orientation`.
  :data:`METRICS` lists names, families and ranges. Conventions (Ω, polarity, bad input):
  :mod:`core.similarity.domain`.
* Batched on the device (Warp, CPU or CUDA): :class:`BatchedMetric` scores a whole
  :class:`core.render.DRRBatch` against fixed fluoroscope ROIs, one number per pose
  (``python -m core.studies.similarity.benchmark`` times it).
* Likelihood-like cost (:mod:`core.similarity.likelihood`, numpy): weighted least squares of a
  bone's DRR against the line-integral image, weights the expected counts, gain and background
  fitted linearly per pose, optional high-pass and PSF; used by
  :class:`core.tracking.likelihood_cost.LikelihoodCost` for an opt-in final refinement.
* Studies: :mod:`core.studies.similarity.cases` (synthetic and wrist registration cases),
  :mod:`core.studies.similarity.study` (response to noise, translation and rotation; its docstring holds
  the results and the recommended default cost: ``1 - GC`` on the fluoroscope ROI smoothed with
  σ = 1.5 px), :mod:`core.studies.similarity.study_report` (JSON + figures),
  :mod:`core.studies.similarity.edge_study` (edge operators on line pairs and a foot frame).
"""

from .batched import BATCHED_KINDS, BatchedMetric, BatchedScores
from .domain import domain, line_integral_image, sample_roi
from .gradient import (
    gradient_correlation,
    gradient_difference,
    gradient_information,
    gradient_orientation,
)
from .information import joint_histogram, mutual_information, regional_mutual_information
from .intensity import lad, ncc, pattern_intensity, sid
from .metrics import METRICS, MetricInfo, similarity

__all__ = [
    "BATCHED_KINDS",
    "METRICS",
    "BatchedMetric",
    "BatchedScores",
    "MetricInfo",
    "domain",
    "gradient_correlation",
    "gradient_difference",
    "gradient_information",
    "gradient_orientation",
    "joint_histogram",
    "lad",
    "line_integral_image",
    "mutual_information",
    "ncc",
    "pattern_intensity",
    "regional_mutual_information",
    "sample_roi",
    "sid",
    "similarity",
]
