"""Where the evaluation scripts find the shared sample data (``../shared/data``:
TUM fr1_desk, ICL-NUIM and 7-Scenes redkitchen samples, see its README.md)."""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["shared_data_root"]


def shared_data_root() -> Path:
    """``$SPGEO_SHARED_DATA`` when set, else ``shared/data`` beside the checkout
    (the folder holding ``spgeo``'s repository).  The folder may not exist:
    callers check and say so."""
    env = os.environ.get("SPGEO_SHARED_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"
