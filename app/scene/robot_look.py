"""A URDF robot's own look: its links' <visual>s (meshes, boxes, cylinders, spheres), read once per file.

The review scene draws a profile's frame tree (calib_core.io.urdf_export.to_urdf) at each calibration's
parameters. A profile made from a URDF (`urdf: robot.urdf`) has one frame per URDF link, named after the
link and at the link's pose, so a link's visuals hang under that frame's node in each copy and every copy
shows them where its own calibration puts the link (app/scene/review_scene/copies.py).

Meshes (STL, OBJ, DAE; `package://` or relative to the URDF, found as yourdfpy finds them) are read with
trimesh and kept as plain arrays, in the visual's own frame (m): each copy sends them to the browser once,
and a frame step only moves the link frames. A robot's meshes together keep at most MAX_FACES triangles (a
bigger one is thinned by vertex clustering, in proportion to its share), since every copy in every browser
holds them. A mesh that cannot be found or read leaves its link to the simple shapes of the frame tree and
is named in the look's one warning; a link without visuals in a URDF that has some draws nothing (a tool or
flange frame); a URDF without any visual is drawn with the simple shapes throughout.
"""

from __future__ import annotations

import io
import logging
import os
import threading
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calib_core import Profile
from calib_core.io import BODY
from calib_core.model import profile_urdf_path

from ..store.meshes import MESH_SUFFIXES
from ..store.robots import PACKAGE_ROOT

if TYPE_CHECKING:  # both load when a look is read (trimesh's import takes half a second: not at the desk's start)
    import trimesh
    import yourdfpy

log = logging.getLogger(__name__)

MAX_FACES = 100_000  # triangles per robot, over all its visuals (each copy in each browser holds them)
MAX_MESH_BYTES = 64 * 1024 * 1024  # a mesh file above this is not read (named in the warning)
CYLINDER_SECTIONS = 24
DEFAULT_RGBA = (0.72, 0.74, 0.78, 1.0)  # a visual without a colour of its own (the built-in bodies' grey)
SHOWN_PROBLEMS = 3  # visuals the warning names (the log names every one)
_CACHED = 8  # looks kept (one per URDF file version)


@dataclass(frozen=True)
class LinkVisual:
    """One <visual> of a link: its pose in the link frame and its triangles in its own frame (m)."""

    link: str
    T_link_visual: np.ndarray  # (4, 4)
    vertices: np.ndarray  # (V, 3) float32, m
    faces: np.ndarray  # (F, 3) uint32
    rgb: tuple[int, int, int]
    opacity: float
    what: str  # "mesh FILE" or the primitive's name, for messages


@dataclass(frozen=True)
class RobotLook:
    """The visuals of the links drawn with their own (`links`), the warning that says which are not and why,
    and what reading took."""

    urdf: str  # the URDF's file name
    visuals: tuple[LinkVisual, ...]
    links: frozenset[str]  # links drawn with their own visuals: the frame tree's simple shapes of these go
    warning: str | None  # the few first problems, for the review's answer
    problems: tuple[str, ...]  # every visual that cannot be drawn, and why (the log's)
    faces_read: int  # triangles in the files
    faces: int  # triangles kept (at most MAX_FACES)
    seconds: float


_lock = threading.Lock()
_looks: dict[tuple, RobotLook | None] = {}
_paths: dict[tuple, Path | None] = {}  # (profile source, its version) -> the URDF it names
_reading: dict[tuple, threading.Lock] = {}  # a URDF version being read -> held by its reader


def robot_look(profile: Profile) -> RobotLook | None:
    """The look of a profile made from a URDF file (None: a profile of its own frames, or a URDF without any
    visual, or one that cannot be read any more), read once per version of the file."""
    path = _urdf_path(profile)
    if path is None:
        return None
    try:
        stat = path.stat()
    except OSError:
        return None
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    with _lock:
        if key in _looks:
            return _looks[key]
        reading = _reading.setdefault(key, threading.Lock())
    with reading:  # one reader per file: two viewers opening one robot read it once; other robots never wait
        with _lock:
            if key in _looks:
                return _looks[key]
        look = read_look(path)
        if look is not None and look.warning:
            more = len(look.problems) > SHOWN_PROBLEMS
            log.warning("%s%s", look.warning, f" (every one: {'; '.join(look.problems)})" if more else "")
        with _lock:
            while len(_looks) >= _CACHED:
                _looks.pop(next(iter(_looks)))
            _looks[key] = look
            _reading.pop(key, None)
        return look


