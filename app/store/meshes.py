"""A robot's meshes uploaded with its profile and URDF: a zip of the description package's mesh files.

A zip keeps the package's folders, which the URDF's mesh names depend on (`package://arm_description/meshes/
base.stl`, `../meshes/base.stl`), is one file to pick in a browser and one `-F meshes_zip=@meshes.zip` for curl.
Its paths are taken relative to the profile's folder (the package's root): the store unpacks it there, beside
the profile and the URDF, and the review finds the meshes as it finds those of a URDF on disk, but in that
folder only (app/scene/robot_look.py `mesh_file`, robots.PACKAGE_ROOT).

The zip is checked whole before anything is written, from its directory: every entry a plain relative path
(no `..`, no absolute path, no drive), a regular file or a folder (no symlink), a mesh or what a mesh reads
(a texture, an OBJ's material), not encrypted; at most MAX_FILES files and `max_unpacked_bytes` unpacked
(against zip bombs: zipfile itself stops an entry at the size the directory gives it). A macOS archive's
`__MACOSX/` folder and `.DS_Store` files are left out. The meshes of a profile file named on this machine
are kept as such an archive too, zipped in memory (archive_files; app/robots/profile_meshes.py), checked alike.
"""

from __future__ import annotations

import io
import os
import stat
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from calib_core import InputError

from ..errors import TooLarge
from .files import fsync_dir

MESH_SUFFIXES = (".stl", ".obj", ".dae", ".ply", ".glb", ".gltf")  # what app/scene/robot_look.py reads
TEXTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".mtl")  # what a DAE or an OBJ reads beside it
SUFFIXES = MESH_SUFFIXES + TEXTURE_SUFFIXES
MAX_FILES = 2000
_LEFT_OUT = ("__MACOSX", ".DS_Store")  # what macOS's Finder adds to a zip
_CHUNK_BYTES = 1 << 20


class MeshesTooLarge(TooLarge):
    """More unpacked bytes or files than the desk takes."""


@dataclass(frozen=True)
class MeshArchive:
    """A checked zip of meshes: the upload's name (for messages), its bytes and the files it holds."""

    name: str
    data: bytes
    files: tuple[tuple[str, zipfile.ZipInfo], ...]  # (relative POSIX path, its entry)

    @property
    def paths(self) -> tuple[str, ...]:
        return tuple(path for path, _ in self.files)


