"""Thesis §6.2–6.4 evaluated: metric response (``cases``, ``study``, ``study_report``), edge operators
(``edge_study``), batched-metric speed (``benchmark``)."""
