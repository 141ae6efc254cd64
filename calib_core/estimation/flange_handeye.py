"""Hand-eye from recorded flange poses (specs handeye-poses.md): images of a board, each with the flange's pose
in the base as the controller reported it; no URDF, no joint angles, no pose guessed.

Eye-in-hand: F_i X C_i = Z (F_i the flange in the base, reported; X the camera in the flange; C_i the board in
the camera, from image i; Z the board in the base). Eye-to-hand: X C_i = F_i Z (X the camera in the base, Z the
board in the flange). Both read A_i X = Z B_i with B_i = C_i^-1 and A_i = F_i or F_i^-1, so the closed forms of
`handeye` start them (each image's C_i by PnP), and image i's corners are predicted at C_i = X^-1 A_i^-1 Z.

Then the reprojection bundle adjustment: X and Z (with `intrinsics_free` also the camera's fx, fy, cx, cy, k1, k2,
p1, p2, k3, started at its file) minimise the corners' pixel distances over the images used, by the desk's
Levenberg-Marquardt with exact derivatives: the pinhole's, chained through the poses' rotation vectors (their
right Jacobians). A controller's pose is not exact: each image's reported flange pose has an error of its own,
fitted with a standard deviation that, like the corners', the data give (variance components), so that the
corners are not asked to absorb it and the standard deviations (Gauss-Newton, at those weights) stay honest.
Whether that model or the reported poses taken as exact predicts an image better from its reported pose is asked
of the images themselves (k-fold cross-validation on the images fitted; the poses' errors are fitted only where they
predict better by more than the comparison's standard error): on real data the poses' disagreement
with the images is not always a controller's independent error (a camera model that is off, errors that follow
the arm's configuration), and then the corners' pixels judge X and Z better (benchmarks/README.md). Either way
the noise reported is the variance components', and the standard deviations are those of that noise.

A chessboard's corners come in an order fixed only up to a half turn: each image's is the one the poses agree
with (`_consistent_orders`), before anything is fitted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..io.flange_poses import BoardSpec, Camera, natural_key
from ..sensors.pinhole import Pinhole
from .handeye import hand_eye_candidates, inverse, pose
from .solver import levenberg_marquardt

SETUPS = ("eye-in-hand", "eye-to-hand")
MIN_IMAGES = 3  # fitted images at least: fewer leave the hand-eye equations undetermined
# A real camera's chessboard corners lie up to about 0.8 px (RMS) off a flat board's homography even with the lens
# model undone (the ViSP sample: 0.33-0.82 px; a printed board is not quite flat, a lens not quite its model): the
# simulated cameras' 0.3 px limit would refuse them. A false grid is off by several px.
REAL_GRID_RESIDUAL_PX = 1.5
FLANGE_DOUBT_MM, FLANGE_DOUBT_DEG = 5.0, 2.0  # reported poses this far off the images: a convention is wrong
_N_INTRINSICS = 9  # fx, fy, cx, cy, k1, k2, p1, p2, k3
# The cross-validation that chooses whether the reported poses' errors are fitted (_cross_validate): leave one out
# up to this many images. The variance components need their images: ViSP's sample with 5 of its 7 fitted images
# finds a flange rotation error ten times the 7's, and fewer folds judged the poses' errors on such fits.
CV_FOLDS = 10


@dataclass
class View:
    """One image's board: the corners found (K, 2) px and which of the board's points they are, or why not."""

    image: str
    corners: np.ndarray | None
    ids: np.ndarray | None
    reason: str = ""


@dataclass
class FlangeCalibration:
    setup: str
    X: np.ndarray  # (4, 4) m: the camera in the flange (eye-in-hand) or in the base (eye-to-hand)
    Z: np.ndarray  # (4, 4) m: the board in the base (eye-in-hand) or in the flange (eye-to-hand)
    X_std: np.ndarray  # (6,) x, y, z (m), rx, ry, rz (rad, about X's own axes)
    Z_std: np.ndarray
    camera: Camera
    images: list[dict] = field(default_factory=list)  # per image: image, used, heldout, found, rms_px, reason
    heldout_rms_px: float | None = None
    fitted_rms_px: float = 0.0
    iterations: int = 0
    start: str = ""  # the closed form that started it
    noise: dict = field(default_factory=dict)  # what the data show: corner_px, flange_mm, flange_deg
    # the reported poses' errors: fitted (bool), chosen_by, cross_validation_px (fitted, exact, folds) or None
    flange_errors: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """The pinned output (specs handeye-poses.md), lengths in mm, standard deviations' angles in deg."""
        names = (
            ("camera_in_flange", "board_in_base")
            if self.setup == "eye-in-hand"
            else ("camera_in_base", "board_in_flange")
        )
        out: dict = {"setup": self.setup}
        for name, T, std in ((names[0], self.X, self.X_std), (names[1], self.Z, self.Z_std)):
            M = T.copy()
            M[:3, 3] *= 1000.0
            sd = {k: float(v) * 1000.0 for k, v in zip("xyz", std[:3], strict=True)}
            sd |= {f"r{k}": math.degrees(float(v)) for k, v in zip("xyz", std[3:], strict=True)}
            out[name] = {"matrix": M.tolist(), "unit": "mm", "std": sd}
        out["camera"] = {"camera_matrix": self.camera.matrix.tolist(), "distortion": self.camera.distortion.tolist()}
        out["images"] = self.images
        held = [i["image"] for i in self.images if i["heldout"]]
        out["heldout"] = {"images": held, "rms_px": self.heldout_rms_px}
        out["fitted_rms_px"] = self.fitted_rms_px
        out["noise"] = self.noise
        out["flange_errors"] = self.flange_errors
        out["start"] = self.start
        out["warnings"] = self.warnings
        return out

    @property
    def warnings(self) -> list[str]:
        """What to check before using it: reported poses far off what the images show."""
        mm, deg = self.noise.get("flange_mm", 0.0), self.noise.get("flange_deg", 0.0)
        if mm <= FLANGE_DOUBT_MM and deg <= FLANGE_DOUBT_DEG:
            return []
        return [
            f"the reported flange poses disagree with the images by {mm:.3g} mm and {deg:.3g} deg an image (a "
            "controller's are off by a fraction of that): check that they are the flange in the base (not the base "
            "in the flange), their units (--length-unit, --angle-unit) and which image each belongs to"
        ]


