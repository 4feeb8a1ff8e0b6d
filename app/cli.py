"""The ``talus`` command line.

Subcommands::

    talus demo  [--out DIR] [--frames N] [--pixels N] [--seed N] [--device cpu|cuda]
    talus bench drr [--device cpu|cuda|all] [--out FILE] [--quick]
    talus bench interaction [--pixels N] [--device cpu|cuda] [--out FILE]
    talus track STUDY --trial T [--bones a,b] [--frames 0:500] [--device cuda:0] [--resume]
    talus gui   [--demo DIR]
    talus sample wrist [--data DIR] [--out PNG] [--device cpu|cuda]
    talus --version

Machine-readable results (JSON) go to stdout; progress and diagnostics go to stderr, so
``talus demo > result.json`` and ``talus bench drr | jq`` work. The numerical work is done by
:mod:`core`; its modules are imported only when a command needs them, so ``talus --version`` and
``--help`` are fast and a missing optional module is reported by name.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import inspect
import json
import numbers
import os
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from . import __version__

PROG = "talus"

# exit statuses
EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_CANCELLED = 130  # the shell's convention for "stopped by SIGINT"


class CliError(Exception):
    """An error reported to the user as one line, without a traceback."""

    def __init__(self, message: str, status: int = EXIT_ERROR) -> None:
        super().__init__(message)
        self.status = status


# ----------------------------------------------------------------------------------- helpers


def _load(module: str, attr: str, *, needed_for: str, hint: str = "") -> Callable[..., Any]:
    """Import ``module.attr`` lazily; a missing module is named in the error."""
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        missing = exc.name or module
        where = "" if missing == module else f" (imported by '{module}')"
        extra = f" {hint}" if hint else ""
        raise CliError(
            f"{needed_for} needs the module '{missing}'{where}, which is not installed or "
            f"cannot be imported.{extra}"
        ) from exc
    try:
        return getattr(mod, attr)
    except AttributeError as exc:
        raise CliError(
            f"{needed_for} needs '{module}.{attr}', which this installation does not provide"
        ) from exc


def _json_default(obj: Any) -> Any:
    """JSON for paths, numpy scalars/arrays and dataclasses found in result dicts."""
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "tolist"):  # numpy arrays and scalars
        return obj.tolist()
    if hasattr(obj, "__dataclass_fields__"):
        return {name: getattr(obj, name) for name in obj.__dataclass_fields__}
    return repr(obj)


def _to_json(result: Any) -> str:
    return json.dumps(result, indent=2, default=_json_default)


def _write_atomically(path: Path, content: str | bytes) -> None:
    """Write text (plus a newline) or bytes to ``path`` via a temporary file and a rename:
    never half-written."""
    path = path.expanduser()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        if isinstance(content, bytes):
            with os.fdopen(fd, "wb") as fh:
                fh.write(content)
        else:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(content)
                fh.write("\n")
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


class CancelToken:
    """Cancellation flag handed to :mod:`core` jobs as their ``cancel`` callback.

    ``token()``, ``token.is_set()`` and ``bool(token)`` answer "has the user asked to stop?".
    """

    def __init__(self) -> None:
        self._set = False

    def set(self) -> None:
        self._set = True

    def is_set(self) -> bool:
        return self._set

    __call__ = is_set
    __bool__ = is_set


@contextlib.contextmanager
def _sigint_cancels(token: CancelToken, what: str):
    """First Ctrl-C sets ``token`` (the job stops cleanly); a second one interrupts at once."""
    previous = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame):
        token.set()
        print(f"\n{PROG} {what}: cancelling (Ctrl-C again to abort) ...", file=sys.stderr)
        signal.signal(signal.SIGINT, signal.default_int_handler)

    try:
        signal.signal(signal.SIGINT, on_sigint)
    except ValueError:  # not the main thread: leave Ctrl-C alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _progress_printer(what: str, unit: str) -> Callable[..., None]:
    """A progress callback printing one line per call to stderr.

    Accepts ``(done, total)``, ``(done, total, message)`` or a single fraction in [0, 1].
    """
    start = time.perf_counter()

    def progress(*args: Any, **kwargs: Any) -> None:
        values = [a for a in args if isinstance(a, numbers.Real) and not isinstance(a, bool)]
        texts = [str(a) for a in args if not isinstance(a, numbers.Real)]
        texts += [str(v) for k, v in kwargs.items() if k in ("message", "msg", "stage")]
        if len(values) >= 2:
            status = f"{unit} {int(values[0])}/{int(values[1])}"
        elif len(values) == 1:
            status = f"{100.0 * float(values[0]):.0f}%"
        else:
            status = ""
        line = " ".join(s for s in [status, *texts] if s)
        elapsed = time.perf_counter() - start
        print(f"{PROG} {what}: {line} ({elapsed:.1f} s)", file=sys.stderr, flush=True)

    return progress


# ---------------------------------------------------------------------------------- commands


def _cmd_demo(args: argparse.Namespace) -> int:
    make_demo_study = _load(
        "core.synthetic.demo", "make_demo_study", needed_for="'talus demo'"
    )
    out = Path(args.out).expanduser()
    cached = None if args.regenerate else _cached_demo(out, args)
    if cached is not None:
        print(f"{PROG} demo: using the demo study already in {out} (--regenerate to rebuild)",
              file=sys.stderr)
        print(_to_json(cached))
        return _open_demo_gui(out, args)
    token = CancelToken()
    with _sigint_cancels(token, "demo"):
        try:
            # core libraries (Warp) print their start-up banner on stdout: keep stdout pure JSON
            # options left out take the defaults of make_demo_study
            given = {"n_frames": args.frames, "pixels": args.pixels, "seed": args.seed,
                     "device": args.device}
            options = {k: v for k, v in given.items() if v is not None}
            with contextlib.redirect_stdout(sys.stderr):
                result = make_demo_study(
                    out, **options, progress=_progress_printer("demo", "frame"), cancel=token
                )
        except KeyboardInterrupt:
            token.set()
            result = None
        except Exception:
            if not token.is_set():
                raise
            result = None
    if result is not None:
        print(_to_json(result))  # also after a cancel: the summary says what was written
    if token.is_set():
        print(f"{PROG} demo: cancelled; complete frames so far are in {out}", file=sys.stderr)
        return EXIT_CANCELLED
    return _open_demo_gui(out, args)


def _cached_demo(out: Path, args: argparse.Namespace) -> dict | None:
    """The summary of a complete demo study in ``out`` made with the same options, if any."""
    try:
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if summary.get("format") != "talus-synthetic-study" or summary.get("status") != "complete":
        return None
    for option, key in (("frames", "n_frames"), ("pixels", "pixels"), ("seed", "seed")):
        value = getattr(args, option)
        if value is not None and summary.get(key) != value:
            return None
    return summary


def _open_demo_gui(out: Path, args: argparse.Namespace) -> int:
    """Show the demo study in the window when asked to and a display is available."""
    if args.no_gui:
        return EXIT_OK
    if sys.platform.startswith("linux") and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        print(f"{PROG} demo: no display; view the study with '{PROG} gui --demo {out}'",
              file=sys.stderr)
        return EXIT_OK
    try:
        run_gui = _load("app.main_window", "run_gui", needed_for="showing the demo",
                        hint="Install the GUI extra: pip install 'talus-biplane[gui]'.")
    except CliError as exc:
        print(f"{PROG} demo: {exc}", file=sys.stderr)
        return EXIT_OK
    return int(run_gui(demo=out))


def _bench_devices(choice: str) -> list[str]:
    if choice != "all":
        return [choice]
    devices = ["cpu"]
    try:
        import warp as wp
    except ImportError:
        return devices
    with contextlib.redirect_stdout(sys.stderr):
        wp.init()
    if wp.is_cuda_available():
        devices.append("cuda")
    return devices


def _cmd_bench_drr(args: argparse.Namespace) -> int:
    run_drr_benchmark = _load(
        "core.studies.render.benchmark", "run_drr_benchmark", needed_for="'talus bench drr'"
    )
    devices = _bench_devices(args.device)
    print(f"{PROG} bench drr: devices {', '.join(devices)}", file=sys.stderr)
    with contextlib.redirect_stdout(sys.stderr):
        result = run_drr_benchmark(devices=devices, quick=args.quick)
    text = _to_json(result)
    if args.out:
        _write_atomically(Path(args.out), text)
        print(f"{PROG} bench drr: wrote {args.out}", file=sys.stderr)
    print(text)
    return EXIT_OK


def _cmd_sample_wrist(args: argparse.Namespace) -> int:
    load = _load("core.samples", "load_wrist_sample", needed_for="'talus sample wrist'")
    preview = _load("core.samples", "wrist_preview", needed_for="'talus sample wrist'")
    data = Path(args.data).expanduser()
    if not data.is_dir():
        raise CliError(
            f"--data: expected the autoscoper_wrist sample folder, '{data}' is not a directory"
        )
    try:
        sample = load(data)
        rgb, drrs = preview(sample, device=args.device)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    import cv2

    out = Path(args.out)
    ok, png = cv2.imencode(".png", rgb[..., ::-1])
    if not ok:
        raise CliError(f"--out: could not encode the preview as PNG for {out}")
    _write_atomically(out, png.tobytes())
    print(f"{PROG} sample wrist: wrote {out}", file=sys.stderr)
    print(_to_json({"png": str(out), "views": len(drrs),
                    "drr_max": [float(d.max()) for d in drrs],
                    "drr_shape": [list(d.shape) for d in drrs]}))
    return EXIT_OK


def _cmd_bench_interaction(args: argparse.Namespace) -> int:
    run = _load("app.benchmark", "run_interaction_benchmark",
                needed_for="'talus bench interaction'")
    with contextlib.redirect_stdout(sys.stderr):
        result = run(pixels=args.pixels, device=args.device)
    text = _to_json(result)
    if args.out:
        _write_atomically(Path(args.out), text)
    print(text)
    return EXIT_OK


def _cmd_bench_module(module: str, what: str):
    """A ``talus bench`` subcommand running ``core.studies.<module>.benchmark.main(argv)``."""

    def command(args: argparse.Namespace) -> int:
        main_fn = _load(f"core.studies.{module}.benchmark", "main", needed_for=f"'talus bench {what}'")
        argv = [a for a in args.rest if a != "--"]
        if inspect.signature(main_fn).parameters:
            result = main_fn(argv)
        else:  # a main() that parses sys.argv itself
            saved = sys.argv
            sys.argv = [f"{PROG} bench {what}", *argv]
            try:
                result = main_fn()
            finally:
                sys.argv = saved
        return int(result or 0)

    return command


def _cmd_track(args: argparse.Namespace) -> int:
    main_fn = _load("core.tracking.cli", "main", needed_for="'talus track'")
    argv = [a for a in args.rest if a != "--"] or ["--help"]
    return int(main_fn(argv) or 0)


def _check_display() -> None:
    """Qt aborts the process when it finds no display: say so clearly instead."""
    if not sys.platform.startswith("linux") or os.environ.get("QT_QPA_PLATFORM"):
        return
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise CliError(
            "'talus gui' needs a display: DISPLAY is not set (run it from a desktop session, "
            "over ssh -X, or under xvfb-run)"
        )


def _cmd_gui(args: argparse.Namespace) -> int:
    run_gui = _load(
        "app.main_window",
        "run_gui",
        needed_for="'talus gui'",
        hint="Install the GUI extra: pip install 'talus-biplane[gui]'.",
    )
    demo = None
    if args.demo is not None:
        demo = Path(args.demo).expanduser()
        if not demo.is_dir():
            raise CliError(f"--demo: expected a demo study folder, '{demo}' is not a directory")
    _check_display()
    return int(run_gui(demo=demo))


# ------------------------------------------------------------------------------------ parser


def _int_at_least(minimum: int) -> Callable[[str], int]:
    """argparse type: an integer >= ``minimum``; the error names the value given."""
    want = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {want}, got {value}")
        return value

    return parse


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Talus: biplane fluoroscopy bone tracking.",
        epilog="JSON results go to stdout, progress to stderr.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = sub.add_parser(
        "demo",
        help="write (once) and open the built-in synthetic biplane study",
        description="Write the built-in synthetic biplane study (rig, CT volumes, fluoroscope "
        "frames rendered at known bone poses, ground truth) to --out, print its summary as "
        "JSON and open it in the window when a display is available. A study already in --out "
        "made with the same options is reused. Ctrl-C cancels cleanly after the frame in "
        "progress.",
    )
    demo.add_argument("--out", default="demo_out", metavar="DIR", help="output folder")
    demo.add_argument("--frames", type=_int_at_least(1), metavar="N",
                      help="number of frames (default: the demo's, 10)")
    demo.add_argument("--pixels", type=_int_at_least(1), metavar="N",
                      help="image size in pixels, N x N (default: the demo's, 512)")
    demo.add_argument("--seed", type=_int_at_least(0), metavar="N",
                      help="random seed (default 0)")
    demo.add_argument("--device", choices=["cpu", "cuda"],
                      help="Warp device for the DRRs (default: cuda when present, else cpu)")
    demo.add_argument("--no-gui", action="store_true",
                      help="only write the study (the window opens when a display is available)")
    demo.add_argument("--regenerate", action="store_true",
                      help="rebuild the study even if --out already holds one made with the "
                      "same options")
    demo.set_defaults(func=_cmd_demo)

    bench = sub.add_parser("bench", help="benchmarks that print JSON")
    bench_sub = bench.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    drr = bench_sub.add_parser(
        "drr",
        help="DRR rendering speed",
        description="Time DRR rendering on the given devices and print JSON (machine, device, "
        "sizes, times).",
    )
    drr.add_argument("--device", choices=["cpu", "cuda", "all"], default="all",
                     help="device(s) to time; 'all' = cpu plus cuda when present (default)")
    drr.add_argument("--out", metavar="FILE", help="also write the JSON to FILE")
    drr.add_argument("--quick", action="store_true", help="small sizes, few repeats")
    drr.set_defaults(func=_cmd_bench_drr)
    inter = bench_sub.add_parser(
        "interaction",
        help="overlay update latency while dragging a bone",
        description="Time preview and full-resolution overlay updates of one dragged bone on "
        "the demo study and print JSON.",
    )
    inter.add_argument("--pixels", type=_int_at_least(16), default=512, metavar="N")
    inter.add_argument("--device", choices=["cpu", "cuda"], default=None)
    inter.add_argument("--out", metavar="FILE", help="also write the JSON to FILE")
    inter.set_defaults(func=_cmd_bench_interaction)
    for what, module, text in (
        ("io", "io", "frame access of cine and TIFF sequences"),
        ("imaging", "imaging", "flatfield, undistortion, deconvolution, grid fits"),
        ("markers", "markers", "bead localisations per second"),
        ("metrics", "similarity", "similarity metrics of DRR batches"),
        ("track", "tracking", "whole-trial tracking speed and where the time goes"),
    ):
        sp = bench_sub.add_parser(what, help=text, description=f"Benchmark: {text}. Other options "
                                  f"go to python -m core.studies.{module}.benchmark (its own help: "
                                  f"'talus bench {what} -- --help').")
        sp.add_argument("rest", nargs=argparse.REMAINDER, help="benchmark options")
        sp.set_defaults(func=_cmd_bench_module(module, what))

    sample = sub.add_parser("sample", help="previews of real sample data")
    sample_sub = sample.add_subparsers(dest="sample", metavar="SAMPLE", required=True)
    wrist = sample_sub.add_parser(
        "wrist",
        help="render the radius of the Autoscoper wrist sample over its radiographs",
        description="Load the Autoscoper wrist sample (MayaCam cameras, TIFF CT sub-volumes, "
        "radiographs), render the radius at a hand-found pose in both cameras and save a PNG "
        "(radiograph | DRR | overlay per camera).",
    )
    wrist.add_argument("--data", default="../shared/data/autoscoper_wrist", metavar="DIR",
                       help="the autoscoper_wrist folder (default ../shared/data/autoscoper_wrist)")
    wrist.add_argument("--out", default="wrist_radius.png", metavar="PNG", help="output image")
    wrist.add_argument("--device", choices=["cpu", "cuda"], default=None,
                       help="Warp device (default: cuda when present)")
    wrist.set_defaults(func=_cmd_sample_wrist)

    track = sub.add_parser(
        "track", help="track bones of a study trial (results saved frame by frame)",
        description="Track bones of a study trial; options as in core.tracking.cli: STUDY "
        "--trial T [--bones a,b] [--frames 0:500] [--backward] [--device cuda:0] [--resume] "
        "[--guess velocity|previous|spline] [--mode sequential|joint] [--metric gc] "
        "[--max-uncertainty MM,DEG]. Use 'talus track --help' for the full list.", add_help=False)
    track.add_argument("rest", nargs=argparse.REMAINDER, help="tracking options")
    track.set_defaults(func=_cmd_track)

    gui = sub.add_parser("gui", help="open the Talus window")
    gui.add_argument("--demo", metavar="DIR", help="open this demo study folder at start")
    gui.set_defaults(func=_cmd_gui)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``talus`` command; returns the exit status."""
    parser = build_parser()
    # commands that hand their options to a core module take them without a '--' too
    # ('talus track --help', 'talus bench track --cases one')
    args, extra = parser.parse_known_args(argv)
    if extra:
        if not hasattr(args, "rest"):
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        args.rest = [*extra, *args.rest]
    try:
        return args.func(args)
    except CliError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return exc.status
    except (ValueError, OSError) as exc:
        if os.environ.get("TALUS_DEBUG"):
            raise
        print(f"{PROG} {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
        return EXIT_CANCELLED


if __name__ == "__main__":
    sys.exit(main())
