"""File formats: TUM trajectories and status files (:mod:`spgeo.io.tum`)."""
from .tum import read_status, read_tum, status_path_for, write_status, write_tum

__all__ = ["read_tum", "write_tum", "status_path_for", "write_status", "read_status"]
