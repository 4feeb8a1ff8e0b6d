"""Entry point of the standalone bundle: the ``talus`` command (``talus gui`` opens the window)."""

import multiprocessing
import sys

if __name__ == "__main__":
    multiprocessing.freeze_support()  # worker processes of a frozen app re-enter here
    from app.cli import main

    sys.exit(main())
