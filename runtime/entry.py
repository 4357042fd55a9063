"""Console entry points of the runtime's tools (``[project.scripts]``).

Each imports its tool inside a guard: loading torch takes a second or two, and Ctrl-C (or
``kill``) in that time should end the program with one line, not a traceback through the
import machinery.
"""

from __future__ import annotations

import importlib
import signal
import sys

__all__ = ["calibrate", "personalize", "run_tool", "track"]


def run_tool(module: str, argv: list[str] | None = None) -> int:
    """Import ``module`` and return its ``main(argv)``; 130 (Ctrl-C) or 143 (SIGTERM) with
    one line on stderr when stopped while importing."""
    terminated = []

    def on_term(signum, frame):
        terminated.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        main = importlib.import_module(module).main
    except KeyboardInterrupt:
        print("terminated" if terminated else "interrupted", file=sys.stderr)
        return 143 if terminated else 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    return main(argv)


def track() -> None:
    """``runtime-track``."""
    sys.exit(run_tool("depthmocap.runtime.track_cli"))


def calibrate() -> None:
    """``runtime-calibrate``."""
    sys.exit(run_tool("depthmocap.runtime.calibrate_cli"))


def personalize() -> None:
    """``runtime-personalize``."""
    sys.exit(run_tool("depthmocap.runtime.personalize_cli"))
