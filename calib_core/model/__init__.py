"""The robot model: profiles (YAML or URDF) compiled to frames of elementary transforms, and their kinematics.

The names below load their module on first use (calib_core/_lazy.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_exports

__getattr__ = lazy_exports(
    __name__,
    {
        "kinematics": ("forward", "to_sensor"),
        "loader": ("BUILTIN_PROFILES", "load_profile"),
        "profile": ("Profile",),
        "urdf_import": ("profile_urdf_path",),
    },
)
__all__ = ["BUILTIN_PROFILES", "Profile", "forward", "load_profile", "profile_urdf_path", "to_sensor"]

if TYPE_CHECKING:
    from .kinematics import forward, to_sensor
    from .loader import BUILTIN_PROFILES, load_profile
    from .profile import Profile
    from .urdf_import import profile_urdf_path
