"""Registry of the similarity metrics of thesis §6.2 and a by-name dispatcher (numpy references).

Scores, not costs: larger is more similar and an image against itself scores 1; an optimizer
minimises ``1 - score`` (or a weighted sum of such terms). :data:`METRICS` lists each metric's
family, range and whether :class:`core.similarity.BatchedMetric` computes it on the device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

from .gradient import (
    gradient_correlation,
    gradient_difference,
    gradient_information,
    gradient_orientation,
)
from .information import mutual_information, regional_mutual_information
from .intensity import lad, ncc, pattern_intensity, sid

__all__ = ["METRICS", "MetricInfo", "similarity"]


@dataclass(frozen=True)
class MetricInfo:
    """Description of one metric.

    Attributes
    ----------
    name : str
        Short key (``"ncc"``).
    title : str
        Full name.
    family : {"intensity", "information", "gradient"}
    score_range : (float, float)
        Range of the score (``-inf`` where unbounded).
    batched : bool
        Whether :class:`~core.similarity.BatchedMetric` implements it.
    function : callable
        ``function(drr, fluoro, **options) -> float``, the numpy reference.
    """

    name: str
    title: str
    family: str
    score_range: tuple[float, float]
    batched: bool
    function: Callable[..., float]


_INF = float("inf")
METRICS: dict[str, MetricInfo] = {
    m.name: m
    for m in (
        MetricInfo("sid", "squared intensity differences", "intensity", (-1.0, 1.0), True, sid),
        MetricInfo("lad", "log absolute differences", "intensity", (-_INF, 1.0), False, lad),
        MetricInfo("ncc", "normalised cross-correlation", "intensity", (-1.0, 1.0), True, ncc),
        MetricInfo("mi", "mutual information", "information", (0.0, 1.0), True, mutual_information),
        MetricInfo("nmi", "normalised mutual information", "information", (0.0, 1.0), True,
                   partial(mutual_information, normalized=True)),
        MetricInfo("rmi", "regional mutual information", "information", (0.0, 1.0), False,
                   regional_mutual_information),
        MetricInfo("pi", "pattern intensity", "information", (-_INF, 1.0), False, pattern_intensity),
        MetricInfo("gd", "gradient difference", "gradient", (-1.0, 1.0), True, gradient_difference),
        MetricInfo("gc", "gradient correlation", "gradient", (-1.0, 1.0), True, gradient_correlation),
        MetricInfo("gi", "gradient information", "gradient", (-1.0, 1.0), True, gradient_information),
        MetricInfo("go", "gradient orientation", "gradient", (-0.73, 1.0), True, gradient_orientation),
    )
}


def similarity(kind: str, drr, fluoro, **options) -> float:
    """Score ``drr`` against ``fluoro`` with the metric ``kind`` (a key of :data:`METRICS`).

    ``options`` are the domain options of :mod:`core.similarity.domain` (``threshold``,
    ``dilate``, ``fluoro_mask``, ``fluoro_sigma``) and the metric's own keywords.
    """
    if kind not in METRICS:
        raise ValueError(f"kind: expected one of {tuple(METRICS)}, got {kind!r}")
    return METRICS[kind].function(drr, fluoro, **options)
