"""The NAO's checkerboard sandals as its lower camera sees them: rendering, and detection as in the paper.

The paper (Kastner, Roefer, Laue, section 2.2) measures the 6 x 4 inner vertices of the 7 x 5
checkerboard under each foot in the lower camera's image; here OpenCV's chessboard detectors find
them. To test that measurement without a robot,
`render_board_image` ray-casts the board as the camera model sees it for given parameters and joint
angles (the exact vertex projections come with the image) and adds the camera's blur, uneven light,
noise and 8-bit quantisation. `detect_board` finds the vertices and gives them their identities.

The boards are seen very obliquely (the view ray meets the sole's normal at 77-90 degrees in the
simulated stances): a 25 mm tile is about 40 px wide but only 0.5-9 px tall. OpenCV's detectors find
almost none of them in the raw image, so when the kinematic prediction is known the detector first
stretches the predicted board region to roughly square tiles (an affine warp, which has no horizon
to blow up), and finally refines every corner in an image rectified by the homography of the found
grid, where the tiles are square and each corner window holds just its own two edges. Without a
prediction it looks for the board's bright margin instead (the largest bright four-sided outline at
two grey-level cuts) and rectifies that quadrilateral by its homography before detecting.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..model.kinematics import forward, sensor_points
from ..model.profile import Profile
from ..sensors import Pinhole

# Grey levels of the scene before the camera effects.
BLACK, WHITE, PLATE, ROOM = 35.0, 215.0, 120.0, 25.0
# The white margin around the tiles (OpenCV needs it to separate the outer black tiles) and the plate
# rim beyond it, in whole tiles so that every colour boundary lies on the tile lattice.
QUIET_TILES, RIM_TILES = 1, 1

# Detection: the prediction may be off by up to FAR_PX (mean over the corners), and the better of the
# two orders must be closer than AMBIGUOUS_RATIO times the other. The detectors look at the predicted
# board warped to tiles of CLASSIC_TILE_PX and SB_TILES_PX (least, most), stretched by at most
# STRETCH_MAX, in views of at most VIEW_MAX_PX a side; the final refinement works on REFINE_TILE_PX tiles.
# The sector-based detector's answer on a hard view turns on the tile size and on its random draws: it is
# tried at each of SB_TILES_PX with SB_SEEDS seeds. Of 720 views of three simulated sessions, each a grey level
# and half a pixel of prediction away from the rendered one, it lost none where one unseeded try lost 3.
FAR_PX = 80.0
AMBIGUOUS_RATIO = 0.5
CLASSIC_TILE_PX = (32.0, np.inf)
SB_TILES_PX = ((16.0, 32.0), (24.0, 40.0), (12.0, 20.0))
SB_SEEDS = 2
STRETCH_MAX = 12.0
VIEW_MAX_PX = 1024
REFINE_TILE_PX = 64
OUTLINE_TILE_PX = 40  # tile size of a view rectified by the board's bright outline (no prediction)
OUTLINE_MIN_PX2 = 400.0  # the smallest outline area worth a look
REFINE_BLUR_PX = 0.5  # smooths sharp edges before the rectifying warp interpolates them
# A flat board's corners lie on a homography of the lattice; their RMS distance from the best one
# tracks the true corner error closely (benchmarks/sandal_board.py). Beyond this the corners are a
# false grid or too foreshortened to be measured well.
GRID_RESIDUAL_PX = 0.3

# What the detector measures reliably (benchmarks/sandal_board.py): a board seen at most
# MAX_OBLIQUITY_DEG from its normal, its neighbouring vertices at least MIN_VERTEX_SPACING_PX apart in
# the image. Beyond, tiles a pixel or two tall merge under the blur and most views are lost as
# "partial", "inconsistent" or "not found"; the simulator picks no such view.
MAX_OBLIQUITY_DEG = 86.0
MIN_VERTEX_SPACING_PX = 2.5
MIN_IMAGE_PX = 15  # an image with a side shorter than this holds no board (and makes OpenCV's detectors raise)
# Larger images are not searched: OpenCV's detectors took 19 s on 8000 x 6000 px (a damaged JPEG header said so,
# its pixels mostly grey) and 4 min on 20000 x 20000; a 24 MP camera's image is 6000 x 4000.
MAX_IMAGE_PX = 25_000_000

_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)


@dataclass
class BoardImage:
    image: np.ndarray  # (H, W) uint8 grey
    corners_true: np.ndarray  # (K, 2) px: the exact projection of the vertices, in vertex order
    obliquity_deg: float  # angle between the board's normal and the view ray to its centre


@dataclass
class BoardDetection:
    found: bool
    corners: np.ndarray | None  # (rows * cols, 2) px in row-major order of the board
    reason: str  # "ok", "not found", "partial", "inconsistent", "ambiguous", "far from prediction"
    detail: str = ""  # the numbers behind the reason
    residual_px: float | None = None  # RMS distance of the corners from a flat board's homography

    def to_json(self) -> dict[str, Any]:
        corners = None if self.corners is None else [[float(u), float(v)] for u, v in self.corners]
        return {
            "found": self.found,
            "corners": corners,
            "reason": self.reason,
            "detail": self.detail,
            "residual_px": self.residual_px,
        }


# --- rendering ----------------------------------------------------------------------------------


def board_corners(profile: Profile, p: np.ndarray, q: np.ndarray, target: int, sensor: int | None = None) -> np.ndarray:
    """Image positions (K, 2) px of a board's vertices for parameters p and joint readings q (rad), in a
    camera's image (default: the data sensor's)."""
    s = profile.data.sensor if sensor is None else sensor
    x = sensor_points(profile, p, q[None], np.array([target]), sensor=s)[0, : len(profile.targets[target].grid)]
    return profile.sensors[s].predict(p, x)[0]


def _poses(profile: Profile, p: np.ndarray, q: np.ndarray, target: int, sensor: int) -> tuple[np.ndarray, ...]:
    """Base-frame rotation and position of the board's frame and of the camera's frame."""
    board, camera = profile.targets[target].frame, profile.sensors[sensor].frame
    poses = forward(profile, p, np.asarray(q, float)[None], frames=[board, camera])
    return poses.R[board][0], poses.t[board][0], poses.R[camera][0], poses.t[camera][0]


def render_board_image(
    profile: Profile,
    p: np.ndarray,
    q: np.ndarray,
    target: int,
    rng: np.random.Generator,
    *,
    blur_px: float = 0.8,
    noise: float = 2.0,
    light: float = 0.35,
    supersample: int = 8,
    sensor: int | None = None,
) -> BoardImage:
    """What the profile's camera sees of board `target` for parameters p and joint readings q (rad).

    A pixel whose footprint on the board plane lies in one cell of the tile lattice takes that cell's
    colour; the others (edges) average supersample^2 rays, an exact anti-aliasing at little cost.
    `blur_px` is the optics' Gaussian sigma, `noise` the sensor noise's sigma in grey levels, `light`
    how far the illumination falls towards one side and the image corners (0: even). The rest of the
    robot is not drawn: the room behind the board is dark. `sensor`: the camera (default: the data sensor).
    """
    s = profile.data.sensor if sensor is None else sensor
    camera = profile.sensors[s]
    tgt = profile.targets[target]
    if not isinstance(camera, Pinhole) or camera.image is None or tgt.grid is None or tgt.grid_shape is None:
        raise ValueError("rendering needs a pinhole sensor with an image size and a board target")
    if camera.distortion is not None and np.any(p[list(camera.distortion)] != 0):
        raise ValueError("rendering supports no lens distortion")
    Rb, tb, Rs, ts = _poses(profile, p, q, target, s)
    corners = board_corners(profile, p, q, target, s)

    # A pixel's ray meets the board plane where a homography G says (the ray-plane intersection in
    # closed form): (col w, row w, w) = G (u, v, 1), in tiles from vertex 0; w > 0 where the ray hits.
    o = Rb.T @ (ts - tb)
    fx, fy, cx, cy = (float(p[i]) for i in camera.intrinsics)
    D = Rb.T @ Rs @ camera.R_frame_optical @ np.array([[1 / fx, 0, -cx / fx], [0, 1 / fy, -cy / fy], [0, 0, 1]])
    x0, y0, z0 = tgt.grid[0]
    h = z0 - o[2]  # the plane's height above the camera
    G = np.sign(h) * np.stack([(o[0] - x0) * D[2] + h * D[0], (y0 - o[1]) * D[2] - h * D[1], D[2]])
    G[2] *= float(np.linalg.norm(tgt.grid[1] - tgt.grid[0]))

    width, height = camera.image
    rows, cols = tgt.grid_shape
    face = h > 0  # the pattern is on the plate's underside (-z), seen from below
    m = QUIET_TILES + RIM_TILES

    def cells(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The lattice cell (column, row) that the rays through pixel positions (u, v) hit.

        Cells beyond the plate are merged into one per side (clipped), so the room is not a lattice.
        """
        w = G[2, 0] * u + G[2, 1] * v + G[2, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            col = np.floor((G[0, 0] * u + G[0, 1] * v + G[0, 2]) / w)
            row = np.floor((G[1, 0] * u + G[1, 1] * v + G[1, 2]) / w)
        miss = ~(w > 0)
        col[miss], row[miss] = np.inf, np.inf
        return np.clip(col, -2 - m, cols + m), np.clip(row, -2 - m, rows + m)

    col, row = cells(np.arange(width + 1)[None] - 0.5, np.arange(height + 1)[:, None] - 0.5)
    scene = _shade(col[:-1, :-1], row[:-1, :-1], cols, rows, face)
    uniform = np.ones((height, width), bool)
    for c in (col, row):
        uniform &= (c[:-1, :-1] == c[1:, :-1]) & (c[:-1, :-1] == c[:-1, 1:]) & (c[:-1, :-1] == c[1:, 1:])
    iy, ix = np.nonzero(~uniform)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    su = np.broadcast_to(ix[:, None, None] + offsets[None, None, :], (len(ix), supersample, supersample))
    sv = np.broadcast_to(iy[:, None, None] + offsets[None, :, None], (len(iy), supersample, supersample))
    scene[iy, ix] = _shade(*cells(su, sv), cols, rows, face).mean(axis=(1, 2))

    image = scene * illumination(width, height, light, rng)
    if blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_px)
    if noise > 0:
        image = image + rng.normal(0.0, noise, image.shape)
    centre_ray = tgt.grid.mean(axis=0) - o
    cos = abs(centre_ray[2]) / np.linalg.norm(centre_ray)
    obliquity = float(np.degrees(np.arccos(min(cos, 1.0))))
    return BoardImage(np.clip(np.rint(image), 0, 255).astype(np.uint8), corners, obliquity)


