"""Fluoroscope image correction and image operators (thesis Ch. 3 and §6.4).

Import the sub-modules directly (e.g. ``core.imaging.flatfield``, ``core.imaging.edges``).
"""
