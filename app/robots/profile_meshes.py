"""The meshes of a URDF on this machine, gathered to be kept with a robot added by naming its profile file.

A profile kept by the desk reads no file outside its folder (app/store/robots.py), so the meshes its URDF's
<visual>s name are copied with it, as an uploaded meshes zip is unpacked: into the robot's folder, where the
review then looks for them alone (store.robots.PACKAGE_ROOT). Each mesh is found as the review finds it on disk
(robot_look.mesh_file, from the URDF's own folder) and kept where the kept URDF's name for it finds it: a
relative name relative to where the URDF is kept; `package://PKG/REST` where the file lay in the profile's
folder when the name finds it there (REST, PKG/REST, ...), else at PKG/REST. An OBJ's materials (`mtllib`)
and the textures they name go beside it, as they lay beside it. What the review would not draw (a mesh not
found, not a mesh file, larger than robot_look.MAX_MESH_BYTES) and a name that leads out of the robot's folder
(an absolute path, `../` above it) are left out: the review's warning names them. Too many or too large
together is refused as a zip is (store/meshes.py, MeshesTooLarge).
"""

from __future__ import annotations

import os
import posixpath
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path, PurePosixPath

from ..scene.robot_look import MAX_MESH_BYTES, mesh_file
from ..store.meshes import MESH_SUFFIXES, TEXTURE_SUFFIXES, MeshArchive, archive_files


def gather_meshes(urdf_file: Path, package_root: Path, kept_urdf: str, max_unpacked_bytes: int) -> MeshArchive | None:
    """The meshes `urdf_file` names, as an archive to unpack in the robot's folder (`package_root` on disk: the
    profile's folder), where the URDF is kept at `kept_urdf` (relative POSIX path); None when none is found."""
    try:
        urdf = ET.fromstring(urdf_file.read_bytes())
    except (ET.ParseError, OSError):
        return None  # the profile's loader names what is wrong
    kept_folder = PurePosixPath(kept_urdf).parent
    files: dict[str, Path] = {}
    taken: set[str] = set()  # casefolded: a zip's two names that differ in case only are refused

    def keep(target: str | None, file: Path) -> bool:
        if target is None or target.casefold() in taken:
            return False
        taken.add(target.casefold())
        files[target] = file
        return True

    for mesh in urdf.iterfind("link/visual/geometry/mesh"):
        given = mesh.get("filename") or ""
        found = mesh_file(given, urdf_file.parent) if given else None
        if found is None or found.suffix.lower() not in MESH_SUFFIXES or found.stat().st_size > MAX_MESH_BYTES:
            continue
        target = _target(given, found, package_root, kept_folder)
        if keep(target, found) and found.suffix.lower() == ".obj":
            for name, file in _materials(found):
                keep(_inside(posixpath.join(posixpath.dirname(target), name)), file)
    return archive_files(f"the meshes of {urdf_file}", files, max_unpacked_bytes) if files else None


def _target(given: str, found: Path, package_root: Path, kept_folder: PurePosixPath) -> str | None:
    """Where in the robot's folder the kept URDF's mesh name `given` finds `found` (None: nowhere)."""
    if given.startswith("package://"):
        package, _, rest = given[len("package://") :].partition("/")
        on_disk = os.path.relpath(os.path.abspath(found), os.path.abspath(package_root)).replace(os.sep, "/")
        places = {
            _inside(str(above / name))
            for above in (kept_folder, *kept_folder.parents)
            for name in (rest, f"{package}/{rest}")
        }
        return on_disk if on_disk in places else _inside(f"{package}/{rest}")
    name = given[len("file://") :] if given.startswith("file://") else given
    return None if Path(name).is_absolute() else _inside(str(kept_folder / name))


def _inside(path: str) -> str | None:
    """`path` normalised ('/', no '.' or '..'), None when it leads out of the robot's folder."""
    path = posixpath.normpath(path.replace("\\", "/"))
    return None if path in (".", "..") or path.startswith(("../", "/")) else path


def _materials(obj: Path) -> Iterator[tuple[str, Path]]:
    """An OBJ's material files (its `mtllib` lines) and the textures they name (`map_Kd` ... lines, the name
    last), each as its name relative to the OBJ's folder and the file: those that are there."""
    for name in _readable(_named(obj, (b"mtllib",), all_words=True)):
        mtl = obj.parent / name
        if mtl.suffix.lower() != ".mtl" or not mtl.is_file():
            continue
        yield name, mtl
        for texture in _readable(_named(mtl, (b"map_", b"bump", b"disp", b"norm"))):
            file = mtl.parent / texture
            if file.suffix.lower() in TEXTURE_SUFFIXES and file.is_file():
                yield posixpath.join(posixpath.dirname(name), texture), file


def _readable(names: Iterator[str]) -> list[str]:
    """The names (a generator that opens its file when first asked), or none when the file cannot be read: the
    mesh is kept without its materials."""
    try:
        return list(names)
    except OSError:
        return []


def _named(file: Path, keys: tuple[bytes, ...], *, all_words: bool = False) -> Iterator[str]:
    """The relative file names on `file`'s lines that start with one of `keys`: every word after the key, or
    the last (a texture's options come before its name)."""
    with open(file, "rb") as lines:
        for line in lines:
            words = line.split()
            if len(words) < 2 or not words[0].startswith(keys):
                continue
            for word in words[1:] if all_words else words[-1:]:
                name = word.decode("utf-8", "replace").replace("\\", "/")
                if not PurePosixPath(name).is_absolute():
                    yield name