def find_views(images: dict[str, np.ndarray], board: BoardSpec, camera: Camera) -> dict[str, View]:
    """Each grey image's board corners (px of the image as taken): a chessboard's by the desk's detector on the
    image with the lens distortion undone (sub-pixel, checked against a flat board's homography within
    REAL_GRID_RESIDUAL_PX), a ChArUco board's by OpenCV's CharucoDetector (its corners' ids), the markers it missed
    looked for again where the board's layout puts them."""
    out = {}
    if board.kind == "chessboard":
        import cv2

        from ..vision import detect_board

        distorted = bool(np.any(camera.distortion))
        for name, grey in images.items():
            flat = cv2.undistort(grey, camera.matrix, camera.distortion) if distorted else grey
            found = detect_board(flat, board.cols, board.rows, max_residual_px=REAL_GRID_RESIDUAL_PX)
            if found.found and found.corners is not None:
                corners = np.asarray(found.corners, float)
                if distorted:  # back to the image as taken: through the lens model
                    rays = np.column_stack([corners, np.ones(len(corners))]) @ np.linalg.inv(camera.matrix).T
                    uv, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), camera.matrix, camera.distortion)
                    corners = uv.reshape(-1, 2)
                out[name] = View(name, corners, np.arange(board.cols * board.rows))
            else:
                out[name] = View(name, None, None, found.reason + (f": {found.detail}" if found.detail else ""))
        return out
    import cv2

    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, f"DICT_{board.dictionary}"))
    cv_board = cv2.aruco.CharucoBoard((board.cols, board.rows), board.square_m, board.marker_m, dictionary)
    # The markers missed at first looked for again where the board's layout puts them: on real images a board
    # seen at a slant or in uneven light loses most of its markers otherwise (sample_sessions/handeye-rosi-charuco:
    # 4 of 24 corners in one image, 8 in another, all 24 with the layout's help).
    settings = cv2.aruco.CharucoParameters()
    settings.tryRefineMarkers = True
    detector = cv2.aruco.CharucoDetector(cv_board, settings)
    for name, grey in images.items():
        corners, ids, _, _ = detector.detectBoard(grey)
        if ids is None or len(ids) < 6:
            out[name] = View(name, None, None, f"not found ({0 if ids is None else len(ids)} ChArUco corners)")
        else:
            out[name] = View(name, corners.reshape(-1, 2).astype(float), ids.ravel().astype(int))
    return out


