"""The ``talus`` command line: the parser, assembled from :mod:`app.commands`, and dispatch.

Each command lives in its own module (``app/commands/<name>.py``, listed in
:data:`app.commands.COMMANDS`); what they share (JSON output, progress, Ctrl-C, errors and
exit statuses) is :mod:`app.commands._shared`. Machine-readable results (JSON) go to stdout;
progress and diagnostics go to stderr, so ``talus demo > result.json`` and
``talus bench drr | jq`` work. :mod:`core` is imported only when a command runs, so
``talus --help``, ``--version`` and argument errors answer at once.

Exit statuses: 0 done, 1 error (the message names the file or argument), 2 bad arguments,
3 the study is open for writing elsewhere, 4 nothing could be done (``talus track``: no bone
could be tracked), 130 interrupted by Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from core import __version__

from .commands import COMMANDS
from .commands._shared import (
    DEBUG_ENV,
    EXIT_CANCELLED,
    EXIT_ERROR,
    EXIT_LOCKED,
    EXIT_NOTHING_DONE,
    EXIT_OK,
    EXIT_USAGE,
    PROG,
    CliError,
    debugging,
    report_error,
)

__all__ = ["EXIT_CANCELLED", "EXIT_ERROR", "EXIT_LOCKED", "EXIT_NOTHING_DONE", "EXIT_OK",
           "EXIT_USAGE", "CliError", "build_parser", "main"]


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, with room for sub-command names beside their help: argparse
    measures them one indent short, so a name as long as 'calibrate' put its help on the next
    line."""

    def add_argument(self, action: argparse.Action) -> None:
        super().add_argument(action)
        if action.help is not argparse.SUPPRESS and isinstance(action, argparse._SubParsersAction):
            names = [len(self._format_action_invocation(a)) for a in action._get_subactions()]
            self._action_max_length = max(self._action_max_length,
                                          max(names, default=0) + self._current_indent + 2)


class _Parser(argparse.ArgumentParser):
    """The parser of ``talus`` and of every command (sub-parsers are of the same class)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog=PROG,
        description="Talus: biplane fluoroscopy bone tracking.",
        epilog="JSON results go to stdout, progress to stderr. Exit status: 0 done, 1 error, "
        "2 bad arguments, 3 study locked by another writer, 4 nothing could be done, "
        "130 interrupted (Ctrl-C).",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help=f"show tracebacks of errors (or set {DEBUG_ENV}=1)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(module_name)
        command = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.configure(command)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``talus`` command; returns the exit status."""
    parser = build_parser()
    # commands that hand their options to a library module take them without a '--' too
    # ('talus bench track --cases one')
    args, extra = parser.parse_known_args(argv)
    if extra:
        if not hasattr(args, "rest"):
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        args.rest = [*extra, *args.rest]
    command = " ".join(str(v) for v in (args.command, getattr(args, "benchmark", None),
                                        getattr(args, "sample", None),
                                        getattr(args, "action", None)) if v)
    try:
        return int(args.run(args) or EXIT_OK)
    except KeyboardInterrupt:
        print(f"\n{PROG} {command}: interrupted", file=sys.stderr)
        return EXIT_CANCELLED
    except Exception as exc:
        if (args.debug or debugging()) and not isinstance(exc, CliError):
            raise
        return report_error(exc, command)


if __name__ == "__main__":
    sys.exit(main())
