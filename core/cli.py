"""The ``baarda`` command.

Exit status: 0 success; 1 the analysis ran but a check asked for failed (none yet);
2 bad input or usage (one line ``baarda: error: FILE:LINE: what is wrong`` or ``baarda: error:
COMMAND: what is wrong with the options``, no traceback unless ``--debug``): also an output that
names an input or cannot be written; 3 an internal error; 4 (:data:`NOT_CONVERGED`) the
adjustment did not converge within ``--max-iter`` iterations (or stalled): the results are
written, marked as not converged (JSON ``summary.converged`` false and ``summary.termination``,
a column ``adjustment`` in every CSV, a banner in the report), and one line ``baarda: FILE: NOT
converged: ...`` goes to stderr — unless the normal equations are singular at the last iterate,
when nothing is written and the line says so; 130 interrupted (SIGINT, Ctrl-C) and 143
terminated (SIGTERM), with one line ``baarda: interrupted`` / ``baarda: terminated``; 141 the
reader of the output went away (a broken pipe, ``baarda ... | head``), quietly, as other
commands do.

Outputs are checked before anything is read (:func:`baarda.io.output.check_outputs`: never
an input, also through a link; writable) and written atomically (:func:`baarda.io.output.atomic_write`):
an interrupted run leaves the previous file as it was.
"""

from __future__ import annotations

import os
import signal
import sys

from .cli_parser import NOT_CONVERGED, build_parser
from .errors import BaardaError
from .text import printable, shorten

__all__ = ["main", "build_parser", "NOT_CONVERGED"]


class Terminated(BaseException):
    """SIGTERM, raised in the main thread as SIGINT raises KeyboardInterrupt (exit status 143)."""


def _terminate(signum, frame):
    raise Terminated


def main(argv=None) -> int:
    """``baarda ARGS``: parse the arguments (light: no numpy), then load and run the command.

    The computation is imported inside the handlers below, so a Ctrl-C or a SIGTERM while it
    loads (seconds on a loaded machine) ends in one line with 130 or 143, as one during the run
    does (issue 25)."""
    args = build_parser().parse_args(argv)
    previous = None
    if args.command != "serve":        # (the server keeps its own way of ending)
        try:
            previous = signal.signal(signal.SIGTERM, _terminate)
        except ValueError:             # not the main thread (main() called from a thread)
            pass
    try:
        from .commands import run
        from .threads import limit_native_threads

        limit_native_threads()
        code = run(args)
        sys.stdout.flush()             # a broken pipe shows here, not at exit
        return code
    except BaardaError as err:
        if getattr(args, "debug", False):
            raise
        print(f"baarda: error: {shorten(printable(err))}", file=sys.stderr)   # one line, whatever the file holds
        return 2
    except KeyboardInterrupt:
        print("baarda: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("baarda: terminated", file=sys.stderr)
        return 143
    except BrokenPipeError:            # the reader of our output went away (`baarda ... | head`)
        try:
            sys.stdout = open(os.devnull, "w")   # no second error when Python flushes at exit
        except OSError:
            pass
        return 141
    except Exception as err:  # an internal error: say so in one line, traceback with --debug
        if getattr(args, "debug", False):
            raise
        print(f"baarda: internal error: {type(err).__name__}: {shorten(printable(err))} (run with --debug for details)",
              file=sys.stderr)
        return 3
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
