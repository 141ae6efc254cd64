"""One process's link to a ROS 2 graph: its own rclpy context, one node, an executor thread and a listening thread.

Each link is independent (its own context), so a driver's link closes without touching another's. The
graph is the environment's: ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE and RMW_IMPLEMENTATION.

The topics a link listens to (`Link.listen`: joint states, measurements) are not spun by rclpy's executor: it
builds its wait set anew from every entity of the node at each wake-up (NAO's joint states at 100 Hz: 0.85 ms of CPU
a message, 8.5% of a core; 6 joints at a real arm's 500 Hz, 20%; the GIL held meanwhile). The listening thread waits
on those subscriptions alone and takes every message that came: 0.43 ms and 0.15 ms a message
(benchmarks/ros2_listen.py). The executor keeps what needs it: services, clients, timers and a publisher's events.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.callback_groups import CallbackGroup
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription

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


class _Listened(CallbackGroup):
    """The listened subscriptions' group: the executor leaves them out of its wait set (the link's listening
    thread takes their messages)."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


class Link:
    """A node on the graph, spun by an executor in a daemon thread until close(): a single-threaded one unless
    `threads` > 1 (a node whose callbacks may stall, as the simulated robot's parameter service). rclpy's
    multi-threaded executor spins hot under a stream of messages: it yields a task it has handed to its pool
    again until a worker starts it, and hands it over again each time (a desk meeting a 100 Hz joint stream
    spent a whole core on it, and its other threads waited for the GIL).

    Listeners of one topic (same type and QoS) share one subscription, which stays until close(): destroying a
    subscription while the executor spins can kill its thread (InvalidHandle, rclpy's executor reads the
    handles of the node's subscriptions between its wait and its dispatch). So the connection check's listeners
    stop when it has met the robot, and the driver's joint states come through the same subscription. Their
    callbacks run in the link's listening thread, one message after another in the order each topic's came."""

    def __init__(
        self,
        node_name: str,
        *,
        namespace: str | None = None,
        parameter_overrides: list[Any] | None = None,
        threads: int = 1,
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
        self.executor = (
            MultiThreadedExecutor(num_threads=threads, context=self.context)
            if threads > 1
            else SingleThreadedExecutor(context=self.context)
        )
        self.executor.add_node(self.node)
        self._closed = False
        self._lock = threading.Lock()
        self._topics: list[tuple[str, Any, QoSProfile, list[Callable[[Any], None]]]] = []
        self._listened = _Listened()
        self._subscriptions: list[Subscription[Any]] = []  # the listened ones, in the order of self._topics
        self._wake = GuardCondition(None, None, context=self.context)  # a new subscription, or close()
        self._thread = threading.Thread(target=self._spin, name=f"ros2-{node_name}", daemon=True)
        self._thread.start()
        self._listener = threading.Thread(target=self._listen, name=f"ros2-listen-{node_name}", daemon=True)
        self._listener.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except ExternalShutdownException:  # the context shut down under the spin
            pass
        except InvalidHandle:  # close() shut the executor down while a callback's guard condition fired
            if not self._closed:
                raise

    def _listen(self) -> None:
        """The listening thread: waits on the listened subscriptions and takes every message that came. The wait set
        is rclpy's own (rclpy.impl), as its executors use it: rclpy 9 wraps it in nothing public."""
        count, wait_set = -1, None
        while not self._closed:
            with self._lock:
                subscriptions = list(self._subscriptions)
                listeners = [t[3] for t in self._topics]
            if len(subscriptions) != count:
                count = len(subscriptions)
                with self.context.handle:
                    wait_set = _rclpy.WaitSet(count, 1, 0, 0, 0, 0, self.context.handle)
            assert wait_set is not None
            wait_set.clear_entities()
            for sub in subscriptions:
                wait_set.add_subscription(sub.handle)
            wait_set.add_guard_condition(self._wake.handle)
            wait_set.wait(-1)
            for k, sub in enumerate(subscriptions):
                if not wait_set.is_ready("subscription", k):
                    continue
                while not self._closed and (taken := sub.handle.take_message(sub.msg_type, sub.raw)) is not None:
                    self._dispatch(listeners[k], taken[0])

    def listen(self, msg_type: Any, topic: str, qos: QoSProfile, callback: Callable[[Any], None]) -> Callable[[], None]:
        """Call `callback` with each message on `topic` (in the link's listening thread) until the returned stop() is
        called."""
        with self._lock:
            entry = next((t for t in self._topics if t[:3] == (topic, msg_type, qos)), None)
            if entry is None:
                entry = (topic, msg_type, qos, [])
                self._topics.append(entry)
                sub = self.node.create_subscription(msg_type, topic, _unused, qos, callback_group=self._listened)
                self._subscriptions.append(sub)
                self._wake.trigger()
            entry[3].append(callback)

        def stop() -> None:
            with self._lock:
                if callback in entry[3]:
                    entry[3].remove(callback)

        return stop

    def _dispatch(self, listeners: list[Callable[[Any], None]], msg: Any) -> None:
        with self._lock:
            now = list(listeners)
        for callback in now:
            callback(msg)

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
        self._wake.trigger()
        self._listener.join(timeout=10.0)
        self.executor.shutdown(timeout_sec=10.0)
        self._thread.join(timeout=10.0)  # the spin has returned: nothing uses the node any more
        self._wake.destroy()
        self.node.destroy_node()
        self.context.try_shutdown()


def _unused(msg: Any) -> None:
    """A listened subscription's callback: never called (the listening thread dispatches its messages)."""
