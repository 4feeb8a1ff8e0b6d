"""Interaction latency benchmark (``talus bench interaction``): prints JSON, asserts nothing.

Times what happens while a user drags a bone: one pose edit -> preview DRR overlays of that
bone in both views -> coloured RGBA images (the pane's work after that is a pixmap upload).
Measured on the demo study (``talus demo`` geometry), preview and full resolution.
"""

from __future__ import annotations

import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from core.render import default_device

from .overlay import OverlayRenderer, colorize
from .posing import translate_in_view

__all__ = ["run_interaction_benchmark"]


def run_interaction_benchmark(*, folder: str | Path | None = None, pixels: int = 512,
                              device: str | None = None, repeats: int = 20) -> dict:
    """Time preview/full overlay updates for one dragged bone on a demo study."""
    from core.synthetic.demo import make_demo_study

    from .session import open_study

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(folder) if folder else Path(tmp) / "demo"
        if not (path / "study.json").is_file():
            make_demo_study(path, n_frames=1, pixels=pixels, seed=0, device=device)
        session = open_study(path, read_only=True)
        session.close()  # the model holds what the benchmark needs (rig, volumes, poses)
    m = session.model
    dev = device or default_device()
    renderer = OverlayRenderer(m.rig, [b.volume for b in m.layers], device=dev)
    bone = [b.name for b in m.layers].index("talus")
    layer = m.layers[bone]
    result = {"benchmark": "interaction", "device": dev, "image": list(m.rig[0].image_shape),
              "bone": layer.name, "volume_ijk": list(layer.volume.shape_ijk),
              "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count()}}
    for name, preview in (("preview", True), ("full", False)):
        T = m.pose(bone)
        renderer.render(T[None], bones=[bone], preview=preview)  # compile / warm up
        times = []
        for k in range(repeats):
            t0 = time.perf_counter()
            T = translate_in_view(m.rig[0], T, layer.centroid, 1.0, 0.5 * (-1) ** k)
            images = renderer.render(T[None], bones=[bone], preview=preview)
            for o in images:
                colorize(o.drr, layer.color, layer.opacity, "blend")
            times.append(time.perf_counter() - t0)
        ms = 1e3 * np.array(times)
        result[name] = {"ms_median": float(np.median(ms)), "ms_max": float(ms.max()),
                        "rays_per_view": [int(o.drr.size) for o in images],
                        "scale": images[0].scale if images else None, "repeats": repeats}
    result["preview_within_100ms"] = bool(result["preview"]["ms_median"] <= 100.0)
    return result


def main() -> None:  # pragma: no cover
    import argparse
    import json

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--pixels", type=int, default=512)
    ap.add_argument("--device")
    a = ap.parse_args()
    print(json.dumps(run_interaction_benchmark(pixels=a.pixels, device=a.device), indent=2))


if __name__ == "__main__":  # pragma: no cover
    main()
