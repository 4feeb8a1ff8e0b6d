"""The read of a C3D file's bones that :func:`core.io.c3d.read_c3d` runs in a child process (ezc3d
crashes the process on some damaged files).

The child runs this file by its path (``runpy.run_path``), not through the :mod:`core.io`
package: it needs numpy and ezc3d only, so a read starts in about a fifth of the CPU time that
importing the package takes. Argument 1: a scratch folder (``out.npz`` is written there), 2: the
C3D file.
"""

import sys

import numpy as np


def read_arrays(path: str) -> dict:
    """The fields of :class:`core.io.c3d.C3DBones` of the file ``path``, as arrays."""
    try:
        import ezc3d
    except ImportError:  # pragma: no cover - depends on the installation
        raise ImportError("C3D files need ezc3d: pip install 'talus-biplane[interop]'") from None
    c = ezc3d.c3d(str(path))
    params = c["parameters"]
    rate = float(params["POINT"]["RATE"]["value"][0])
    units = str(params["POINT"].get("UNITS", {}).get("value", ["mm"])[0] or "mm")
    plabels = tuple(params["POINT"]["LABELS"]["value"])
    pts = np.asarray(c["data"]["points"], dtype=float)
    points = pts[:3].transpose(2, 1, 0) if pts.size else np.zeros((0, len(plabels), 3))
    rot = np.asarray(c["data"].get("rotations", np.zeros((4, 4, 0, 0))), dtype=float)
    labels = tuple(params.get("ROTATION", {}).get("LABELS", {}).get("value", ()))
    if rot.ndim != 4 or rot.shape[:2] != (4, 4):
        raise ValueError(f"rotation data of shape {rot.shape}, expected 4 x 4 x bones x frames")
    if len(labels) != rot.shape[2]:
        labels = tuple(f"rotation{k + 1}" for k in range(rot.shape[2]))
    poses = rot.transpose(3, 2, 0, 1)
    fields = {"bones": labels, "poses": poses, "rate": rate, "point_labels": plabels, "points": points,
              "units": units}
    return {k: np.asarray(v) for k, v in fields.items()}


if __name__ == "__main__":
    np.savez(sys.argv[1] + "/out.npz", **read_arrays(sys.argv[2]))