def _shade(col: np.ndarray, row: np.ndarray, cols: int, rows: int, face: bool) -> np.ndarray:
    """Grey level of lattice cells (tiles -1 .. cols - 1 across): tiles (the corner tiles black), the white
    margin, the plate rim, the room."""
    ring = np.maximum(np.maximum(-1 - col, col + 1 - cols), np.maximum(-1 - row, row + 1 - rows))  # <= 0: a tile
    out = np.where(ring <= QUIET_TILES + RIM_TILES, PLATE, ROOM)
    if not face:
        return out
    with np.errstate(invalid="ignore"):
        black = (col + row) % 2 == 0
    return np.where(ring <= 0, np.where(black, BLACK, WHITE), np.where(ring <= QUIET_TILES, WHITE, out))


def illumination(width: int, height: int, light: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth light field: a linear fall-off in a random direction and vignetting towards the corners."""
    aspect = height / width
    x = np.linspace(-1.0, 1.0, width)[None]
    y = np.linspace(-aspect, aspect, height)[:, None]
    phi = rng.uniform(0.0, 2 * np.pi)
    ramp = 0.5 + 0.5 * (x * np.cos(phi) + y * np.sin(phi)) / np.hypot(1.0, aspect)
    vignette = (x**2 + y**2) / (1.0 + aspect**2)
    return 1.0 - light * (0.5 * ramp + 0.5 * vignette)


# --- detection ----------------------------------------------------------------------------------


def too_large(width: int, height: int) -> str:
    """Why an image of width x height px is not searched for a board (beyond MAX_IMAGE_PX)."""
    return (
        f"an image of {width} x {height} px ({width * height / 1e6:.0f} MP) is more than the board detector searches "
        f"({MAX_IMAGE_PX / 1e6:.0f} MP): a damaged file, or a camera's image to scale down"
    )


def detect_board(
    image: np.ndarray,
    cols: int = 6,
    rows: int = 4,
    predicted: np.ndarray | None = None,
    max_residual_px: float = GRID_RESIDUAL_PX,
) -> BoardDetection:
    """The cols x rows inner corners of a checkerboard in a grey (or BGR) uint8 image, sub-pixel, row-major.

    `predicted` ((rows * cols, 2) px, the kinematic prediction in vertex order; it may be off by tens
    of px) lets the detector look where the board should be, stretched to square-ish tiles, and gives
    the corners their identities. OpenCV's order is only defined up to the board's symmetries: its
    handedness (the NAO's vertex order, seen from below, is the mirror image of OpenCV's usual one)
    is taken from the prediction, and of the two orders a 180-degree turn allows, the one closer to
    the prediction, unless neither is clearly closer ("ambiguous") or both are far off ("far from
    prediction"). Without a prediction the order is normalised to rows running left to right and top
    to bottom as in a frontal view, the top-left-most corner first; which physical vertex is which is
    then not known.

    Other rejections: "not found"; "partial" when only a fragment of the grid (3 x 3 corners or more)
    was found, as for a half-hidden board or one too foreshortened to resolve; "inconsistent" when the
    refined corners stray more than `max_residual_px` (RMS; GRID_RESIDUAL_PX, the simulated cameras' limit) from
    a flat board's homography.
    """
    if cols < 3 or rows < 3:
        raise ValueError("OpenCV's chessboard detectors need at least 3 x 3 inner corners")
    height, width = image.shape[:2]
    if min(height, width) < MIN_IMAGE_PX:
        return BoardDetection(False, None, "not found", f"an image of {width} x {height} px holds no board")
    if height * width > MAX_IMAGE_PX:
        return BoardDetection(False, None, "not found", too_large(width, height))
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    predicted = None if predicted is None else np.asarray(predicted, float)
    seen, inconsistent = 0, None
    for grid, partial in _grids(grey, cols, rows, predicted):
        seen = max(seen, partial)
        if grid is None:
            continue
        corners, residual = _refine(cv2.GaussianBlur(grey, (0, 0), REFINE_BLUR_PX), grid, cols, rows)
        if residual <= max_residual_px:
            detection = identify(corners, cols, rows, predicted)
            detection.residual_px = residual
            return detection
        inconsistent = residual if inconsistent is None else min(inconsistent, residual)
    if inconsistent is not None:
        detail = f"{inconsistent:.2f} px RMS off a flat board's homography"
        return BoardDetection(False, None, "inconsistent", detail, inconsistent)
    if seen:
        return BoardDetection(False, None, "partial", f"{seen} of {rows * cols} corners")
    return BoardDetection(False, None, "not found")


def _grids(
    grey: np.ndarray, cols: int, rows: int, predicted: np.ndarray | None
) -> Iterator[tuple[np.ndarray | None, int]]:
    """Whole grids (rows * cols, 2) px in some row-major order, one detector after the other, each with how
    many corners of a partial grid it saw (0 with a whole grid or none).

    OpenCV's classic detector is fast and finds most boards. The sector-based one finds some of the
    most foreshortened ones too and, allowed a pattern larger than 3 x 3, tells a partly hidden board
    (fewer corners) from none; it does both best on smaller, squarer tiles than the classic one needs.
    The sector-based detector draws at random (from OpenCV's global generator, so its answer would depend on
    what ran before it in the process): it is seeded, and tried with SB_SEEDS seeds until one finds the whole
    grid. OpenCV's classic detector with adaptive thresholds comes last, for views where a grey level's noise
    tipped the others.
    """
    yield _classic(grey, cols, rows, predicted, 0), 0
    if predicted is None:
        yield _find_in_outline(grey, cols, rows), 0
    for tile_px in SB_TILES_PX if predicted is not None else SB_TILES_PX[:1]:  # no prediction: the image as it is
        for seed in range(SB_SEEDS):
            cv2.setRNGSeed(seed)
            yield _sector_based(grey, cols, rows, predicted, tile_px)
    yield _classic(grey, cols, rows, predicted, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE), 0


def _classic(grey: np.ndarray, cols: int, rows: int, predicted: np.ndarray | None, flags: int) -> np.ndarray | None:
    view, back = _view(grey, predicted, cols, rows, CLASSIC_TILE_PX)
    found, corners = cv2.findChessboardCorners(view, (cols, rows), flags=flags)
    return corners.reshape(-1, 2) @ back[:, :2].T + back[:, 2] if found else None


def _sector_based(
    grey: np.ndarray, cols: int, rows: int, predicted: np.ndarray | None, tile_px: tuple[float, float]
) -> tuple[np.ndarray | None, int]:
    view, back = _view(grey, predicted, cols, rows, tile_px)
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(view, (3, 3), cv2.CALIB_CB_LARGER)
    if not found:
        return None, 0
    h, w = meta.shape  # the detected grid: h rows of w corners
    corners = corners.reshape(h, w, 2) @ back[:, :2].T + back[:, 2]
    if (h, w) == (rows, cols):
        return corners.reshape(-1, 2), 0
    if (h, w) == (cols, rows):
        return corners.transpose(1, 0, 2).reshape(-1, 2), 0
    fits = (h <= rows and w <= cols) or (h <= cols and w <= rows)
    return None, h * w if fits else 0


def _find_in_outline(grey: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """The whole grid found in a view rectified by a bright quadrilateral outline (the board's white
    margin), image px, or None. Seen obliquely, the board's tiles are too flat for OpenCV anywhere in
    the raw image; the homography of the margin's four corners undoes the perspective."""
    width, height = (cols + 1 + 2 * QUIET_TILES) * OUTLINE_TILE_PX, (rows + 1 + 2 * QUIET_TILES) * OUTLINE_TILE_PX
    square = np.float32([[0, 0], [width, 0], [width, height], [0, height]])
    for outline in _bright_outlines(grey):
        to_view = cv2.getPerspectiveTransform(outline, square)
        view = cv2.warpPerspective(grey, to_view, (width, height), flags=cv2.INTER_LINEAR)
        found, corners = cv2.findChessboardCorners(view, (cols, rows), flags=0)
        if not found:
            found, corners, _ = cv2.findChessboardCornersSBWithMeta(view, (cols, rows), 0)
        if found:
            return cv2.perspectiveTransform(corners.reshape(-1, 1, 2).astype(float), np.linalg.inv(to_view)).reshape(
                -1, 2
            )
    return None


def _bright_outlines(grey: np.ndarray) -> list[np.ndarray]:
    """Four-sided outlines (4, 2) px of the largest bright regions: above Otsu's cut of the image, and
    above Otsu's cut of those brighter pixels (a white board on a grey plate on a dark floor)."""
    smooth = cv2.GaussianBlur(grey, (5, 5), 0)
    level, _ = cv2.threshold(smooth, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    levels = [level]
    brighter = smooth[smooth > level]
    if brighter.size:
        levels.append(cv2.threshold(brighter.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)[0])
    outlines = []
    for cut in levels:
        _, mask = cv2.threshold(smooth, cut, 255, cv2.THRESH_BINARY)
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        for contour in sorted(contours, key=cv2.contourArea, reverse=True)[:2]:
            if cv2.contourArea(contour) < OUTLINE_MIN_PX2:
                break
            hull = cv2.convexHull(contour)
            for tolerance in (0.02, 0.04, 0.08):  # of the hull's perimeter
                corners = cv2.approxPolyDP(hull, tolerance * cv2.arcLength(hull, True), True)
                if len(corners) == 4:
                    outlines.append(corners.reshape(4, 2).astype(np.float32))
                    break
    return outlines


def _view(
    grey: np.ndarray, predicted: np.ndarray | None, cols: int, rows: int, tile_px: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """The predicted board's neighbourhood warped (affinely) to tiles of tile_px = (least, most) px
    along both grid directions, stretching by at most STRETCH_MAX, with room for the prediction's
    error; and the 2 x 3 map back to image px. The image itself without a prediction or when the
    prediction has no shape (all corners at one point)."""
    identity = np.eye(2, 3)
    if predicted is None:
        return grey, identity
    g = predicted.reshape(rows, cols, 2)
    J = np.stack([(g[:, -1] - g[:, 0]).mean(axis=0) / (cols - 1), (g[-1] - g[0]).mean(axis=0) / (rows - 1)], axis=1)
    predicted_px = np.linalg.norm(J, axis=0)
    if abs(np.linalg.det(J)) <= 1e-3 * predicted_px.max() ** 2:
        return grey, identity
    wanted_px = np.minimum(np.clip(predicted_px, *tile_px), STRETCH_MAX * predicted_px)
    W = np.diag(wanted_px) @ np.linalg.inv(J)
    half = wanted_px * (np.array([cols, rows]) + 1 + 2 * QUIET_TILES) / 2 + FAR_PX * np.linalg.norm(W, axis=1)
    half = np.minimum(half, VIEW_MAX_PX / 2)
    A = np.hstack([W, (half - W @ predicted.mean(axis=0))[:, None]])
    size = (int(np.ceil(2 * half[0])), int(np.ceil(2 * half[1])))
    view = cv2.warpAffine(grey, A, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return view, cv2.invertAffineTransform(A)


def _refine(grey: np.ndarray, grid: np.ndarray, cols: int, rows: int) -> tuple[np.ndarray, float]:
    """The whole grid's corners refined on the board (`refine_on_board`)."""
    lattice = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), axis=-1).reshape(-1, 2).astype(float)
    return refine_on_board(grey, grid, lattice)


def refine_on_board(
    grey: np.ndarray, corners: np.ndarray, lattice: np.ndarray, half_window_px: int | None = None
) -> tuple[np.ndarray, float]:
    """Sub-pixel corners (K, 2) px, refined in the image rectified by the homography of their places on a flat
    board (`lattice` (K, 2): column and row, in tiles), and the RMS distance (px) of the refined corners from
    the best homography through them.

    In the raw image a foreshortened tile is a few px tall, so a corner window would hold the
    neighbouring corners' edges; rectified, the tiles are REFINE_TILE_PX squares, and the window
    (`half_window_px`, default nearly half a tile) holds just the corner's own two edges."""
    H, _ = cv2.findHomography(lattice, corners, 0)
    t = REFINE_TILE_PX
    half = t // 2 - 1 if half_window_px is None else half_window_px
    to_image = H @ np.array([[1 / t, 0, -1], [0, 1 / t, -1], [0, 0, 1]])  # rectified px -> image px
    size = tuple(int(n) for n in (lattice.max(axis=0) + 2) * t)
    rectified = cv2.warpPerspective(grey, to_image, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    start = ((lattice + 1) * t).astype(np.float32).reshape(-1, 1, 2)
    refined = cv2.cornerSubPix(rectified, start, (half, half), (-1, -1), _SUBPIX)
    out = cv2.perspectiveTransform(refined.astype(float), to_image).reshape(-1, 2)
    H2, _ = cv2.findHomography(lattice, out, 0)
    fitted = cv2.perspectiveTransform(lattice.reshape(-1, 1, 2), H2).reshape(-1, 2)
    return out, float(np.sqrt(((fitted - out) ** 2).sum(axis=1).mean()))


def identify(corners: np.ndarray, cols: int, rows: int, predicted: np.ndarray | None) -> BoardDetection:
    """Put the corners (rows * cols, 2) px of a grid in some row-major order into vertex order (see
    detect_board); a square grid may also be turned by 90 degrees."""

    def handedness(c: np.ndarray) -> float:
        a, b = c[cols - 1] - c[0], c[-cols] - c[0]
        return float(np.sign(a[0] * b[1] - a[1] * b[0]))

    def mirrored(c: np.ndarray) -> np.ndarray:
        return c.reshape(rows, cols, 2)[:, ::-1].reshape(-1, 2)

    if predicted is None:
        if handedness(corners) < 0:
            corners = mirrored(corners)
        if corners[-1].sum() < corners[0].sum():
            corners = corners[::-1]
        return BoardDetection(True, corners, "ok")
    if handedness(corners) * handedness(predicted) < 0:
        corners = mirrored(corners)
    if rows == cols:
        orders = [np.rot90(corners.reshape(rows, cols, 2), k).reshape(-1, 2) for k in range(4)]
    else:
        orders = [corners, corners[::-1]]
    distances = [float(np.linalg.norm(c - predicted, axis=1).mean()) for c in orders]
    best, second = np.argsort(distances)[:2]
    near, other = distances[best], distances[second]
    detail = f"mean distance to the prediction {near:.1f} px (the other order {other:.1f} px)"
    if near > FAR_PX:
        return BoardDetection(False, None, "far from prediction", detail)
    if near > AMBIGUOUS_RATIO * other:
        return BoardDetection(False, None, "ambiguous", detail)
    return BoardDetection(True, orders[best], "ok", detail)