class _Model:
    """Every corner of the images used, predicted with its exact Jacobian, and each image's flange-pose error.

    theta: X's rotation vector and translation, Z's, the intrinsics when free, then per image used the error of
    its reported flange pose (a rotation vector and a translation in the flange's frame: F_i' = F_i E_i). The
    residuals are the corners' pixel errors over `sigma_px` and the pose errors over their own standard deviations
    (`sigma_rad`, `sigma_m`): the reported pose is a measurement, so that its error is fitted as a pose error and
    not spread over the image's corners."""

    def __init__(
        self, setup: str, views: list[View], poses: list[np.ndarray], points: np.ndarray, camera: Camera, free: bool
    ):
        self.setup, self.views, self.points, self.free = setup, views, points, free
        self.F = np.array(poses)
        self.camera = camera
        self.sensor = Pinhole(
            name="camera", frame=0, unit="px", noise={"sigma": 1.0}, intrinsics=(0, 1, 2, 3), image=camera.size,
            R_frame_optical=np.eye(3), range=None, distortion=(4, 5, 6, 7, 8),
        )  # fmt: skip
        self.measured = np.concatenate([v.corners for v in views]).ravel()
        self.n_pose = 12 + (_N_INTRINSICS if free else 0)  # theta's entries before the images' pose errors
        self.sigma_px, self.sigma_rad, self.sigma_m = 0.5, math.radians(0.01), 1e-4
        self.errors = True  # the flange poses' errors fitted (False: the reported poses taken as exact)
        self.iterations = 0

    def intrinsics(self, theta: np.ndarray) -> np.ndarray:
        return theta[12 : self.n_pose] if self.free else _intr(self.camera)

    def image_rows(self, v: View, F: np.ndarray, theta: np.ndarray, error: np.ndarray | None, jacobian: bool):
        """Image v's pixels (n, 2) with its flange at F (its error E = (Exp(w), t) applied when given), and with
        `jacobian` d(pixels)/d(X, Z, intrinsics) (n, 2, n_pose) and d/d(error) (n, 2, 6)."""
        return self.corners([v.ids], F[None], None if error is None else error[None], theta, jacobian)[:3]

    def corners(
        self, ids: list[np.ndarray], F: np.ndarray, errors: np.ndarray | None, theta: np.ndarray, jacobian: bool
    ):
        """`image_rows` of m images at once, their corners one after the other: image i's corners `ids[i]` with
        its flange at F[i] (m, 4, 4), its error errors[i] (m, 6) applied when given; and each corner's image."""
        img = np.repeat(np.arange(len(ids)), [len(i) for i in ids])
        Rx, tx, Rz, tz = _rot(theta[0:3]), theta[3:6], _rot(theta[6:9]), theta[9:12]
        P = self.points[np.concatenate(ids)]
        y = P @ Rz.T + tz  # in the frame Z is given in
        w_e = np.zeros((len(ids), 3)) if errors is None else errors[:, :3]
        RE, tE = _rot(w_e), (np.zeros((len(ids), 3)) if errors is None else errors[:, 3:])
        RF, tF = F[:, :3, :3], F[:, :3, 3]
        if self.setup == "eye-in-hand":  # the corners in the flange: E^-1 F^-1 y
            u = np.einsum("nij,ni->nj", RF[img], y - tF[img])  # F^-1 y
            w = np.einsum("nij,ni->nj", RE[img], u - tE[img])
            L = RE.transpose(0, 2, 1) @ RF.transpose(0, 2, 1)  # d(w)/d(y)
        else:  # in the base: F E y
            u = np.einsum("nji,ni->nj", RE[img], y) + tE[img]
            w = np.einsum("nji,ni->nj", RF[img], u) + tF[img]
            L = RF @ RE
        x = (w - tx) @ Rx  # R_x^T (w - t_x)
        h, dh_dx, dh_dint = self.sensor.predict(self.intrinsics(theta), x, derivatives=jacobian)
        if not jacobian:
            return h, None, None, img
        n = len(P)
        D = np.zeros((n, 3, 12))
        D[:, :, 0:3] = _skew(x) @ _right_jacobian(theta[0:3])
        D[:, :, 3:6] = -Rx.T
        RxL = Rx.T @ L
        D[:, :, 6:9] = -(RxL @ Rz)[img] @ _skew(P) @ _right_jacobian(theta[6:9])
        D[:, :, 9:12] = RxL[img]
        Jp = dh_dx @ D
        if self.free:
            Jp = np.concatenate([Jp, dh_dint], axis=2)
        DE = np.zeros((n, 3, 6))
        Jr = _right_jacobian(w_e)[img]
        if self.setup == "eye-in-hand":
            DE[:, :, 0:3] = Rx.T @ _skew(w) @ Jr
            DE[:, :, 3:6] = (-Rx.T @ RE.transpose(0, 2, 1))[img]
        else:
            DE[:, :, 0:3] = -(Rx.T @ RF @ RE)[img] @ _skew(y) @ Jr
            DE[:, :, 3:6] = (Rx.T @ RF)[img]
        return h, Jp, dh_dx @ DE, img

    def residuals_jacobian(self, theta: np.ndarray, jacobian: bool = True):
        n_img = len(self.views)
        errors = theta[self.n_pose :].reshape(n_img, 6) if self.errors else None
        h, Jp, JE, img = self.corners([v.ids for v in self.views], self.F, errors, theta, jacobian)
        r = (h.ravel() - self.measured) / self.sigma_px
        if self.errors:
            scale = np.array([self.sigma_rad] * 3 + [self.sigma_m] * 3)
            r = np.concatenate([r, (errors / scale).ravel()])
        if not jacobian:
            return r, None
        n_rows = len(self.measured)
        J = np.zeros((len(r), len(theta)))
        J[:n_rows, : self.n_pose] = Jp.reshape(n_rows, -1) / self.sigma_px
        if self.errors:  # each corner's rows on its own image's error
            columns = self.n_pose + 6 * np.repeat(img, 2)[:, None] + np.arange(6)
            J[np.arange(n_rows)[:, None], columns] = JE.reshape(n_rows, 6) / self.sigma_px
            J[n_rows:, self.n_pose :] = np.diag(np.tile(1.0 / scale, n_img))
        return r, J

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        return self.residuals_jacobian(theta, jacobian=False)[0]

    def settle_noise(self, theta: np.ndarray, passes: int = 6) -> np.ndarray:
        """The corners' and the flange poses' noise estimated with the fit (variance components, Helmert: each
        group's weighted sum of squares over its redundancy), refitted until they settle."""
        n_c = len(self.measured)
        n_img = len(self.views)
        for _ in range(passes):
            theta = self.solve(theta)
            if not self.errors:
                return theta
            r, J = self.residuals_jacobian(theta)
            Q, _ = np.linalg.qr(J)
            redundancy = 1.0 - np.sum(Q**2, axis=1)
            rot = np.zeros(len(r), bool)
            rot[n_c:] = np.tile([True] * 3 + [False] * 3, n_img)
            tra = np.zeros(len(r), bool)
            tra[n_c:] = ~rot[n_c:]
            old = (self.sigma_px, self.sigma_rad, self.sigma_m)
            factors = []
            for rows in (slice(0, n_c), rot, tra):
                factors.append(math.sqrt(float(np.sum(r[rows] ** 2)) / max(float(np.sum(redundancy[rows])), 1e-9)))
            self.sigma_px = max(old[0] * factors[0], 1e-3)
            self.sigma_rad = max(old[1] * factors[1], 1e-7)
            self.sigma_m = max(old[2] * factors[2], 1e-7)
            if max(abs(math.log(f)) for f in factors) < 0.02:
                break
        return self.solve(theta)

    def noise(self) -> dict:
        """What the variance components found: the corners' px, the reported poses' mm and deg."""
        return {
            "corner_px": self.sigma_px,
            "flange_mm": 1000 * self.sigma_m,
            "flange_deg": math.degrees(self.sigma_rad),
        }

    def solve(self, theta: np.ndarray) -> np.ndarray:
        result = levenberg_marquardt(self.residuals_jacobian, theta, fun=self.residuals)
        self.iterations += result.iterations
        return result.x


