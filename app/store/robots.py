"""The robots the desk has had: one row per instance (name, profile, driver kind and options, origin).

A robot on the desk is an instance of a profile (a model): five NAOs are `nao-1` ... `nao-5`, each with
profile `nao`. Sessions, calibrations and applies name the instance. A profile is a built-in one by name,
or a profile file: one added through the API is kept under DATA/robots/<name>/ (with the URDF it names and
that URDF's meshes), so the robot is there after a restart. A built-in robot the desk has no row of yet (a
store made before instances, or one opened without a desk) is the instance of its profile, named after it.
"""

from __future__ import annotations

import json
import secrets
import shutil
import sqlite3
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath
from typing import Any, TypeVar

import yaml

from calib_core import InputError, Profile
from calib_core.model import BUILTIN_PROFILES
from calib_core.safe_yaml import load_yaml

from ..errors import NotFound
from .db import Database, now
from .files import fsync_dir, write_bytes
from .meshes import MeshArchive, unpack
from .profiles import file_name, instance_profile, load_model
from .validation import check_id

T = TypeVar("T")
# Marks the folder of a robot the desk keeps: its URDF's meshes are looked for there only (app/scene/robot_look.py).
PACKAGE_ROOT = ".uploaded-description"
CONFINED = b"the URDF's meshes are looked for in this folder only\n"  # PACKAGE_ROOT's text


@dataclass(frozen=True)
class RobotRecord:
    name: str
    profile: str  # a built-in profile's name, or a profile file (relative: under the data directory)
    driver: str | None  # the driver kind (app/drivers/registry.py), None: real data only
    options: dict[str, Any] = field(default_factory=dict)
    origin: str = "api"  # "builtin" (the desk's defaults), "config" (its configuration file), "api" (added)
    added: str = ""


@dataclass(frozen=True)
class ProfileFiles:
    """A profile file, the URDF it names and that URDF's meshes, to be kept under DATA/robots/<name>/."""

    profile_name: str
    profile: bytes
    urdf: tuple[str, bytes] | None = None
    meshes: MeshArchive | None = None  # unpacked beside the profile (the description package's root)


class RobotRepository:
    def __init__(self, db: Database, data_dir: Path) -> None:
        self.db = db
        self.data_dir = data_dir
        self._profiles: dict[str, Profile] = {}
        self._confine_meshes()

    def _confine_meshes(self) -> None:
        """Every kept robot's URDF finds its meshes in its own folder only, a robot kept before every folder got
        its PACKAGE_ROOT mark included (its URDF could name any file on the server: `../..`, an absolute path)."""
        for folder in (self.data_dir / "robots").glob("[!.]*/"):
            if not (folder / PACKAGE_ROOT).is_file():
                write_bytes(folder / PACKAGE_ROOT, CONFINED)

    def list(self) -> list[RobotRecord]:
        return [_record(r) for r in self.db.all("SELECT * FROM robots ORDER BY added, name")]

    def get(self, name: str) -> RobotRecord:
        row = self.db.one("SELECT * FROM robots WHERE name = ?", (name,))
        if row is None:
            if name in BUILTIN_PROFILES:
                return RobotRecord(name, name, None, origin="builtin")
            raise NotFound.unknown("robot", name)
        return _record(row)

    def profile(self, name: str) -> Profile:
        """The robot's profile, named after the robot. An unknown robot is bad input (422)."""
        if name not in self._profiles:
            try:
                record = self.get(name)
            except NotFound:
                known = sorted({r.name for r in self.list()} | set(BUILTIN_PROFILES))
                raise InputError(f"unknown robot '{name}' (known: {', '.join(known)})") from None
            self._profiles[name] = instance_profile(record.profile, name, self.data_dir)
        return self._profiles[name]

    def names_with_data(self) -> list[str]:
        """Robots that sessions, calibrations or applies name, in the order they first appear."""
        rows = self.db.all(
            "SELECT robot FROM sessions UNION SELECT robot FROM calibrations UNION SELECT robot FROM applies"
        )
        return sorted({r["robot"] for r in rows})

    def has_data(self, name: str) -> bool:
        return name in self.names_with_data()

    def put(self, record: RobotRecord) -> None:
        """Record a robot the desk starts with (its defaults or its configuration file)."""
        with self.db.tx() as db:
            _upsert(db, record)
        self._profiles.pop(record.name, None)

    def add(self, record: RobotRecord, files: ProfileFiles | None, prepare: Callable[[Profile], T]) -> T:
        """A new robot (`record.profile` a built-in name, or `files`): its files put in place, its profile (the
        model, not yet named after the robot) loaded and `prepare(model)` run (the desk makes its driver
        there), then its row inserted. Any failure leaves nothing behind; returns what `prepare` returned."""
        check_id("robot name", record.name)
        if self.db.exists("robots", record.name, "name") or record.name in self.names_with_data():
            raise InputError(f"a robot '{record.name}' exists already (or its sessions do): choose another name")
        folder = self.data_dir / "robots" / record.name
        with self.db.lock:
            try:
                if files is not None:
                    staged = self._stage(record.name, files)
                    if folder.exists():
                        shutil.rmtree(folder)  # a leftover of an add whose row never committed
                    staged.rename(folder)
                    fsync_dir(folder.parent)
                    record = replace(record, profile=f"robots/{record.name}/{files.profile_name}")
                result = prepare(load_model(record.profile, self.data_dir))
                with self.db.tx() as db:
                    _upsert(db, replace(record, origin="api"))
            except BaseException:
                if files is not None:
                    shutil.rmtree(folder, ignore_errors=True)
                raise
        self._profiles.pop(record.name, None)
        return result

    def remove(self, name: str) -> None:
        """Forget a robot added through the API that has no data (its files go too)."""
        record = self.get(name)
        if record.origin != "api":
            raise InputError(f"robot '{name}' comes from the desk's configuration: change that to remove it")
        if self.has_data(name):
            raise InputError(f"robot '{name}' has sessions or calibrations: they keep it on the desk")
        with self.db.tx() as db:
            db.execute("DELETE FROM robots WHERE name = ?", (name,))
        self._profiles.pop(name, None)
        shutil.rmtree(self.data_dir / "robots" / name, ignore_errors=True)

    def _stage(self, name: str, files: ProfileFiles) -> Path:
        """The files in a staging folder beside the robots' folders: the URDF where the profile's `urdf:` puts
        it (in its folder, when that is a plain relative one: `urdf/arm.urdf`), the meshes unpacked beside the
        profile, so that the URDF's mesh names find them as on disk. A URDF given with a profile that names
        none, and meshes without a URDF, are refused."""
        if files.urdf is not None and files.urdf[0] == files.profile_name:
            raise InputError(f"the profile and its URDF are both named {files.profile_name}: rename one")
        if files.meshes is not None and files.urdf is None:
            raise InputError("meshes go with a URDF: give the URDF the profile names too", file=files.meshes.name)
        text, urdf_path = _point_at_urdf(
            files.profile_name, files.profile, None if files.urdf is None else files.urdf[0]
        )
        if files.meshes is not None:
            taken = {files.profile_name.casefold(), (urdf_path or "").casefold()}
            clash = next((p for p in files.meshes.paths if p.casefold() in taken), None)
            if clash is not None:
                raise InputError(f"{clash} is the profile's or the URDF's own name: rename it", file=files.meshes.name)
        root = self.data_dir / "robots"
        root.mkdir(exist_ok=True)
        staged = root / f".{name}.{secrets.token_hex(3)}"
        staged.mkdir()
        try:
            if files.urdf is not None and urdf_path is not None:
                urdf_file = staged.joinpath(*urdf_path.split("/"))
                write_bytes(urdf_file, files.urdf[1], atomic=False)
                fsync_dir(urdf_file.parent)
            if files.meshes is not None:
                unpack(files.meshes, staged)
            write_bytes(staged / PACKAGE_ROOT, CONFINED, atomic=False)
            write_bytes(staged / files.profile_name, text, atomic=False)
            fsync_dir(staged)
        except BaseException:
            shutil.rmtree(staged, ignore_errors=True)
            raise
        return staged


