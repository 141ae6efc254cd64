"""Where a camera and its board stand when the profile does not say: the start of a hand-eye calibration.

A camera (eye-in-hand: on the flange; eye-to-hand: in the room) or the board it sees (on the table, on the
flange) hangs from a `registration: true` frame, a pose nobody measured. From the data alone:

1. per image, the board's pose in the camera (`handeye.board_poses`: PnP on the measured pixels and the
   board's points; two for a planar board, the second its flip);
2. the kinematics of the current model close the loop camera - robot - board: with S_i the pose of the
   camera's registration frame's parent and B_i that of the board's, X the camera's registration and Z the
   board's, the camera sees the board at C_i with S_i X C_i = B_i Z, that is A_i Z = X C_i for
   A_i = S_i^-1 B_i, the robot-world/hand-eye equation (`handeye`); one unknown pose is a mean;
3. each closed form (Shah's, Park and Martin's on either pose), and each again with the images whose PnP flip
   agrees better with it flipped, is refined by least squares on the registrations alone with the model as
   it is, and the candidates come out best first (`CameraStart`).

Step 3's best is the registration `register` gives; the others are further starts for a calibration that
stays far above the noise (`calibrate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.kinematics import forward
from ..model.profile import Profile
from ..sensors.pinhole import Pinhole
from .handeye import (
    board_poses,
    hand_eye_candidates,
    inverse,
    mean_pose,
    pose,
    rotation_spread_deg,
    zyx_angles,
)
from .problem import Problem, local_points
from .solver import levenberg_marquardt

MIN_TURN_SPREAD_DEG = 5.0  # the motions' rotation axes must differ this much for both poses to be found
REFINE_ITERATIONS = 30  # of each candidate's refinement on the registrations alone
SAME_CANDIDATE = (1.0, np.radians(0.1))  # length unit, rad: candidates this close are refined once
SHOWN_FRAMES = 10


@dataclass(frozen=True)
class CameraStart:
    """A start for the registrations of a camera and its board: how it was made, the parameters, and the
    least-squares cost of the registrations refined with everything else held."""

    label: str
    p: np.ndarray
    cost: float


def registration_frame(profile: Profile, frame: int) -> int | None:
    """The registration frame on the chain from the base to `frame` nearest to it, or None."""
    chain = [f for f in profile.chain(frame) if profile.frames[f].registration]
    return chain[-1] if chain else None


def is_camera(profile: Profile, sensor: int) -> bool:
    """Whether a sensor measures pixels through a lens whose rays can be traced back (a pinhole camera)."""
    return isinstance(profile.sensors[sensor], Pinhole)


def camera_starts(profile: Profile, data: Dataset, p: np.ndarray) -> list[CameraStart]:
    """Starts for the registrations of the camera whose observations `data` are (one sensor) and of the boards
    it sees, from `p` (every other parameter as it is): best (lowest refined cost) first. InputError when the
    images cannot fix them (no board pose in any image, too few images, motions about one axis)."""
    (s,) = data.sensors
    camera = registration_frame(profile, profile.sensors[s].frame)
    targets = sorted(np.unique(data.target).tolist(), key=lambda t: -len(np.unique(data.cfg[data.target == t])))
    candidates: list[tuple[str, np.ndarray]] = [("", p.copy())]
    solved: set[int] = set()  # registration frames solved so far
    for t in targets:
        board = registration_frame(profile, profile.targets[t].frame)
        unknown = [f for f in (camera, board) if f is not None and f not in solved]
        if not unknown:
            continue
        loop = _Loop(profile, data, s, t, *(f if f in unknown else None for f in (camera, board)))
        candidates = [(label or new, q2) for label, q in candidates for new, q2 in loop.solutions(q)]
        solved.update(unknown)
    params = [op.param for f in sorted(solved) for op in profile.frames[f].ops]
    return _refined(profile, data, params, candidates)


def view_registration(profile: Profile, data: Dataset, p: np.ndarray, frame: int) -> np.ndarray:
    """p with the one registration `frame` (the camera's or its board's) set from the board's poses in the images
    of `data` (one sensor, one target: a single image will do), every other parameter as in p: the mean of the
    poses the images give it."""
    (s,) = data.sensors
    (t,) = np.unique(data.target).tolist()
    camera = frame if frame == registration_frame(profile, profile.sensors[s].frame) else None
    board = frame if frame == registration_frame(profile, profile.targets[t].frame) else None
    (_, out), *_ = _Loop(profile, data, s, t, camera, board).solutions(p)
    return out


class _Loop:
    """The images of one board by one camera and the kinematic loop between them (module doc, step 2)."""

    def __init__(
        self, profile: Profile, data: Dataset, sensor: int, target: int, camera: int | None, board: int | None
    ) -> None:
        self.profile, self.camera, self.board = profile, camera, board
        self.sensor, self.target = sensor, target
        obs = np.flatnonzero(data.target == target)
        self.data = data
        self.cfgs = np.unique(data.cfg[obs])
        self.obs = [obs[data.cfg[obs] == c] for c in self.cfgs]

    def names(self) -> str:
        return " and ".join(self.profile.frames[f].name for f in (self.camera, self.board) if f is not None)

    def board_poses(self, p: np.ndarray) -> tuple[np.ndarray, list[list[np.ndarray]]]:
        """The configurations whose image fixes the board's pose, and each one's poses (optical frame)."""
        sensor = self.profile.sensors[self.sensor]
        assert isinstance(sensor, Pinhole)
        found, poses = [], []
        for c, obs in zip(self.cfgs, self.obs, strict=True):
            points = local_points(self.profile, self.data, obs, self.target, p)
            rays = sensor.view_rays(p, self.data.measured[obs, :2]) @ sensor.R_frame_optical
            ok = np.isfinite(points).all(axis=1) & np.isfinite(rays).all(axis=1) & (rays[:, 2] > 0)
            fits = board_poses(points[ok], rays[ok])
            if fits:
                found.append(c)
                poses.append(fits)
        if not found:
            frames = ", ".join(str(int(f)) for f in self.data.frame_ids[self.cfgs[:SHOWN_FRAMES]])
            more = f" and {len(self.cfgs) - SHOWN_FRAMES} more" if len(self.cfgs) > SHOWN_FRAMES else ""
            raise InputError(
                f"{self.profile.targets[self.target].name} is found in none of the {len(self.cfgs)} images of "
                f"{sensor.name} (frames {frames}{more}): its pose in an image needs at least 4 of its points, not "
                f"on one line, and the pose of {self.names()} is unknown until one does",
                file=self.data.source,
            )
        return np.array(found), poses

    def solutions(self, p: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """`p` with the unknown registrations from each closed form (module doc, steps 1-3 before refining)."""
        profile = self.profile
        cfgs, fits = self.board_poses(p)
        both = self.camera is not None and self.board is not None
        need = 3 if both else 1
        if len(cfgs) < need:
            raise InputError(
                f"{len(cfgs)} configurations show {profile.targets[self.target].name} to "
                f"{profile.sensors[self.sensor].name} with a pose: where {self.names()} stand needs at least "
                f"{need}{', the robot turned about different axes between them' if both else ''}",
                file=self.data.source,
            )
        q = p.copy()
        for f in (self.camera, self.board):
            if f is not None:
                q[[op.param for op in profile.frames[f].ops]] = 0.0
        A, K_camera, K_board = self._kinematics(q, cfgs)
        optical = pose(profile.sensors[self.sensor].R_frame_optical, np.zeros(3))

        def seen(choice: list[int]) -> np.ndarray:
            P = np.array([f[min(k, len(f) - 1)] for f, k in zip(fits, choice, strict=True)])
            return K_camera @ optical @ P @ inverse(K_board)

        C, flipped = seen([0] * len(cfgs)), seen([1] * len(cfgs))
        if not both:
            X = mean_pose(A @ inverse(C)) if self.camera is not None else mean_pose(inverse(A) @ C)
            return [("the mean of the board's poses", self._set(q, X if self.camera is not None else None, X))]
        spread = rotation_spread_deg(A)
        if spread < MIN_TURN_SPREAD_DEG:
            raise InputError(
                f"the {len(cfgs)} configurations that show {profile.targets[self.target].name} turn the robot about "
                f"one axis only (their axes within {spread:.1f} deg): where {self.names()} stand needs turns about "
                "different axes",
                file=self.data.source,
            )
        out = []
        for label, Z, X in hand_eye_candidates(A, C):
            out.append((label, self._set(q, X, Z)))
            # The flip of each image's PnP that agrees better with this solution.
            choice = [int(_pose_gap(A[i] @ Z, X @ flipped[i]) < _pose_gap(A[i] @ Z, X @ C[i])) for i in range(len(A))]
            if any(choice):
                _, Z2, X2 = next(c for c in hand_eye_candidates(A, seen(choice)) if c[0] == label)
                out.append((f"{label}, {sum(choice)} flipped", self._set(q, X2, Z2)))
        return out

    def _kinematics(self, q: np.ndarray, cfgs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A_i = S_i^-1 B_i, and the transforms from each registration frame down to the sensor's and the
        target's frames (identity where the pose is known: it is in S_i or B_i then)."""
        prof = self.profile
        sensor_frame, target_frame = prof.sensors[self.sensor].frame, prof.targets[self.target].frame
        poses = forward(prof, q, np.nan_to_num(self.data.joints[cfgs]), frames=[sensor_frame, target_frame])

        def at(frame: int) -> np.ndarray:
            return pose(poses.R[frame], poses.t[frame])

        S = at(sensor_frame if self.camera is None else self.camera)
        B = at(target_frame if self.board is None else self.board)
        K_camera = inverse(S) @ at(sensor_frame)
        K_board = inverse(B) @ at(target_frame)
        return inverse(S) @ B, K_camera, K_board

    def _set(self, q: np.ndarray, X: np.ndarray | None, Z: np.ndarray) -> np.ndarray:
        """q with the camera's registration X and the board's Z (each where unknown)."""
        out = q.copy()
        for f, T in ((self.camera, X), (self.board, Z)):
            if f is not None and T is not None:
                out[[op.param for op in self.profile.frames[f].ops]] = pose_parameters(T)
        return out


