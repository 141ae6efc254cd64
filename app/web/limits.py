"""How much one request may ask of the desk: the size of an upload and the rows of data an import or a
calibration may hold. Work that grows with the data is bounded by these, or refused up front naming the
limit (`calib serve --max-upload-mb`, `--max-rows`), never left to run out of memory."""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_MAX_UPLOAD_BYTES = 20 * 1024 * 1024
# 96,000 Robonaut observations (3 coordinates each): imported in 8 s, calibrated (full, 20% held out) in 66 s
# (148 s on a busy machine) with the server and its worker at 1.5 GB at most (benchmarks/big_session.py, 2 cores).
DEFAULT_MAX_ROWS = 100_000


@dataclass(frozen=True)
class Limits:
    upload_bytes: int = DEFAULT_MAX_UPLOAD_BYTES  # a CSV to import, a robot's profile with its URDF
    rows: int = DEFAULT_MAX_ROWS  # rows of a CSV to import; observations of a calibration

    def __post_init__(self) -> None:
        if self.upload_bytes < 1024 or self.rows < 1:
            raise ValueError("an upload limit of at least 1 KB and a row limit of at least 1")

    @property
    def unpacked_bytes(self) -> int:
        """A robot's meshes unpacked from their zip: 8 times the upload limit (meshes zip to a third to a fifth)."""
        return 8 * self.upload_bytes

    @property
    def upload_text(self) -> str:
        """The upload limit as the operator set it (MB)."""
        return f"{self.upload_bytes / (1024 * 1024):g} MB"
