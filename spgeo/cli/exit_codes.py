"""The exit codes of every ``spgeo`` command (README, "Exit codes and outputs")."""

__all__ = ["EXIT_OK", "EXIT_FAILED", "EXIT_BAD_INPUT", "EXIT_FLAGGED", "EXIT_INTERRUPTED"]

#: done, result ok
EXIT_OK = 0
#: an unexpected error (one line on stderr; the traceback with ``-v -v``)
EXIT_FAILED = 1
#: bad arguments or input files (one line naming the value or file; nothing written)
EXIT_BAD_INPUT = 2
#: finished and outputs written, but the result is flagged (SfM status not ok, VO
#: without a map, a model not in the cache)
EXIT_FLAGGED = 3
#: Ctrl-C (VO writes the frames processed so far, marked interrupted)
EXIT_INTERRUPTED = 130
