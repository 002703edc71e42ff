"""ROS 2 through rclpy, for the backends that read topics and the monitor's diagnostics publisher.

The ROS 2 backends (`handeye.drivers.camera.ros2`, `handeye.drivers.robot.ros2`, `handeye.app.ros2`,
the simulated cell's nodes in `handeye.mocks.ros2_cell`) import rclpy only through
`import_rclpy`, when they connect, so that the rest of handeye runs without
it. rclpy comes from the ``ros-rclpy`` wheels with the Fast DDS middleware
(``pip install 'handeye[ros2]'``): no ROS installation is needed.

`Ros2Node` is one node of the process's single rclpy context, whose
callbacks run in one background executor thread: the context is created
with the first node and shut down with the last, and it never installs
signal handlers (Ctrl-C stays the application's ``KeyboardInterrupt``).
Which ROS graph the nodes join is ROS's own environment: ``ROS_DOMAIN_ID``
and ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (``LOCALHOST`` keeps DDS traffic on
this machine; the tests use it with a domain id of their own).

Time: a message's header stamp is ROS time, which without ``use_sim_time``
is the system clock, the ``time.time()`` clock every `drivers` frame and
robot state is stamped on.
"""

from __future__ import annotations

import collections
import logging
import re
import threading
import time
from collections.abc import Callable
from typing import Annotated

from pydantic import AfterValidator

from handeye.calib.params import NonEmptyStr
from handeye.drivers.errors import DeviceError

log = logging.getLogger(__name__)

INSTALL_HINT = ("pip install 'handeye[ros2]' (the ros-rclpy wheels with Fast DDS; no ROS installation "
                "needed)")