def calibrate_flange(
    views: dict[str, View],
    poses: dict[str, np.ndarray],
    camera: Camera,
    board: BoardSpec,
    setup: str,
    *,
    heldout: set[str] | None = None,
    intrinsics_free: bool = False,
    pose_errors: bool | None = None,
) -> FlangeCalibration:
    """X and Z from the images with a board found and a pose, less `heldout` (never fitted, their error given).
    A chessboard view's corners are put in the order the poses agree with, in place.

    `pose_errors` None: the reported poses' errors fitted (variance components) or the poses taken as exact,
    whichever predicts the images better from their reported poses in a k-fold cross-validation on the images
    fitted (`_cross_validate`; the poses as exact unless fitting their errors wins by more than a standard error);
    on real data a controller's pose errors are not always what the model says (a
    camera model that is off, errors that follow the arm's configuration), and the corners' pixels are then the
    better judge. The noise reported is the variance components' either way, and the standard deviations of the
    poses taken as exact are those of that noise (`_sandwich`). True or False forces it (False: a plain
    reprojection bundle adjustment's X and Z, the benchmark's baseline)."""
    if setup not in SETUPS:
        raise InputError(f"--setup {setup!r}: expected eye-in-hand or eye-to-hand")
    heldout = heldout or set()
    points = board.points()
    names = sorted(views, key=natural_key)
    used = [n for n in names if views[n].corners is not None and n in poses and n not in heldout]
    if len(used) < MIN_IMAGES:
        raise InputError(
            f"{len(used)} images with the board found, a pose and not held out: a hand-eye calibration needs "
            f"{MIN_IMAGES} at least"
        )
    fit = [views[n] for n in used]
    F = [poses[n] for n in used]
    if board.kind == "chessboard":
        _consistent_orders(fit, np.array(F) if setup == "eye-in-hand" else inverse(np.array(F)), points, camera)
    theta0, start = _start(setup, fit, F, points, camera)
    choice = {"fitted": pose_errors, "chosen_by": "asked", "cross_validation_px": None}
    if pose_errors is None:
        cv = _cross_validate(setup, fit, F, points, camera, intrinsics_free)
        choice["cross_validation_px"] = cv
        choice["fitted"] = cv is None or cv["fit_errors"]
        choice["chosen_by"] = "too few images to cross-validate" if cv is None else "cross-validation"
    desk = _fit(setup, fit, F, points, camera, intrinsics_free, True, theta0)
    if choice["fitted"]:
        model, theta = desk
        r, J = model.residuals_jacobian(theta)
        cov = np.linalg.pinv(J.T @ J)  # the weights are the noise the data show (variance components)
    else:  # the corners' pixels with the noise the variance components found: the reported poses' error too
        model, theta = _fit(setup, fit, F, points, camera, intrinsics_free, False, theta0)
        r, _ = model.residuals_jacobian(theta, jacobian=False)
        cov = _sandwich(model, theta, desk[0])
    X, Z = pose(_rot(theta[0:3]), theta[3:6]), pose(_rot(theta[6:9]), theta[9:12])
    X_std, Z_std = _pose_std(cov[:6, :6], theta[0:3]), _pose_std(cov[6:12, 6:12], theta[6:9])
    intr = model.intrinsics(theta)
    cam = Camera(np.array([[intr[0], 0, intr[2]], [0, intr[1], intr[3]], [0, 0, 1.0]]), intr[4:].copy(), camera.size)
    images, held_sq, held_n = [], 0.0, 0
    for n in names:
        v = views[n]
        entry = {"image": n, "used": n in used, "heldout": n in heldout, "found": v.corners is not None, "rms_px": None}
        if v.corners is None:
            entry["reason"] = v.reason
        elif n not in poses:
            entry["reason"] = "no pose for it"
        else:
            # A fitted image with its pose's error fitted; a held-out one at the pose as reported.
            k = used.index(n) if n in used else None
            error = None if k is None or not model.errors else theta[model.n_pose + 6 * k : model.n_pose + 6 * k + 6]
            pred = model.image_rows(v, poses[n], theta, error, jacobian=False)[0]
            turned = board.kind == "chessboard" and k is None  # an image not fitted: its corners in the fit's order
            if turned and np.sum((pred - v.corners[::-1]) ** 2) < np.sum((pred - v.corners) ** 2):
                v.corners = v.corners[::-1].copy()
            sq = np.sum((pred - v.corners) ** 2, axis=1)
            entry["rms_px"] = float(np.sqrt(sq.mean()))
            if n in heldout:
                held_sq, held_n = held_sq + float(sq.sum()), held_n + len(sq)
        images.append(entry)
    corners = r[: len(model.measured)] * model.sigma_px
    return FlangeCalibration(
        setup,
        X,
        Z,
        X_std,
        Z_std,
        cam,
        images,
        math.sqrt(held_sq / held_n) if held_n else None,
        math.sqrt(float(corners @ corners) / (len(corners) / 2)),
        model.iterations,
        start,
        desk[0].noise(),
        choice,
    )


