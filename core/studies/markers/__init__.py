"""Thesis Chapter 4 evaluated: localizer study (``study``, ``motion_study``, ``plots``), speed
(``benchmark``)."""
