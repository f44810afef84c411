"""JSON output of result objects (reports, evaluation tables)."""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["json_default"]


def json_default(obj: Any) -> Any:
    """``json.dump`` fallback: numpy arrays -> lists, numpy scalars -> Python
    numbers, anything else -> ``str``."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    return str(obj)

