"""Names a package hands on from its modules, each module imported on first use: `import calib_core` and its
subpackages stay light (no SciPy, OpenCV or rosbags until a name that needs them is asked for)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from importlib import import_module
from typing import Any


def lazy_exports(package: str, modules: Mapping[str, tuple[str, ...]]) -> Callable[[str], Any]:
    """The package's module `__getattr__`: `modules` maps each of its modules (relative: "loader",
    "estimation.calibrate") to the names it hands on (the package's `__all__`, and what its `if TYPE_CHECKING:`
    block imports for type checkers)."""
    where = {name: module for module, names in modules.items() for name in names}

    def getattr_(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(f".{where[name]}", package), name)
        setattr(sys.modules[package], name, value)  # asked once: later lookups find it without this hook
        return value

    return getattr_
