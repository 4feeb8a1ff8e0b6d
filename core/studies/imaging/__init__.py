"""Thesis Chapter 3 evaluated: the distortion study (``acceptance``), image-correction speed
(``benchmark``)."""
