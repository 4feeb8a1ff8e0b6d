"""Shared helpers for the I/O tests: writing DICOM series with SimpleITK."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def write_dicom_series(
    folder: Path,
    hu: np.ndarray,
    *,
    spacing=(0.7, 0.8, 2.5),
    origin=(10.0, -20.0, 30.0),
    direction=None,
    slope: float = 1.0,
    intercept: float = -1024.0,
    uid: str = "1.2.826.0.1.3680043.2.1125.77.1",
    names=None,
    description: str = "CT foot",
) -> list[Path]:
    """Write ``hu[k, j, i]`` as one DICOM file per slice k (stored = (hu - intercept) / slope).

    ``direction`` columns are the i (row direction), j (column direction) and k axes; k must be
    their cross product (a right-handed series). ``names[k]`` is the file name of slice k.
    """
    import SimpleITK as sitk

    folder.mkdir(parents=True, exist_ok=True)
    D = np.eye(3) if direction is None else np.asarray(direction, float)
    sx, sy, sz = spacing
    writer = sitk.ImageFileWriter()
    writer.KeepOriginalImageUIDOn()
    writer.SetImageIO("GDCMImageIO")

    def ds(v):
        return "\\".join(f"{x:.8f}" for x in v)

    out = []
    for k in range(hu.shape[0]):
        img = sitk.GetImageFromArray(hu[k].astype(np.int16))
        img.SetSpacing((sx, sy))
        pos = np.asarray(origin, float) + k * sz * D[:, 2]
        tags = {
            "0008|0060": "CT",
            "0008|0016": "1.2.840.10008.5.1.4.1.1.2",
            "0008|0018": f"{uid}.{k + 1}",
            "0008|103e": description,
            "0020|000d": "1.2.826.0.1.3680043.2.1125.77",
            "0020|000e": uid,
            "0020|0013": str(k + 1),
            "0020|0032": ds(pos),
            "0020|0037": ds(np.concatenate([D[:, 0], D[:, 1]])),
            "0028|1052": f"{intercept:g}",
            "0028|1053": f"{slope:g}",
        }
        for key, value in tags.items():
            img.SetMetaData(key, value)
        p = folder / (names[k] if names else f"slice_{k:03d}.dcm")
        writer.SetFileName(str(p))
        writer.Execute(img)
        out.append(p)
    return out


@pytest.fixture
def dicom_writer():
    """The :func:`write_dicom_series` helper."""
    return write_dicom_series