def check_archive(name: str, data: bytes, max_unpacked_bytes: int) -> MeshArchive:
    """The zip `data` (uploaded as `name`) checked as the module says; InputError naming the entry otherwise
    (MeshesTooLarge when it is too large)."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, NotImplementedError) as exc:
        raise InputError(f"not a readable zip ({exc})", file=name) from None
    return MeshArchive(name, data, checked_entries(name, infos, max_unpacked_bytes))


def archive_files(name: str, files: dict[str, Path], max_unpacked_bytes: int) -> MeshArchive:
    """Files on this machine (relative POSIX path -> the file) as a MeshArchive, checked as an uploaded zip is:
    their sizes and number from the files' own before any is read, then zipped in memory (stored) and checked
    again (a file that grew meanwhile). InputError naming `name` when a file cannot be read."""
    try:
        checked_entries(
            name, [zipfile.ZipInfo.from_file(file, path) for path, file in files.items()], max_unpacked_bytes
        )
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as zf:
            for path, file in files.items():
                zf.write(file, path)
    except OSError as exc:
        raise InputError(f"cannot read {exc.filename} ({exc.__class__.__name__})", file=name) from None
    return check_archive(name, buffer.getvalue(), max_unpacked_bytes)


def checked_entries(
    name: str, infos: list[zipfile.ZipInfo], max_unpacked_bytes: int
) -> tuple[tuple[str, zipfile.ZipInfo], ...]:
    """The files of a zip directory `infos` (relative path, entry), checked as the module says."""
    if len(infos) > 2 * MAX_FILES:  # folders count too: a directory of millions of entries is read no further
        raise MeshesTooLarge(f"more than {2 * MAX_FILES} entries", file=name)
    files: list[tuple[str, zipfile.ZipInfo]] = []
    folders: set[str] = set()
    total = 0
    for info in infos:
        path = _relative_path(name, info.filename)
        if path is None:
            continue
        mode = info.external_attr >> 16
        if stat.S_ISLNK(mode):
            raise InputError(f"{info.filename} is a symbolic link: zip the files themselves", file=name)
        if info.is_dir():
            folders.add(path)
            continue
        if stat.S_IFMT(mode) and not stat.S_ISREG(mode):  # zipfile.writestr sets permissions without a file type
            raise InputError(f"{info.filename} is not a regular file", file=name)
        if info.flag_bits & 0x1:
            raise InputError(f"{info.filename} is encrypted: zip it without a password", file=name)
        if PurePosixPath(path).suffix.lower() not in SUFFIXES:
            raise InputError(
                f"{info.filename} is not a mesh file: a robot's meshes zip holds only meshes "
                f"({', '.join(MESH_SUFFIXES)}) and their textures ({', '.join(TEXTURE_SUFFIXES)})",
                file=name,
            )
        total += info.file_size
        files.append((path, info))
        if len(files) > MAX_FILES:
            raise MeshesTooLarge(f"more than {MAX_FILES} files", file=name)
        if total > max_unpacked_bytes:
            raise MeshesTooLarge(
                f"larger than {max_unpacked_bytes / 2**20:g} MB unpacked (the desk's limit for a robot's meshes)",
                file=name,
            )
    if not files:
        raise InputError("holds no mesh file", file=name)
    seen: set[str] = set()
    for path, info in files:
        if path.casefold() in seen or path in folders:
            raise InputError(f"{info.filename} is in the zip twice", file=name)
        seen.add(path.casefold())
    for path, info in files:
        for above in PurePosixPath(path).parents:
            if str(above).casefold() in seen:
                raise InputError(f"{info.filename} is below a file of the zip ({above})", file=name)
    return tuple(files)


def _relative_path(name: str, given: str) -> str | None:
    """An entry's path, relative and normalised ('/' separators, no '.' parts); None for what is left out."""
    text = given.replace("\\", "/")
    if "\x00" in text or any(ord(c) < 32 for c in text):
        raise InputError(f"{given!r}: a path with control characters", file=name)
    if text.startswith("/") or (len(text) > 1 and text[1] == ":"):
        raise InputError(f"{given} is an absolute path: the zip's paths are relative to the package", file=name)
    parts = [p for p in text.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise InputError(f"{given} reaches outside the package's folder ('..')", file=name)
    if not parts or parts[0] == _LEFT_OUT[0] or parts[-1] == _LEFT_OUT[1]:
        return None
    if any(len(p.encode()) > 255 for p in parts):
        raise InputError(f"{given}: a name longer than 255 bytes", file=name)
    return "/".join(parts)


def unpack(archive: MeshArchive, folder: Path) -> list[Path]:
    """Write the archive's files under `folder` (a staging folder: each file fsynced, then every folder that
    got a new name); InputError when an entry cannot be unpacked (a CRC error: a corrupt zip). The files."""
    written: list[Path] = []
    made: set[Path] = {folder}
    try:
        with zipfile.ZipFile(io.BytesIO(archive.data)) as zf:
            for path, info in archive.files:
                target = folder.joinpath(*path.split("/"))
                target.parent.mkdir(parents=True, exist_ok=True)
                made.update(p for p in target.parents if p.is_relative_to(folder))
                with zf.open(info) as src, open(target, "wb") as out:
                    while chunk := src.read(_CHUNK_BYTES):
                        out.write(chunk)
                    out.flush()
                    os.fsync(out.fileno())
                written.append(target)
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as exc:
        raise InputError(f"cannot be unpacked ({exc})", file=archive.name) from None
    for d in sorted(made, key=lambda p: len(p.parts), reverse=True):
        fsync_dir(d)
    return written