def _fit(
    setup: str,
    views: list[View],
    poses: list[np.ndarray],
    points: np.ndarray,
    camera: Camera,
    free: bool,
    errors: bool,
    theta0: np.ndarray,
) -> tuple[_Model, np.ndarray]:
    """The bundle adjustment from the closed form's theta0: the reported poses' errors fitted with the noise the
    data show (`errors`), or the poses taken as exact."""
    model = _Model(setup, views, poses, points, camera, free)
    model.errors = errors
    theta = np.concatenate([theta0, _intr(camera) if free else [], np.zeros(6 * len(views) * errors)])
    return model, model.settle_noise(theta)


def _cross_validate(
    setup: str, views: list[View], poses: list[np.ndarray], points: np.ndarray, camera: Camera, free: bool
) -> dict | None:
    """The RMS px of each image's corners predicted from its reported pose by a fit of the other folds' images,
    with the poses' errors fitted and with the poses taken as exact: the images in natural order dealt into
    CV_FOLDS folds (one image each when there are fewer images). None when a fold's fit would have fewer than
    MIN_IMAGES images."""
    n = len(views)
    folds = min(CV_FOLDS, n)
    if n - math.ceil(n / folds) < MIN_IMAGES:
        return None
    sq = {True: np.zeros(n), False: np.zeros(n)}  # each image's squared corner distances, summed
    for j in range(folds):
        train = [i for i in range(n) if i % folds != j]
        tv, tp = [views[i] for i in train], [poses[i] for i in train]
        theta0, _ = _start(setup, tv, tp, points, camera)
        for errors in (True, False):
            model, theta = _fit(setup, tv, tp, points, camera, free, errors, theta0)
            for i in range(j, n, folds):
                pred = model.image_rows(views[i], poses[i], theta, None, jacobian=False)[0]
                sq[errors][i] = float(np.sum((pred - views[i].corners) ** 2))
    count = sum(len(v.corners) for v in views)
    corners = np.array([len(v.corners) for v in views], float)
    gain = (sq[False] - sq[True]) / corners  # per image: how much lower its mean squared distance is when fitted
    return {
        "fitted": math.sqrt(sq[True].sum() / count),
        "exact": math.sqrt(sq[False].sum() / count),
        "folds": folds,
        # The poses' errors fitted only where they predict better by more than the comparison's own standard
        # error (the one-standard-error rule): with a few images the better of two close figures is chance, and
        # the plain model is the one to keep then.
        "fit_errors": bool(gain.mean() > gain.std(ddof=1) / math.sqrt(n)),
    }