def pose_parameters(T: np.ndarray) -> list[float]:
    """x, y, z, yaw, pitch, roll of a registration frame (Trans Rot_z Rot_y Rot_x) for the pose T."""
    return [*T[:3, 3], *zyx_angles(T[:3, :3])]


def _pose_gap(T1: np.ndarray, T2: np.ndarray) -> float:
    """How far apart two poses are: the rotation's chord plus the translation relative to its size."""
    rot = float(np.linalg.norm(T1[:3, :3] - T2[:3, :3]))
    scale = max(float(np.linalg.norm(T1[:3, 3])), float(np.linalg.norm(T2[:3, 3])), 1e-9)
    return rot + float(np.linalg.norm(T1[:3, 3] - T2[:3, 3])) / scale


def _refined(
    profile: Profile, data: Dataset, params: list[int], candidates: list[tuple[str, np.ndarray]]
) -> list[CameraStart]:
    """Each distinct candidate refined by least squares on `params` alone: best first."""
    problem = Problem(profile, data, params, candidates[0][1])
    out: list[CameraStart] = []
    tried: list[np.ndarray] = []
    lengths = np.array([profile.parameters[i].kind == "length" for i in params])
    for label, q in candidates:
        x0 = q[params]
        gap = np.abs(np.array(tried) - x0) if tried else np.zeros((0, len(params)))
        near = np.where(lengths, gap <= SAME_CANDIDATE[0], gap <= SAME_CANDIDATE[1]).all(axis=1)
        if near.any():
            continue
        tried.append(x0)
        res = levenberg_marquardt(
            problem.residuals_jacobian, x0, fun=problem.residuals, max_iterations=REFINE_ITERATIONS
        )
        out.append(CameraStart(label, problem.params(res.x), res.cost))
    return sorted(out, key=lambda c: c.cost)
