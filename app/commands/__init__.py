"""The ``talus`` commands: one module per command, listed in :data:`COMMANDS`.

A command module defines

* ``HELP``: its one-line summary in ``talus --help``;
* ``configure(parser)``: adds its arguments (and sub-commands) to its ``argparse`` parser and
  sets ``parser.set_defaults(run=...)`` for what runs it;
* ``run(args) -> int``: does the work and returns the exit status (see
  :mod:`app.commands._shared` for JSON output, progress, Ctrl-C and error handling).

Command modules import ``core`` (numpy, Warp, …) only inside ``run``, so building the parser
for ``talus --help`` imports none of it. Adding a command is one new module here plus one line
in :data:`COMMANDS`.
"""

from __future__ import annotations

# command name -> module (the order of `talus --help`)
COMMANDS: dict[str, str] = {
    "demo": "app.commands.demo",
    "gui": "app.commands.gui",
    "calibrate": "app.commands.calibrate",
    "track": "app.commands.track",
    "batch": "app.commands.batch",
    "study": "app.commands.study",
    "report": "app.commands.report",
    "bench": "app.commands.bench",
    "sample": "app.commands.sample",
    "import": "app.commands.import_folder",
    "export": "app.commands.export",
}

__all__ = ["COMMANDS"]