def _point_at_urdf(profile_name: str, text: bytes, urdf_name: str | None) -> tuple[bytes, str | None]:
    """The profile with its `urdf:` naming the URDF given with it (`urdf_name`, in the folder the profile's
    `urdf:` names when that is a plain relative folder, else beside the profile), and that path. A profile
    that names a URDF not given with it, or none when one is given, is refused: a profile kept by the desk
    reads no file outside its folder."""
    doc = load_yaml(text, profile_name)
    ref = doc.get("urdf") if isinstance(doc, dict) else None
    if urdf_name is None:
        if ref is not None:
            raise InputError(f"urdf: {ref} is not given with the profile (give the URDF file too)", file=profile_name)
        return text, None
    if not isinstance(ref, str) or not ref.strip():
        raise InputError(f"urdf: the profile names no URDF file, but {urdf_name} is given with it", file=profile_name)
    path = kept_urdf_path(ref, urdf_name)
    if ref == path:
        return text, path
    return yaml.safe_dump({**doc, "urdf": path}, sort_keys=False, allow_unicode=True).encode(), path


def kept_urdf_path(ref: str, urdf_name: str) -> str:
    """Where the desk keeps a URDF named `urdf_name` that a profile's `urdf: ref` names, relative to the profile's
    folder: in the folder `ref` names when that is a plain relative one (`urdf/arm.urdf`), else beside it."""
    folder = PurePosixPath(ref.strip().replace("\\", "/")).parent.parts
    plain = all(part == file_name(part, "") for part in folder)  # no '..', no absolute path, no hidden folder
    return "/".join([*folder, urdf_name]) if plain else urdf_name


def _upsert(db: sqlite3.Connection, r: RobotRecord) -> None:
    db.execute(
        "INSERT INTO robots VALUES (?, ?, ?, ?, ?, ?) ON CONFLICT(name) DO UPDATE SET profile = excluded.profile, "
        "driver = excluded.driver, options = excluded.options, origin = excluded.origin",
        (r.name, r.profile, r.driver, json.dumps(r.options), r.origin, r.added or now()),
    )


def _record(r: sqlite3.Row) -> RobotRecord:
    return RobotRecord(r["name"], r["profile"], r["driver"], json.loads(r["options"]), r["origin"], r["added"])
