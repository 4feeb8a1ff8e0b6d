"""``talus bench …``: benchmarks that print JSON (machine, device, sizes, times).

:data:`BENCHMARKS` is the one table of what each benchmark runs, as ``"module:function"``
strings imported on use. ``drr`` and ``interaction`` take the options below; every other entry
is a ``main(argv)`` that parses its own options (``talus bench track --help``).
"""

from __future__ import annotations

import argparse
import inspect
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, load, print_json, stdout_to_stderr, warp_device
from .types import int_at_least

HELP = "benchmarks that print JSON (machine, sizes, times)"

# benchmark name -> "module:function" it runs
BENCHMARKS: dict[str, str] = {
    "drr": "core.studies.render.benchmark:run_drr_benchmark",
    "interaction": "app.benchmark:run_interaction_benchmark",
    "io": "core.studies.io.benchmark:main",
    "imaging": "core.studies.imaging.benchmark:main",
    "markers": "core.studies.markers.benchmark:main",
    "metrics": "core.studies.similarity.benchmark:main",
    "calibration": "core.studies.calibration.benchmark:main",
    "track": "core.studies.tracking.benchmark:main",
    "review": "app.benchmark_review:main",
}

_HELP = {
    "drr": "DRR rendering speed",
    "interaction": "overlay update latency while dragging a bone",
    "io": "frame access of cine and TIFF sequences",
    "imaging": "flatfield, undistortion, deconvolution, grid fits",
    "markers": "bead localisations per second",
    "metrics": "similarity metrics of DRR batches",
    "calibration": "bead detection, labelling, DLT and bundle adjustment",
    "track": "whole-trial tracking speed and where the time goes",
    "review": "GUI-thread cost of the review docks per tracked frame",
}


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    drr = sub.add_parser("drr", help=_HELP["drr"], description="Time DRR rendering on the given "
                         "devices and print JSON (machine, device, sizes, times).")
    drr.add_argument("--device", choices=["cpu", "cuda", "all"], default="all",
                     help="device(s) to time; 'all' = cpu plus cuda when present (default)")
    drr.add_argument("--out", metavar="FILE", help="also write the JSON to FILE")
    drr.add_argument("--quick", action="store_true", help="small sizes, few repeats")
    drr.set_defaults(run=run_drr)
    inter = sub.add_parser("interaction", help=_HELP["interaction"],
                           description="Time preview and full-resolution overlay updates of one "
                           "dragged bone on the demo study and print JSON.")
    inter.add_argument("--pixels", type=int_at_least(16), default=512, metavar="N")
    inter.add_argument("--device", choices=["cpu", "cuda"], default=None)
    inter.add_argument("--out", metavar="FILE", help="also write the JSON to FILE")
    inter.set_defaults(run=run_interaction)
    for name, target in BENCHMARKS.items():
        if name in ("drr", "interaction"):
            continue
        module = target.partition(":")[0]
        sp = sub.add_parser(name, help=_HELP.get(name, ""), add_help=False,
                            description=f"Benchmark: {_HELP.get(name, name)}. Options go to "
                            f"python -m {module} ('talus bench {name} --help').")
        sp.add_argument("rest", nargs=argparse.REMAINDER, help="benchmark options")
        sp.set_defaults(run=_module_runner(name))


def _devices(choice: str) -> list[str]:
    if choice != "all":
        return [warp_device(choice)]
    devices = ["cpu"]
    try:
        import warp as wp
    except ImportError:
        return devices
    with stdout_to_stderr():
        wp.init()
    if wp.is_cuda_available():
        devices.append("cuda")
    return devices


def run_drr(args: argparse.Namespace) -> int:
    run_drr_benchmark = load(BENCHMARKS["drr"], needed_for="'talus bench drr'")
    devices = _devices(args.device)
    print(f"{PROG} bench drr: devices {', '.join(devices)}", file=sys.stderr)
    with stdout_to_stderr():
        result = run_drr_benchmark(devices=devices, quick=args.quick)
    print_json(result, args.out)
    if args.out:
        print(f"{PROG} bench drr: wrote {args.out}", file=sys.stderr)
    return EXIT_OK


def run_interaction(args: argparse.Namespace) -> int:
    run = load(BENCHMARKS["interaction"], needed_for="'talus bench interaction'")
    warp_device(args.device)
    with stdout_to_stderr():
        result = run(pixels=args.pixels, device=args.device)
    print_json(result, Path(args.out) if args.out else None)
    return EXIT_OK


def _module_runner(name: str):
    """Run ``BENCHMARKS[name]``, a ``main(argv)``; a ``main(argv, prog=...)`` is given
    ``talus bench NAME`` as the name its usage shows."""

    def run(args: argparse.Namespace) -> int:
        main_fn = load(BENCHMARKS[name], needed_for=f"'talus bench {name}'")
        argv = [a for a in args.rest if a != "--"]
        if "prog" in inspect.signature(main_fn).parameters:
            result = main_fn(argv, prog=f"{PROG} bench {name}")
        else:
            result = main_fn(argv)
        return int(result or 0)

    return run