def _urdf_path(profile: Profile) -> Path | None:
    """profile_urdf_path, read once per version of the profile file (parsing NAO's YAML takes 0.2 s, and every
    review of every robot asks)."""
    try:
        version = Path(profile.source).stat().st_mtime_ns
    except OSError:
        version = None  # a built-in profile ("nao (built-in)"): its file does not change while the desk runs
    key = (profile.source, version)
    with _lock:
        if key in _paths:
            return _paths[key]
    path = profile_urdf_path(profile)  # outside the lock: nobody waits for another robot's YAML
    with _lock:
        while len(_paths) >= _CACHED:
            _paths.pop(next(iter(_paths)))
        _paths[key] = path
    return path


def read_look(path: Path, max_faces: int = MAX_FACES) -> RobotLook | None:
    """Read a URDF's visuals and their meshes (see the module); None when it has no visual at all."""
    import yourdfpy

    t0 = time.perf_counter()
    name = path.name
    try:
        urdf = yourdfpy.URDF.load(
            io.BytesIO(path.read_bytes()), build_scene_graph=False, load_meshes=False, build_collision_scene_graph=False
        )
    except Exception as exc:  # the profile loaded it: what yourdfpy refuses costs the look only
        why = f"its visuals cannot be read ({exc})"
        return RobotLook(name, (), frozenset(), f"{name}: {why}; drawn with simple shapes", (why,), 0, 0, 0.0)
    visuals, failed = link_visuals(urdf, path.parent)
    if not visuals and not failed:
        return None
    read = sum(len(v.faces) for v in visuals)
    if read > max_faces:
        cap = face_cap([len(v.faces) for v in visuals], max_faces)
        visuals = [_thinned(v, cap) for v in visuals]
    problems = tuple(f"{why} (link '{link}')" for link, whys in failed.items() for why in whys)
    warning = None
    if failed:
        more = f" and {len(problems) - SHOWN_PROBLEMS} more" if len(problems) > SHOWN_PROBLEMS else ""
        links_are = "its link is" if len(failed) == 1 else f"their {len(failed)} links are"
        warning = f"{name}: {'; '.join(problems[:SHOWN_PROBLEMS])}{more}: {links_are} drawn with simple shapes"
    links = frozenset(link.name for link in urdf.robot.links if link.name not in failed)
    kept = sum(len(v.faces) for v in visuals)
    return RobotLook(name, tuple(visuals), links, warning, problems, read, kept, time.perf_counter() - t0)


def link_visuals(urdf: yourdfpy.URDF, folder: Path) -> tuple[list[LinkVisual], dict[str, list[str]]]:
    """Every link's visuals (meshes looked for from `folder`, the URDF's), and per link what cannot be drawn: a
    link with a visual that cannot be drawn keeps none of its visuals."""
    colours = {m.name: m.color.rgba for m in urdf.robot.materials if m.color is not None}
    visuals: list[LinkVisual] = []
    failed: dict[str, list[str]] = {}  # link -> what could not be read
    for link in urdf.robot.links:
        mine = []
        for visual in link.visuals:
            try:
                mesh, own_rgba, what = _geometry(visual.geometry, folder)
            except _Unreadable as exc:
                failed.setdefault(link.name, []).append(str(exc))
                continue
            if mesh is None:
                continue
            rgba = _rgba(visual.material, colours, own_rgba)
            T = np.eye(4) if visual.origin is None else np.asarray(visual.origin, float)
            vertices, faces = np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32)
            mine.append(LinkVisual(link.name, T, vertices, faces, _rgb(rgba), float(rgba[3]), what))
        if link.name not in failed:
            visuals.extend(mine)
    return visuals, failed


class _Unreadable(Exception):
    """A visual that cannot be drawn; its message names the file and why."""


