"""Thesis Chapter 6 evaluated: tracking acceptance (``acceptance``), wrist sample check (``wrist_check``),
speed (``benchmark``)."""
