"""Single images and a folder of camera images, for a quick look without a study.

:func:`read_image` reads the first frame of an image file (``.npy``, ``.tif``/``.tiff``,
``.png``). :func:`camera_images` finds the images of each camera in a folder that is *not* a
study (no ``study.json``): the frames a ``summary.json`` lists under ``files.frames`` (as
``talus demo`` writes), or else files and folders named like ``cam01``, ``camera2`` or
``view0``, skipping images whose names mention a DRR, mask, label, ground truth or flatfield.
A study folder is opened with :class:`core.study.Study` instead.

Images are arrays indexed ``[row, col]``; errors are :class:`~core.io.errors.FileError`
naming the file or folder and what was expected.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np

from .errors import FileError, reading

__all__ = ["IMAGE_SUFFIXES", "camera_images", "read_image"]

IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".npy")
_VIEW_KEY = re.compile(r"(?:cam(?:era)?|view)[_\-]?0*(\d+)", re.IGNORECASE)
_NOT_FLUORO = re.compile(r"drr|mask|label|truth|flatfield", re.IGNORECASE)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """The first frame of an image file as an array ``[row, col]`` (or ``[row, col, channel]``).

    Raises
    ------
    FileError
        For a missing, unreadable or unsupported file (the message names it).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise FileError(f"{path}: expected an image file ({', '.join(IMAGE_SUFFIXES)})",
                        path=path, expected="an image file")
    with reading(path, "an image"):
        if suffix == ".npy":
            image = np.load(path, allow_pickle=False)
        elif suffix in (".tif", ".tiff"):
            import tifffile

            image = tifffile.imread(path, key=0)
        else:
            import cv2

            if not path.is_file():
                raise FileNotFoundError(2, "No such file", str(path))
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise ValueError(f"{path}: not a readable PNG image")
        image = np.asarray(image)
        while image.ndim > 2 and image.shape[-1] not in (3, 4):
            image = image[0]  # a stack: [frame, row, col]
        if image.ndim < 2 or image.size == 0:
            raise ValueError(f"{path}: expected a 2-D image, got shape {image.shape}")
    return image


def _listed_frames(folder: Path) -> dict[str, list[Path]] | None:
    """Frames per camera listed by ``summary.json`` (``files.frames``), if there is one."""
    path = folder / "summary.json"
    if not path.is_file():
        return None
    with reading(path, "a JSON summary"):
        doc = json.loads(path.read_text(encoding="utf-8"))
    frames = doc.get("files", {}).get("frames") if isinstance(doc, dict) else None
    if not isinstance(frames, dict) or not all(isinstance(v, list) for v in frames.values()):
        raise FileError(f"{path}: expected 'files': {{'frames': {{camera: [paths]}}}}",
                        path=path, expected="a frame list per camera")
    return {str(cam): [folder / p for p in paths] for cam, paths in sorted(frames.items()) if paths}


def camera_images(folder: str | os.PathLike, *, n_views: int = 2) -> list[tuple[str, Path]]:
    """``[(label, path), ...]``: the first image of each camera in ``folder`` (at most ``n_views``).

    ``label`` is ``"<camera>: <path relative to folder>"``. Read the images with
    :func:`read_image`.

    Raises
    ------
    FileError
        ``folder`` is not a folder, or holds no camera images.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileError(f"{folder}: not a folder", path=folder, expected="a folder")
    listed = _listed_frames(folder)
    if listed is not None:
        if not listed:
            raise FileError(f"{folder / 'summary.json'}: no camera images (no frames written)",
                            path=folder / "summary.json", expected="frames")
        return [(f"{cam}: {paths[0].relative_to(folder).as_posix()}", paths[0])
                for cam, paths in list(listed.items())[:n_views]]
    groups: dict[int, list[Path]] = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder)
        if (path.suffix.lower() not in IMAGE_SUFFIXES or len(rel.parts) > 3
                or _NOT_FLUORO.search(str(rel)) or not path.is_file()):
            continue
        keys = _VIEW_KEY.findall(str(rel))
        if keys:
            groups.setdefault(int(keys[-1]), []).append(path)
    if not groups:
        raise FileError(
            f"{folder}: no camera images found (expected .tif/.png/.npy images in files or "
            "folders named like cam01, cam02)", path=folder, expected="camera images")
    return [(f"cam{key:02d}: {groups[key][0].relative_to(folder).as_posix()}", groups[key][0])
            for key in sorted(groups)[:n_views]]
