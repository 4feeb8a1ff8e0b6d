"""Reading speed of sequences and volumes (``python -m core.studies.io.benchmark``, ``talus bench io``)."""
