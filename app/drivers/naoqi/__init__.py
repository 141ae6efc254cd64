"""NAOqi for the desk (the `naoqi` extra): a NAO through its own SDK over libqi, and a simulated one.

The contract other tools rely on is /specs naoqi.md: the connection file (connection.py), the driver
(driver.py), the simulated NAO served over libqi (sim.py, `calib sim-naoqi`). Nothing here imports `qi` at import
time: `require()` does, and says what to install when it is missing.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

from calib_core import InputError

INSTALL_HINT = (
    "install the NAOqi extra first: pip install -e '.[naoqi]' (in a checkout) or pip install 'robot-selfcal[naoqi]'"
)
CONNECT_TIMEOUT_S = 3.0


def require() -> ModuleType:
    """The `qi` module; InputError saying to install the `naoqi` extra when it is missing."""
    try:
        import qi
    except ImportError:
        raise InputError(f"libqi's Python bindings (qi) are not installed here: {INSTALL_HINT}") from None
    return qi


def open_session(url: str, timeout_s: float = CONNECT_TIMEOUT_S) -> Any:
    """A libqi session connected to the robot at `url`; RuntimeError, saying why, when it does not answer."""
    qi = require()
    session = qi.Session()
    future = session.connect(url, _async=True)
    future.wait(int(timeout_s * 1000))
    if not future.isFinished():
        future.cancel()
        raise RuntimeError(f"no answer within {timeout_s:g} s")
    if future.hasError():
        raise RuntimeError(future.error())
    return session
