"""A `calib handeye` folder from a ROS bag whose robot published its flange on /tf but not its joint states (issue
35): the still moments of the tool frame in the base frame, an image of each, the pose then.

The transforms on /tf and /tf_static form a tree; the tool frame's pose in the base frame at time t is the product
of the edges on the path between them, each edge at its latest transform up to t. The tool is still where it moves
less than `still_mm_s` and `still_deg_s` from one transform to the next for `still_s` at least; of each still
moment the image nearest its middle is kept, with the pose at that image's time. A CameraInfo topic, if the bag has
one, gives camera.yaml (ROS camera_calibration's form).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..files import write_atomic
from .bag_import import (
    _MESSAGE_ERRORS,
    IMAGE_TYPES,
    _default_image_topics,
    _index_images,
    _load_images,
    _open_reader,
    _reason,
    _topic_type,
    decode_image,
)

TF_TYPE = "tf2_msgs/msg/TFMessage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"


@dataclass
class TfImport:
    images: int  # written
    still: int  # still moments of the tool
    camera: bool  # camera.yaml written from a CameraInfo topic
    image_topic: str


def _transform(tf) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q, t = tf.transform.rotation, tf.transform.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [t.x, t.y, t.z]
    return T


def _edges(reader, bag: Path) -> dict[str, tuple[str, list[int], list[np.ndarray]]]:
    """child frame -> (parent frame, times ns, transforms), from /tf and /tf_static (static: time 0)."""
    edges: dict[str, tuple[str, list[int], list[np.ndarray]]] = {}
    topics = [t for t in ("/tf", "/tf_static") if t in reader.topics]
    if not topics:
        raise InputError("has no /tf or /tf_static topic: the flange's pose comes from them", file=str(bag))
    for topic in topics:
        connections = _topic_type(reader, bag, topic, [TF_TYPE], "transforms")
        try:
            for conn, _, raw in reader.messages(connections=connections):
                for tf in reader.deserialize(raw, conn.msgtype).transforms:
                    parent, child = tf.header.frame_id.lstrip("/"), tf.child_frame_id.lstrip("/")
                    t = 0 if topic == "/tf_static" else tf.header.stamp.sec * 1_000_000_000 + tf.header.stamp.nanosec
                    entry = edges.setdefault(child, (parent, [], []))
                    entry[1].append(t)
                    entry[2].append(_transform(tf))
        except (*_MESSAGE_ERRORS, KeyError, AttributeError) as exc:
            raise InputError(f"topic '{topic}' cannot be read ({_reason(exc)})", file=str(bag)) from None
    for child, (parent, times, poses) in edges.items():
        order = np.argsort(times, kind="stable")
        edges[child] = (parent, [times[k] for k in order], [poses[k] for k in order])
    return edges


def _chain(edges: dict, base: str, tool: str, bag: Path) -> list[str]:
    """The frames from the tool up to (not including) the base: each one's edge to its parent composes the pose."""
    path, frame = [], tool
    while frame != base:
        if frame not in edges or frame in path:
            known = ", ".join(sorted({*edges, *(p for p, _, _ in edges.values())})) or "none"
            raise InputError(f"--tf: no chain of transforms from '{base}' to '{tool}' (frames: {known})", file=str(bag))
        path.append(frame)
        frame = edges[frame][0]
    return path


def _pose_at(edges: dict, chain: list[str], t: int) -> np.ndarray | None:
    """The tool in the base at t (ns): each edge's latest transform up to t; None before an edge has one."""
    T = np.eye(4)
    for child in chain:
        _, times, poses = edges[child]
        k = bisect.bisect_right(times, t) - 1
        if k < 0:
            return None
        T = poses[k] @ T
    return T


def still_moments(
    times_ns: np.ndarray, poses: np.ndarray, mm_s: float, deg_s: float, still_s: float
) -> list[tuple[int, int]]:
    """(start, end) ns of each stretch where the pose moves less than mm_s and deg_s for still_s at least."""
    if len(times_ns) < 2:
        return []
    dt = np.diff(times_ns) / 1e9
    move_mm = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) * 1000
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    turn_deg = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    still = (move_mm <= mm_s * np.maximum(dt, 1e-9)) & (turn_deg <= deg_s * np.maximum(dt, 1e-9))
    out, start = [], None
    for k, s in enumerate(still):
        if s and start is None:
            start = k
        if (not s or k == len(still) - 1) and start is not None:
            end = k + 1 if s else k
            if (times_ns[end] - times_ns[start]) / 1e9 >= still_s:
                out.append((int(times_ns[start]), int(times_ns[end])))
            start = None
    return out


