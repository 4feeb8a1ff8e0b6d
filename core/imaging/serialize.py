"""Arrays in plain-JSON parameter dicts (flatfields, PSFs) for the study store.

By default an array becomes ``{"__ndarray__": <base64 of its little-endian bytes>, "dtype": ...,
"shape": [...]}``, so a whole pipeline round-trips through :func:`json.dumps`. A store that keeps
arrays in their own files passes its own ``array_encoder`` (array → JSON-able reference) and
``array_decoder`` (reference → array) to the ``to_dict`` / ``from_dict`` methods instead.
"""

from __future__ import annotations

import base64

import numpy as np

__all__ = ["decode_array", "encode_array"]


def encode_array(a: np.ndarray) -> dict:
    """Inline, lossless JSON form of a numeric array."""
    arr = np.ascontiguousarray(a)
    if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise ValueError(f"a: expected a numeric array, got dtype {arr.dtype}")
    le = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    return {"__ndarray__": base64.b64encode(le.tobytes()).decode("ascii"), "dtype": le.dtype.str,
            "shape": list(arr.shape)}


def decode_array(d) -> np.ndarray:
    """Array from :func:`encode_array`'s dict (or a nested list, for hand-written files)."""
    if isinstance(d, dict) and "__ndarray__" in d:
        try:
            raw = base64.b64decode(d["__ndarray__"])
            return np.frombuffer(raw, dtype=np.dtype(d["dtype"])).reshape(d["shape"]).copy()
        except (ValueError, TypeError, KeyError) as exc:
            raise ValueError(f"array: cannot decode the encoded array ({exc})") from exc
    try:
        return np.asarray(d, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"array: expected an encoded array or nested numbers, "
                         f"got {type(d).__name__}") from exc