def _sandwich(plain: _Model, theta: np.ndarray, desk: _Model) -> np.ndarray:
    """The covariance of the poses-as-exact fit's theta when the corners' noise is what the variance components
    found (`desk`): each image's pixels move together with its reported pose's error, (J'J)^-1 J' S J (J'J)^-1."""
    sigma_e = np.array([desk.sigma_rad] * 3 + [desk.sigma_m] * 3)
    A = np.zeros((len(theta), len(theta)))
    B = np.zeros_like(A)
    for v, F in zip(plain.views, plain.F, strict=True):
        _, Jp, JE = plain.image_rows(v, F, theta, np.zeros(6), jacobian=True)
        Jp, JE = Jp.reshape(-1, len(theta)), JE.reshape(-1, 6)
        G = Jp.T @ JE
        A += Jp.T @ Jp
        B += desk.sigma_px**2 * (Jp.T @ Jp) + (G * sigma_e**2) @ G.T
    Ai = np.linalg.pinv(A)
    return Ai @ B @ Ai


def _intr(camera: Camera) -> np.ndarray:
    K = camera.matrix
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *camera.distortion])


def _start(
    setup: str, views: list[View], poses: list[np.ndarray], points: np.ndarray, camera: Camera
) -> tuple[np.ndarray, str]:
    """The closed-form start (theta: rotation vector and translation of X, then of Z) that predicts the corners
    best (each chessboard image's corners already in the order the poses agree with, `_consistent_orders`)."""
    A = np.array(poses) if setup == "eye-in-hand" else inverse(np.array(poses))
    C = np.array([_board_in_camera(v, points, camera) for v in views])
    model = _Model(setup, views, poses, points, camera, False)
    model.errors = False
    best = None
    for label, X, Z in hand_eye_candidates(A, inverse(C)):
        theta = np.concatenate([_rotvec(X[:3, :3]), X[:3, 3], _rotvec(Z[:3, :3]), Z[:3, 3]])
        cost = float(np.sum(model.residuals(theta) ** 2))
        if best is None or cost < best[0]:
            best = (cost, theta, label)
    assert best is not None
    return best[1], best[2]


