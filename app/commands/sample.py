"""``talus sample …``: previews of real sample data."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, CliError, load, print_json, warp_device, write_atomically

HELP = "previews of real sample data"


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="sample", metavar="SAMPLE", required=True)
    wrist = sub.add_parser(
        "wrist",
        help="render the radius of the Autoscoper wrist sample over its radiographs",
        description="Load the Autoscoper wrist sample (MayaCam cameras, TIFF CT sub-volumes, "
        "radiographs), render the radius at a hand-found pose in both cameras and save a PNG "
        "(radiograph | DRR | overlay per camera).",
    )
    wrist.add_argument("--data", default=None, metavar="DIR",
                       help="the autoscoper_wrist folder (default: $TALUS_SAMPLE_DATA/autoscoper_wrist, "
                            "else shared/data/autoscoper_wrist beside the Talus source folder)")
    wrist.add_argument("--out", default="wrist_radius.png", metavar="PNG", help="output image")
    wrist.add_argument("--device", choices=["cpu", "cuda"], default=None,
                       help="Warp device (default: cuda when present)")
    wrist.set_defaults(run=run_wrist)


def default_wrist_folder() -> Path:
    """``$TALUS_SAMPLE_DATA/autoscoper_wrist``, else ``shared/data/autoscoper_wrist`` beside the
    folder Talus runs from (``../shared/data`` of the source tree, wherever the command is run:
    the default was relative to the working folder)."""
    env = os.environ.get("TALUS_SAMPLE_DATA")
    base = Path(env).expanduser() if env else Path(__file__).resolve().parents[3] / "shared" / "data"
    return base / "autoscoper_wrist"


def run_wrist(args: argparse.Namespace) -> int:
    data = Path(args.data).expanduser() if args.data else default_wrist_folder()
    if not data.is_dir():
        raise CliError(
            f"--data: expected the autoscoper_wrist sample folder, '{data}' is not a directory"
        )
    warp_device(args.device)
    load_sample = load("core.samples:load_wrist_sample", needed_for="'talus sample wrist'")
    preview = load("core.samples:wrist_preview", needed_for="'talus sample wrist'")
    sample = load_sample(data)
    rgb, drrs = preview(sample, device=args.device)
    import cv2

    out = Path(args.out)
    ok, png = cv2.imencode(".png", rgb[..., ::-1])
    if not ok:
        raise CliError(f"--out: could not encode the preview as PNG for {out}")
    write_atomically(out, png.tobytes())
    print(f"{PROG} sample wrist: wrote {out}", file=sys.stderr)
    print_json({"png": str(out), "views": len(drrs), "drr_max": [float(d.max()) for d in drrs],
                "drr_shape": [list(d.shape) for d in drrs]})
    return EXIT_OK
