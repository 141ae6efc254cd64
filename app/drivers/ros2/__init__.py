"""ROS 2 for the desk (the `ros2` extra): a robot on its own ROS 2 graph, and a simulated one.

The contract other tools rely on is /specs ros2.md: the connection file (connection.py), the driver
(driver.py), the simulated robot as a ROS 2 node (sim_node.py, `calib sim-ros2`). Nothing here imports rclpy at
import time: `require()` does, and says what to install when it is missing.
"""

from __future__ import annotations

from calib_core import InputError

INSTALL_HINT = (
    "install the ROS 2 extra first: pip install -e '.[ros2]' (in a checkout) or pip install 'robot-selfcal[ros2]'"
)


def require() -> None:
    """InputError saying to install the `ros2` extra when rclpy or a message package is missing."""
    try:
        import geometry_msgs.msg  # noqa: F401
        import rcl_interfaces.srv  # noqa: F401
        import rclpy  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
        import std_msgs.msg  # noqa: F401
        import trajectory_msgs.msg  # noqa: F401
    except ImportError as exc:
        raise InputError(f"ROS 2 is not installed here ({exc.name or exc} is missing): {INSTALL_HINT}") from None