def _geometry(geometry: yourdfpy.Geometry, folder: Path) -> tuple[trimesh.Trimesh | None, tuple | None, str]:
    """A visual's triangles (m), the mesh file's own colour (RGBA 0-1) if it has one, and what it is; None for
    an empty <geometry>."""
    import trimesh

    if geometry.box is not None:
        return trimesh.creation.box(extents=np.asarray(geometry.box.size, float)), None, "box"
    if geometry.cylinder is not None:
        c = geometry.cylinder
        return trimesh.creation.cylinder(radius=c.radius, height=c.length, sections=CYLINDER_SECTIONS), None, "cylinder"
    if geometry.sphere is not None:
        return trimesh.creation.icosphere(subdivisions=2, radius=geometry.sphere.radius), None, "sphere"
    if geometry.mesh is None:
        return None, None, ""
    given = geometry.mesh.filename
    found = mesh_file(given, folder)
    if found is None:
        raise _Unreadable(f"mesh {given} cannot be found")
    if found.suffix.lower() not in MESH_SUFFIXES:
        raise _Unreadable(f"mesh {given} is not a mesh file ({', '.join(MESH_SUFFIXES)})")
    if found.stat().st_size > MAX_MESH_BYTES:
        raise _Unreadable(f"mesh {given} is larger than {MAX_MESH_BYTES // 2**20} MB")
    try:
        mesh = trimesh.load(str(found), force="mesh")
    except Exception as exc:  # trimesh's loaders raise anything a broken file makes them raise
        raise _Unreadable(f"mesh {given} cannot be read ({exc.__class__.__name__}: {exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise _Unreadable(f"mesh {given} holds no triangles")
    scale = geometry.mesh.scale
    if scale is not None:
        mesh.apply_scale(np.broadcast_to(np.asarray(scale, float), 3))
    return mesh, _own_rgba(mesh), f"mesh {given}"


def mesh_file(given: str, folder: Path) -> Path | None:
    """The file a URDF's mesh `filename` means, for a URDF in `folder`; None if there is none. `package://PKG/
    REST` is looked for as ROS would find it (PKG under ROS_PACKAGE_PATH, or share/PKG under AMENT_PREFIX_PATH)
    and, for a description copied without its workspace, in the URDF's folder and every folder above it (as
    REST, and as PKG/REST); `file://PATH` and a plain path are relative to the URDF's folder.

    A URDF kept by the desk, with its uploaded meshes or none (below a folder holding PACKAGE_ROOT: app/store/robots.py)
    finds them in that folder only: `package://` neither in the ROS paths nor above it, and a path that leads
    out of it (`../..`, an absolute one) finds nothing."""
    root = next((d for d in (folder, *folder.parents) if (d / PACKAGE_ROOT).is_file()), None)
    candidates: list[Path] = []
    if given.startswith("package://"):
        package, _, rest = given[len("package://") :].partition("/")
        if root is None:
            for entry in filter(None, os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep)):
                candidates.append(Path(entry) / package / rest)
            for entry in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
                candidates.append(Path(entry) / "share" / package / rest)
        for above in (folder, *folder.parents):
            candidates += [above / rest, above / package / rest]
            if above == root:
                break
    else:
        path = Path(given[len("file://") :] if given.startswith("file://") else given)
        candidates.append(path if path.is_absolute() else folder / path)
    if root is not None:
        inside = root.resolve()
        candidates = [c for c in candidates if c.resolve().is_relative_to(inside)]
    return next((c for c in candidates if c.is_file()), None)


def _own_rgba(mesh: trimesh.Trimesh) -> tuple[float, ...] | None:
    """A mesh file's main colour (a DAE's material, an OBJ's), RGBA 0-1; None for a file without one (STL)."""
    try:
        if mesh.visual.kind == "texture":  # the material's colour: sampling the texture takes long
            rgba = mesh.visual.material.main_color
        elif mesh.visual.kind is None:
            return None
        else:
            rgba = mesh.visual.main_color
        return tuple(float(v) / 255.0 for v in rgba)
    except Exception:  # a visual trimesh cannot say a colour of: the URDF's colour or the default
        return None


