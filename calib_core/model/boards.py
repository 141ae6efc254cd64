"""Printed boards a target may be, as the profile gives them: a ChArUco board (specs handeye.md).

OpenCV's `CharucoBoard((across, down), square, marker, dictionary)`: a checkerboard of `across` x `down`
squares with an ArUco marker in each white square. Vertex k is OpenCV's ChArUco corner id k, the inner
corners row by row from the board's origin (its top-left outer corner, x across, y down, the printed face
towards -z), at `getChessboardCorners()[k]`. The model needs no OpenCV: the layout is computed here, and
the dictionaries are known by name with their number of markers (tests/test_finders.py checks both
against OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..sensors import SpecReader

MIN_CHARUCO_CORNERS = 6  # a ChArUco view with fewer corners found measures nothing (specs handeye.md)

# OpenCV's predefined ArUco dictionaries (cv2.aruco.DICT_*) and how many markers each has.
DICTIONARIES: dict[str, int] = {
    "DICT_4X4_50": 50,
    "DICT_4X4_100": 100,
    "DICT_4X4_250": 250,
    "DICT_4X4_1000": 1000,
    "DICT_5X5_50": 50,
    "DICT_5X5_100": 100,
    "DICT_5X5_250": 250,
    "DICT_5X5_1000": 1000,
    "DICT_6X6_50": 50,
    "DICT_6X6_100": 100,
    "DICT_6X6_250": 250,
    "DICT_6X6_1000": 1000,
    "DICT_7X7_50": 50,
    "DICT_7X7_100": 100,
    "DICT_7X7_250": 250,
    "DICT_7X7_1000": 1000,
    "DICT_ARUCO_ORIGINAL": 1024,
    "DICT_APRILTAG_16h5": 30,
    "DICT_APRILTAG_16H5": 30,
    "DICT_APRILTAG_25h9": 35,
    "DICT_APRILTAG_25H9": 35,
    "DICT_APRILTAG_36h10": 2320,
    "DICT_APRILTAG_36H10": 2320,
    "DICT_APRILTAG_36h11": 587,
    "DICT_APRILTAG_36H11": 587,
    "DICT_ARUCO_MIP_36h12": 250,
    "DICT_ARUCO_MIP_36H12": 250,
}


@dataclass(frozen=True)
class Charuco:
    """A ChArUco board: `squares` (across, down), the square's and the marker's side in the profile's length
    unit, the dictionary by OpenCV's name."""

    squares: tuple[int, int]
    square: float
    marker: float
    dictionary: str

    @property
    def shape(self) -> tuple[int, int]:
        """Rows and columns of its inner corners (vertex k: row k // columns, column k % columns)."""
        across, down = self.squares
        return down - 1, across - 1

    @property
    def markers(self) -> int:
        """How many markers it carries: one in each white square."""
        across, down = self.squares
        return across * down // 2

    def corners(self) -> np.ndarray:
        """Its inner corners (K, 3) in the board frame, in vertex (corner id) order."""
        rows, cols = self.shape
        row, col = np.divmod(np.arange(rows * cols), cols)
        return np.stack([(col + 1) * self.square, (row + 1) * self.square, np.zeros(rows * cols)], axis=1)


def read_charuco(spec: Any, reader: SpecReader, where: str) -> Charuco:
    """A profile's `charuco:` entry, checked: InputError naming the field (`where`.squares, .square, .marker,
    .dictionary) for anything OpenCV's board would not take, or a board no view could find."""
    squares = reader.get(spec, "squares", where)
    if (
        not isinstance(squares, list)
        or len(squares) != 2
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 2 for n in squares)
    ):
        raise reader.fail(f"{where}.squares", f"expected [across, down], whole numbers of 2 or more, got {squares!r}")
    square = reader.number(reader.get(spec, "square", where), f"{where}.square")
    marker = reader.number(reader.get(spec, "marker", where), f"{where}.marker")
    if square <= 0:
        raise reader.fail(f"{where}.square", f"expected the square's side, above 0, got {square:g}")
    if not 0 < marker < square:
        raise reader.fail(f"{where}.marker", f"expected the marker's side, above 0 and below the square's {square:g}")
    name = reader.get(spec, "dictionary", where)
    if not isinstance(name, str) or name not in DICTIONARIES:
        raise reader.fail(
            f"{where}.dictionary",
            f"unknown ArUco dictionary {name!r}: expected OpenCV's name, such as DICT_4X4_50, DICT_5X5_100, "
            f"DICT_6X6_250, DICT_7X7_1000 or DICT_APRILTAG_36h11 ({len(DICTIONARIES)} in all)",
        )
    board = Charuco((squares[0], squares[1]), square, marker, name)
    if board.markers > DICTIONARIES[name]:
        raise reader.fail(
            f"{where}.dictionary", f"{name} has {DICTIONARIES[name]} markers, the board needs {board.markers}"
        )
    rows, cols = board.shape
    if rows * cols < MIN_CHARUCO_CORNERS:
        raise reader.fail(
            f"{where}.squares", f"{rows * cols} inner corners; a view is found by {MIN_CHARUCO_CORNERS} corners or more"
        )
    return board