_TOPIC = re.compile(r"^(~/|/)?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
_NODE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _topic_name(name: str) -> str:
    if not _TOPIC.match(name):
        raise ValueError(f"{name!r} is not a ROS 2 topic name (letters, digits and _ between single /, "
                         "each part starting with a letter or _)")
    return name


def _node_name(name: str) -> str:
    if not _NODE.match(name):
        raise ValueError(f"{name!r} is not a ROS 2 node name (letters, digits and _, not starting with a digit)")
    return name


#: A topic name as a config field (``/camera/camera/color/image_raw``, ``~/camera_transform``).
TopicName = Annotated[NonEmptyStr, AfterValidator(_topic_name)]
#: A node name as a config field.
NodeName = Annotated[NonEmptyStr, AfterValidator(_node_name)]


def import_rclpy():
    """The ``rclpy`` module; `DeviceError` saying in one line how to install it when it is missing."""
    try:
        import rclpy
    except ImportError as e:
        raise DeviceError(f"ROS 2: cannot import rclpy ({e}); install it with {INSTALL_HINT}") from None
    return rclpy


def messages(package: str, *names: str) -> tuple:
    """The message classes ``names`` of ``package`` (``messages("sensor_msgs", "Image")``); `DeviceError`
    with the install line when the package's wheel is missing."""
    import importlib

    try:
        module = importlib.import_module(f"{package}.msg")
        return tuple(getattr(module, n) for n in names)
    except (ImportError, AttributeError) as e:
        raise DeviceError(f"ROS 2: no {package} messages ({e}); install them with {INSTALL_HINT}") from None


def stamp_seconds(header) -> float:
    """A ``std_msgs/Header``'s stamp in seconds (``time.time()`` clock)."""
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def set_stamp(header, t: float) -> None:
    """Set a ``std_msgs/Header``'s stamp to ``t`` seconds."""
    sec = int(t // 1)
    header.stamp.sec = sec
    header.stamp.nanosec = min(int(round((t - sec) * 1e9)), 999_999_999)


def spin_until_shutdown(executor) -> None:
    """Spin ``executor`` until it or its context shuts down.

    A node closed from another thread while the executor builds its wait set
    leaves a destroyed entity in that set: rclpy allows for it where it takes a
    message, not where it waits on a subscription's event handlers, and raises
    ``InvalidHandle``. That wait is dropped and the next one is built without
    the entity; ending the thread instead would leave every node of the process
    unspun (a loaded CI host: no message on any topic afterwards)."""
    from rclpy.exceptions import InvalidHandle
    from rclpy.executors import ExternalShutdownException

    while True:
        try:
            executor.spin()
            return
        except ExternalShutdownException:
            return
        except InvalidHandle:
            continue


class _Context:
    """The process's rclpy context and the executor thread spinning its nodes (reference-counted)."""

    lock = threading.Lock()
    users = 0
    context = None
    executor = None
    thread: threading.Thread | None = None

    @classmethod
    def acquire(cls):
        rclpy = import_rclpy()
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        with cls.lock:
            if cls.users == 0:
                context = rclpy.Context()
                try:
                    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
                except Exception as e:  # rclpy's own RCLError and friends: a broken middleware setup
                    raise DeviceError(f"ROS 2: rclpy.init failed: {e}") from None
                cls.context, cls.executor = context, SingleThreadedExecutor(context=context)
                cls.thread = threading.Thread(target=spin_until_shutdown, args=(cls.executor,),
                                              name="ros2-executor", daemon=True)
                cls.thread.start()
            cls.users += 1
            return cls.context, cls.executor

    @classmethod
    def release(cls) -> None:
        with cls.lock:
            cls.users -= 1
            if cls.users:
                return
            executor, context, thread = cls.executor, cls.context, cls.thread
            cls.executor = cls.context = cls.thread = None
        executor.shutdown(timeout_sec=2.0)
        context.try_shutdown()
        thread.join(2.0)


class Ros2Node:
    """One rclpy node in the process's context, spun by its executor thread; a context manager.

    Parameters
    ----------
    name : str
        The node's name (``ros2 node list``); its private topics are ``~/<topic>`` below it.
    """

    def __init__(self, name: str):
        self.name = name
        self.node = None

    def open(self) -> "Ros2Node":
        if self.node is not None:
            return self
        context, executor = _Context.acquire()
        try:
            from rclpy.node import Node

            # No /rosout: handeye logs to its own console and journal, and a node opened again under the same
            # name (a reconnect) would have rcl warn about its rosout publisher.
            self.node = Node(self.name, context=context, enable_rosout=False)
            executor.add_node(self.node)
        except Exception as e:  # a bad node name, a middleware failure
            self.node = None
            _Context.release()
            raise DeviceError(f"ROS 2: cannot create node {self.name!r}: {e}") from None
        return self

    def close(self) -> None:
        node, self.node = self.node, None
        if node is None:
            return
        executor = _Context.executor
        if executor is not None:
            executor.remove_node(node)
        node.destroy_node()
        _Context.release()

    def __enter__(self) -> "Ros2Node":
        return self.open()

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def subscribe(self, msg_type, topic: str, callback: Callable, *, depth: int = 5):
        """A subscription of ``topic`` keeping the newest ``depth`` messages: reliable when every publisher
        found is (a reliable publisher then resends what a loaded host drops: large images travel as many
        UDP fragments), best effort otherwise (it matches both kinds, as drivers publish either)."""
        return self.node.create_subscription(msg_type, topic, callback, qos(self.reliable(topic), depth))

    def reliable(self, topic: str) -> bool:
        """True when ``topic`` has publishers and all of them are reliable."""
        from rclpy.qos import ReliabilityPolicy

        infos = self.node.get_publishers_info_by_topic(self.resolve(topic))
        return bool(infos) and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)

    def wait_for_publishers(self, topics, timeout: float) -> list[str]:
        """Wait up to ``timeout`` s until every topic has a publisher (discovery takes a moment); returns the
        topics still without one."""
        deadline = time.monotonic() + timeout
        while True:
            missing = [t for t in topics if not self.publishers(t)]
            if not missing or time.monotonic() > deadline:
                return missing
            time.sleep(0.02)

    def publisher(self, msg_type, topic: str, *, reliable: bool = True, depth: int = 10, latched: bool = False):
        """A publisher of ``topic`` (``~/name``: below this node); ``latched``: transient-local, a subscriber
        that joins later gets the newest ``depth`` messages."""
        return self.node.create_publisher(msg_type, topic, qos(reliable, depth, latched))

    def publishers(self, topic: str) -> int:
        """How many publishers ``topic`` has in the graph this node sees."""
        return self.node.count_publishers(self.node.resolve_topic_name(topic))

    def resolve(self, topic: str) -> str:
        """``topic`` as the graph names it (``~/x`` -> ``/<node>/x``)."""
        return self.node.resolve_topic_name(topic)

    def timer(self, period_s: float, callback: Callable):
        """Call ``callback`` every ``period_s`` in the executor thread; returns the timer (`cancel_timer`)."""
        return self.node.create_timer(period_s, callback)

    def cancel_timer(self, timer) -> None:
        self.node.destroy_timer(timer)


def qos(reliable: bool, depth: int, latched: bool = False):
    """A keep-last QoS profile of ``depth`` messages, reliable or best effort, volatile or transient-local."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class SkipLog:
    """Counts the messages a subscriber drops, by reason, and logs the 1st, 10th, 100th ... of each
    (a publisher flooding out-of-order stamps must not flood the log)."""

    def __init__(self, what: str):
        self.what = what
        self.counts: collections.Counter = collections.Counter()

    def __call__(self, reason: str) -> None:
        self.counts[reason] += 1
        n = self.counts[reason]
        if n == 10 ** (len(str(n)) - 1):
            log.warning("%s: %d message%s skipped: %s", self.what, n, "s" if n > 1 else "", reason)


class NodeDevice:
    """The connection of a device that is one `Ros2Node` named by its config's ``node_name`` (mixed into the
    ROS 2 camera and robot before their base class)."""

    _node: Ros2Node | None = None

    def open_node(self) -> Ros2Node:
        self._node = Ros2Node(self.config.node_name).open()
        return self._node

    def disconnect(self) -> None:
        node, self._node = self._node, None
        if node is not None:
            node.close()

    @property
    def is_connected(self) -> bool:
        return self._node is not None
