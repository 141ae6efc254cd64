"""Finders: how a sensor sees a target (the protocol: `base.Finder`), one module each, and their registry.

FINDERS is keyed by sensor model (`Sensor.kind`) and target pattern (`Target.pattern`); a finder serves a
sensor whose readings take the images it looks at (`Sensor.image_roles`) and give their size. The simulator's
capture, bag import, the drivers, the ROS 2 node, the recorded drive, the planner and `Visibility` all ask
`finder_for`. A new board is one module here and one line in FINDERS; a finder module is imported only when a
profile needs it.
"""

from __future__ import annotations

from functools import cache
from importlib import import_module

from ...model.profile import Profile
from .base import Finder, FinderClass, Rendered

# (sensor model, target pattern) -> "module:class" in this package, loaded on first use.
FINDERS: dict[tuple[str, str], str] = {
    ("point3d", "sphere"): "sphere:SphereFinder",
    ("pinhole", "sandal"): "sandal:SandalFinder",
    ("pinhole", "checkerboard"): "checkerboard:CheckerboardFinder",
    ("pinhole", "charuco"): "charuco:CharucoFinder",
}


@cache
def finder_class(key: tuple[str, str]) -> FinderClass | None:
    """The finder class registered for (sensor model, target pattern), or None."""
    if key not in FINDERS:
        return None
    module, name = FINDERS[key].split(":")
    return getattr(import_module(f".{module}", __name__), name)


def finder_for(profile: Profile, sensor: int, target: int) -> Finder | None:
    """The finder of a sensor (its index) for a target, or None: the sensor reads it directly (a tracker's
    reflector, a camera's marker points) or nothing finds it."""
    sens, tgt = profile.sensors[sensor], profile.targets[target]
    kind = finder_class((sens.kind, tgt.pattern))
    if kind is None or tuple(sens.image_roles) != kind.images or sens.image_size_px() is None:
        return None
    return kind(profile, sensor, target)


def finders_served() -> str:
    """What the finders serve, for a message: "pinhole: checkerboard, ...; point3d: sphere"."""
    models = sorted({model for model, _ in FINDERS})
    return "; ".join(f"{m}: {', '.join(sorted(p for n, p in FINDERS if n == m))}" for m in models)


def found_targets(profile: Profile, sensor: int) -> list[int]:
    """The targets a sensor has a finder for (in the profile's order)."""
    return [t for t in range(len(profile.targets)) if finder_for(profile, sensor, t) is not None]


__all__ = ["FINDERS", "Finder", "Rendered", "finder_class", "finder_for", "finders_served", "found_targets"]
