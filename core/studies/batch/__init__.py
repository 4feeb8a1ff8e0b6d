"""Throughput of ``talus batch`` (:mod:`core.tracking.batch`) against the number of workers
(``benchmark``)."""