def handeye_folder_from_bag(
    bag: str | Path,
    out: str | Path,
    base: str,
    tool: str,
    image_topic: str | None = None,
    *,
    still_mm_s: float = 1.0,
    still_deg_s: float = 0.5,
    still_s: float = 0.5,
) -> TfImport:
    """Write `out`/images/NNNN.png, poses.csv (the tool in the base, m and a rotation vector in rad) and, if the
    bag has camera info, camera.yaml: what `calib handeye` takes."""
    import cv2
    from scipy.spatial.transform import Rotation

    bag, out = Path(bag), Path(out)
    reader = _open_reader(bag)
    try:
        edges = _edges(reader, bag)
        chain = _chain(edges, base, tool, bag)
        times = sorted({t for child in chain for t in edges[child][1] if t > 0}) or [0]
        sampled = [(t, _pose_at(edges, chain, t)) for t in times]
        sampled = [(t, T) for t, T in sampled if T is not None]
        moments = still_moments(
            np.array([t for t, _ in sampled]), np.array([T for _, T in sampled]), still_mm_s, still_deg_s, still_s
        )
        topic = image_topic or _default_image_topics(reader, bag, ["image"])[0]
        connections = _topic_type(reader, bag, topic, list(IMAGE_TYPES), "image")
        refs = _index_images(reader, bag, connections, topic)
        stamps = np.array([r.time.stamp_ns or r.time.log_ns for r in refs])
        chosen: dict[int, int] = {}  # image ordinal -> its time
        for start, end in moments:
            inside = np.flatnonzero((stamps >= start) & (stamps <= end))
            if len(inside):
                k = int(inside[np.argmin(np.abs(stamps[inside] - (start + end) / 2))])
                chosen[refs[k].ordinal] = int(stamps[k])
        messages = _load_images(reader, bag, connections, topic, set(chosen))
        camera = _camera_yaml(reader, bag)
    finally:
        reader.close()
    (out / "images").mkdir(parents=True, exist_ok=True)
    rows = ["image,x,y,z,rx,ry,rz"]
    for n, (ordinal, t) in enumerate(sorted(chosen.items(), key=lambda kv: kv[1]), start=1):
        grey = decode_image(*messages[ordinal], topic, str(bag))
        if grey is None:
            continue
        name = f"{n:04d}.png"
        if not cv2.imwrite(str(out / "images" / name), grey):
            raise OSError(f"cannot write images/{name}")
        T = _pose_at(edges, chain, t)
        r = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        rows.append(",".join([name, *(f"{v:.9f}" for v in (*T[:3, 3], *r))]))
    write_atomic(out / "poses.csv", "\n".join(rows) + "\n")
    if camera is not None:
        write_atomic(out / "camera.yaml", camera)
    return TfImport(len(rows) - 1, len(moments), camera is not None, topic)


def _camera_yaml(reader, bag: Path) -> str | None:
    """The bag's camera info (its first message), as ROS camera_calibration writes it; None without one."""
    topics = [t for t, info in reader.topics.items() if info.msgtype == CAMERA_INFO]
    if len(topics) != 1:
        return None
    connections = [c for c in reader.connections if c.topic == topics[0]]
    for conn, _, raw in reader.messages(connections=connections):
        msg = reader.deserialize(raw, conn.msgtype)
        k = [float(v) for v in msg.k]
        d = [float(v) for v in msg.d][:5] + [0.0] * max(0, 5 - len(msg.d))
        return (
            f"# camera info of {topics[0]} in {bag.name}\n"
            f"image_width: {int(msg.width)}\nimage_height: {int(msg.height)}\n"
            f"camera_matrix: {{rows: 3, cols: 3, data: {k}}}\n"
            f"distortion_model: {msg.distortion_model or 'plumb_bob'}\n"
            f"distortion_coefficients: {{rows: 1, cols: 5, data: {d}}}\n"
        )
    return None
