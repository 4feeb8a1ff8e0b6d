"""Thesis Chapter 5 evaluated: calibration study (``study``), labelling (``labelling_study``), figures
(``plots``), speed (``benchmark``)."""
