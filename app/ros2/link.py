"""One process's link to a ROS 2 graph: its own rclpy context, one node and an executor thread.

Each link is independent (its own context), so a driver's link closes without touching another's. The
graph is the environment's: ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE and RMW_IMPLEMENTATION.
"""

from __future__ import annotations

import threading
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# A best-effort subscription matches reliable and best-effort publishers alike (sensor data, joint states).
SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
# As robot_state_publisher publishes robot_description: the last message kept for late joiners.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Commands: reliable, as a ros2_control trajectory controller subscribes.
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)


class Link:
    """A node on the graph, spun by a multi-threaded executor in a daemon thread until close()."""

    def __init__(
        self,
        node_name: str,
        *,
        namespace: str | None = None,
        parameter_overrides: list[Any] | None = None,
        threads: int = 2,
    ) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        try:
            self.node = Node(
                node_name, context=self.context, namespace=namespace, parameter_overrides=parameter_overrides or []
            )
        except BaseException:
            self.context.try_shutdown()
            raise
        self.executor = MultiThreadedExecutor(num_threads=threads, context=self.context)
        self.executor.add_node(self.node)
        self._closed = False
        self._thread = threading.Thread(target=self._spin, name=f"ros2-{node_name}", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except ExternalShutdownException:  # the context shut down under the spin
            pass
        except InvalidHandle:  # close() shut the executor down while a callback's guard condition fired
            if not self._closed:
                raise

    def now_s(self) -> float:
        """The node's clock (the graph's time stamps), s."""
        return self.node.get_clock().now().nanoseconds * 1e-9

    def topic_types(self) -> dict[str, list[str]]:
        return dict(self.node.get_topic_names_and_types())

    def close(self) -> None:
        """Stop the executor, destroy the node, shut the context down; idempotent."""
        if self._closed:
            return
        self._closed = True
        self.executor.shutdown(timeout_sec=10.0)
        self._thread.join(timeout=10.0)  # the spin has returned: nothing uses the node any more
        self.node.destroy_node()
        self.context.try_shutdown()