def _rgba(material: yourdfpy.Material | None, colours: dict[str, np.ndarray], own: tuple[float, ...] | None) -> tuple:
    """The URDF's colour of a visual (its own <color>, else its named material's), else the file's, else grey."""
    if material is not None:
        if material.color is not None:
            return tuple(float(v) for v in material.color.rgba)
        if material.name in colours:
            return tuple(float(v) for v in colours[material.name])
    return own if own is not None else DEFAULT_RGBA


def _rgb(rgba: tuple) -> tuple[int, int, int]:
    r, g, b = (round(255 * min(max(float(v), 0.0), 1.0)) for v in rgba[:3])
    return r, g, b


def _thinned(visual: LinkVisual, max_faces: int) -> LinkVisual:
    """The visual with at most `max_faces` triangles (its own if it has no more)."""
    if len(visual.faces) <= max_faces:
        return visual
    vertices, faces = cluster_vertices(visual.vertices, visual.faces, max_faces)
    return LinkVisual(visual.link, visual.T_link_visual, vertices, faces, visual.rgb, visual.opacity, visual.what)


def face_cap(counts: list[int], max_faces: int) -> int:
    """The most triangles any one mesh may keep so that all keep at most `max_faces` together: the small ones
    keep theirs, only the biggest are thinned (to the same size)."""
    counts = sorted(counts)
    left = max_faces
    for k, n in enumerate(counts):
        if n * (len(counts) - k) > left:
            return max(left // (len(counts) - k), 12)
        left -= n
    return counts[-1] if counts else max_faces


def cluster_vertices(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """A coarser mesh with at most `max_faces` triangles: vertices merged per cell of a grid (their mean), the
    triangles that collapse dropped. The cell is about the smallest that keeps few enough (a geometric
    bisection from the cell the surface area suggests): crude next to quadric decimation, but enough for a
    display and it needs no library."""
    v = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    low = v.min(axis=0)
    size = float(np.max(v.max(axis=0) - low)) or 1.0
    area = float(
        np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1).sum()
    )
    cell = float(np.sqrt(max(area, 1e-12) / max(max_faces, 1)))  # about two triangles per occupied cell

    def clustered(cell: float) -> tuple[np.ndarray, np.ndarray]:
        k = np.floor((v - low) / cell).astype(np.int64)
        n = int(size / cell) + 2
        _, inverse = np.unique((k[:, 0] * n + k[:, 1]) * n + k[:, 2], return_inverse=True)
        f = inverse.reshape(-1)[faces]  # corners in their order: sorting them would turn triangles inside out
        o = np.sort(f, axis=1)
        kept = (o[:, 0] != o[:, 1]) & (o[:, 1] != o[:, 2])
        f, o = f[kept], o[kept]
        m = int(inverse.max()) + 1
        _, first = np.unique((o[:, 0] * m + o[:, 1]) * m + o[:, 2], return_index=True)  # one of each triangle
        means = np.zeros((m, 3))
        np.add.at(means, inverse.reshape(-1), v)
        return means / np.bincount(inverse.reshape(-1), minlength=m)[:, None], f[first]

    fine, coarse, best = 0.0, None, None
    while best is None or (fine > 0 and coarse / fine > 1.05):
        out = clustered(cell)
        if len(out[1]) <= max_faces:
            coarse, best = cell, out
        else:
            fine = cell
        cell = np.sqrt(fine * coarse) if fine > 0 and coarse else cell * 1.5 if coarse is None else cell / 1.5
        if coarse is not None and fine == 0 and cell < size * 1e-6:
            break  # even the finest cell keeps few enough
    means, f = best
    used, f = np.unique(f, return_inverse=True)
    return means[used].astype(np.float32), f.reshape(-1, 3).astype(np.uint32)


def without_bodies(urdf_text: str, links: frozenset[str]) -> str:
    """A display model (to_urdf(bodies=True)) without the simple bodies of the links drawn with their own
    visuals; the cameras, targets and boards the profile adds stay."""
    robot = ET.fromstring(urdf_text)
    for link in robot.iter("link"):
        if link.get("name") not in links:
            continue
        for visual in link.findall("visual"):
            material = visual.find("material")
            if material is not None and material.get("name") == BODY:
                link.remove(visual)
    return ET.tostring(robot, encoding="unicode")