def _consistent_orders(views: list[View], A: np.ndarray, points: np.ndarray, camera: Camera) -> None:
    """A chessboard's corners are found in an order fixed only up to a half turn of the board. Whatever X and Z
    are, A_i X = Z B_i makes the motion between two images turn by the same angle for the robot (A_j^-1 A_i) and
    for the board (B_j^-1 B_i): each image takes the order whose motions to the images before it agree best."""
    turn = np.diag([-1.0, -1.0, 1.0, 1.0])  # the board turned half about its normal through its centre
    centre = points.mean(axis=0)
    flip = pose(np.eye(3), centre) @ turn @ pose(np.eye(3), -centre)
    B = [inverse(_board_in_camera(views[0], points, camera))]
    for i, v in enumerate(views[1:], start=1):
        C = _board_in_camera(v, points, camera)
        options = (C, C @ flip)  # the reversed order's pose is the same board pose turned half
        disagreement = []
        for Ci in options:
            Bi = inverse(Ci)
            disagreement.append(sum(abs(_angle(inverse(A[j]) @ A[i]) - _angle(inverse(B[j]) @ Bi)) for j in range(i)))
        if disagreement[1] < disagreement[0]:
            v.corners = v.corners[::-1].copy()
            C = options[1]
        B.append(inverse(C))


def _angle(T: np.ndarray) -> float:
    """The rotation angle of a rigid transform, rad."""
    return float(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))


def _board_in_camera(v: View, points: np.ndarray, camera: Camera) -> np.ndarray:
    import cv2

    ok, rvec, tvec = cv2.solvePnP(
        points[v.ids].astype(np.float64), v.corners.astype(np.float64), camera.matrix, camera.distortion,
        flags=cv2.SOLVEPNP_IPPE,
    )  # fmt: skip
    if not ok:
        raise InputError(f"{v.image}: the board's pose cannot be found from its corners")
    return pose(cv2.Rodrigues(rvec)[0], tvec.ravel())


def _pose_std(cov: np.ndarray, r: np.ndarray) -> np.ndarray:
    """x, y, z and the rotation's rx, ry, rz standard deviations (about the pose's own axes) from the covariance
    of (rotation vector, translation)."""
    Jr = _right_jacobian(r)
    rot = Jr @ cov[:3, :3] @ Jr.T
    return np.sqrt(np.maximum(np.concatenate([np.diag(cov[3:, 3:]), np.diag(rot)]), 0.0))


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]x of vectors (..., 3)."""
    v = np.asarray(v, float)
    S = np.zeros((*v.shape[:-1], 3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def _rot(r: np.ndarray) -> np.ndarray:
    """The rotations (..., 3, 3) of rotation vectors (..., 3) (Rodrigues)."""
    r = np.asarray(r, float)
    angle = np.linalg.norm(r, axis=-1)[..., None, None]
    K = _skew(r)
    small = angle < 1e-12
    a = np.where(small, 1.0, angle)
    return np.eye(3) + np.where(small, 1.0, np.sin(a) / a) * K + np.where(small, 0.0, (1 - np.cos(a)) / a**2) * (K @ K)


def _rotvec(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def _right_jacobian(r: np.ndarray) -> np.ndarray:
    """J_r(r) (..., 3, 3) of rotation vectors (..., 3): Exp(r + dr) = Exp(r) Exp(J_r(r) dr) to first order."""
    r = np.asarray(r, float)
    angle = np.linalg.norm(r, axis=-1)[..., None, None]
    K = _skew(r)
    small = angle < 1e-6
    a = np.where(small, 1.0, angle)
    first = np.where(small, 0.5, (1 - np.cos(a)) / a**2)
    second = np.where(small, 1.0 / 6.0, (a - np.sin(a)) / a**3)
    return np.eye(3) - first * K + second * (K @ K)
