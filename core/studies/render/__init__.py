"""DRR rendering speed (``python -m core.studies.render.benchmark``, ``talus bench drr``)."""
