"""Resident memory of the running process, for run reports (Linux; elsewhere
the current RSS is unknown and the peak is ``getrusage``'s).

* :func:`current_rss_mb`: resident set size now (``/proc/self/statm``), MiB.
* :func:`peak_rss_mb`: the process's peak resident set size so far
  (``resource.getrusage(RUSAGE_SELF).ru_maxrss``), MiB.
* :class:`RssCheckpoints`: the current RSS every ``every`` frames of a loop.
"""
from __future__ import annotations

import os
import sys
from typing import Dict, Optional

__all__ = ["current_rss_mb", "peak_rss_mb", "RssCheckpoints"]

_MIB = 1024.0 * 1024.0


def current_rss_mb() -> Optional[float]:
    """Resident set size of this process now, MiB (None where ``/proc`` is absent)."""
    try:
        with open("/proc/self/statm", "rb") as fh:
            pages = int(fh.read().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return pages * os.sysconf("SC_PAGE_SIZE") / _MIB


def peak_rss_mb() -> Optional[float]:
    """Peak resident set size of this process so far, MiB (``ru_maxrss``: kB on
    Linux, bytes on macOS); None without the ``resource`` module."""
    try:
        import resource
    except ImportError:
        return None
    peak = float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    return peak / _MIB if sys.platform == "darwin" else peak / 1024.0


class RssCheckpoints:
    """Current RSS (MiB) after every ``every``-th frame of a loop.

    :meth:`frame_done` is called once per processed frame (cheap: one read of
    ``/proc/self/statm`` every ``every`` frames); :meth:`report` gives
    ``{"peak_rss_mb", "rss_every_frames", "rss_mb"}`` with ``rss_mb`` mapping
    the number of frames processed (as a string, for JSON) to the RSS then.
    """

    def __init__(self, every: int = 100) -> None:
        if int(every) < 1:
            raise ValueError("RssCheckpoints: every must be >= 1")
        self.every = int(every)
        self.n = 0
        self.rss: Dict[str, float] = {}

    def frame_done(self) -> None:
        """Count one processed frame; record the RSS at every ``every``-th."""
        self.n += 1
        if self.n % self.every == 0:
            rss = current_rss_mb()
            if rss is not None:
                self.rss[str(self.n)] = round(rss, 1)

    def report(self) -> Dict[str, object]:
        """The peak RSS now (MiB) and the checkpoints (JSON-ready)."""
        peak = peak_rss_mb()
        return {"peak_rss_mb": None if peak is None else round(peak, 1),
                "rss_every_frames": self.every, "rss_mb": dict(self.rss)}
