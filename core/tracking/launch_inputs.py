"""The recorded-launch shortcut shared by the Gauss–Newton engine's frame preparation
(:mod:`core.tracking.engine_buffers`) and the likelihood stage's launches
(:mod:`core.tracking.likelihood_launches`): a launch recorded with the same objects is launched again
without rebuilding its key. A module of its own so that neither imports the other."""

from __future__ import annotations

__all__ = ["same_inputs"]


def same_inputs(kept: list, inputs: list) -> bool:
    """Whether ``inputs`` are the objects of ``kept`` (numbers: of equal value, as the key compares them)."""
    if len(kept) != len(inputs):
        return False
    for a, b in zip(kept, inputs, strict=True):
        if a is not b and not (isinstance(a, (int, float)) and isinstance(b, (int, float)) and a == b):
            return False
    return True
