"""A device that goes away is an outage, not an exit: reconnect with bounded exponential backoff.

Over a production shift a camera gets unplugged and plugged back, a robot
controller reboots or a switch drops the connection. `Reconnecting` holds one
device (a robot or camera of `handeye.app.devices.open_robot` / `open_camera`, not yet
connected) and runs every call on it through `Reconnecting.call`: a
`handeye.drivers.errors.DeviceError` starts an outage, the device is reopened in place
(``reconnect()`` where the driver has one, else ``disconnect()`` then
``connect()``) after waits of ``initial_s``, ``initial_s * factor``, ... up to
``max_s``, and the call is retried once it is back. The device object stays the
same, so whatever holds it (the camera follows the robot's flange pose) keeps
working. Each outage start, failed attempt and end goes to ``on_event`` (an
`OutageEvent`: the session's events, the console, MQTT), and a ``stop`` event
ends the wait at once (`OutageError`), as does an outage longer than
``max_outage_s`` when that is set.

The wrapper stands in for its device (its methods go through `Reconnecting.call`), so the monitor
loop can hand it to code written for a device. Usage::

    with Reconnecting("robot", devices.open_robot(cfg, read_only=True), cfg.reconnect,
                      on_event=record, stop=stop) as robot, \\
         Reconnecting("camera", devices.open_camera(cfg, robot), cfg.reconnect,
                      on_event=record, stop=stop) as camera:
        state = robot.read()                    # rides out a dropped or frozen RTDE stream
        obs = take_sample(robot, camera, ...)   # and an unplugged camera, and the robot behind it
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Generic, Literal, TypeVar

from pydantic import Field

from handeye.app.errors import OutageError
from handeye.calib.params import Float, NonNegativeFloat, Params, PositiveFloat
from handeye.drivers.errors import DeviceError, PoseTimeError

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")


class ReconnectConfig(Params):
    """``[reconnect]``: how a long-running command waits for a device that went away.

    Attributes
    ----------
    initial_s : float
        Wait before the second reconnect attempt (the first is immediate), s.
    factor : float
        Each further wait is this many times the previous one ...
    max_s : float
        ... up to this, s.
    max_outage_s : float
        Give up (`OutageError`) after an outage this long, s; 0 = never (a
        service waits for its devices for as long as it runs).
    """

    initial_s: PositiveFloat = 0.5
    factor: Annotated[Float, Field(ge=1.0)] = 2.0
    max_s: PositiveFloat = 30.0
    max_outage_s: NonNegativeFloat = 0.0

    def delays(self):
        """The waits between attempts (s): 0, initial_s, initial_s * factor, ... capped at max_s."""
        yield 0.0
        d = self.initial_s
        while True:
            yield min(d, self.max_s)
            d = min(d * self.factor, self.max_s)


@dataclass(frozen=True)
class OutageEvent:
    """One step of an outage.

    Attributes
    ----------
    device : str
        The name given to `Reconnecting` (``"robot"``, ``"camera"``, ``"mqtt"``).
    event : str
        ``"outage_start"`` (the error that began it), ``"reconnect_failed"``
        (one attempt, its error) or ``"outage_end"`` (back; ``outage_s`` long).
    t : float
        Wall-clock time, ``time.time()``.
    error : str
        The device error (empty on ``outage_end``).
    attempt : int
        Reconnect attempts so far in this outage (0 where another library makes them: the MQTT client).
    outage_s : float
        Time since the outage started, s.
    """

    device: str
    event: Literal["outage_start", "reconnect_failed", "outage_end"]
    t: float
    error: str
    attempt: int
    outage_s: float

    def message(self) -> str:
        """One console / journal line."""
        if self.event == "outage_start":
            return f"{self.device} outage: {self.error}; reconnecting"
        if self.event == "reconnect_failed":
            return f"{self.device} still away after {self.outage_s:.1f} s (attempt {self.attempt}): {self.error}"
        attempts = f" ({self.attempt} reconnect attempts)" if self.attempt else ""
        return f"{self.device} back after {self.outage_s:.1f} s{attempts}"


class Reconnecting(Generic[T]):
    """One device whose outages are ridden out (see the module docstring); a context manager.

    It stands in for the device: a method called on it (``rc.read()``,
    ``rc.pose_at(t)``, ``rc.true_flange_pose()``) runs through `call`, any other
    attribute is the device's. So a camera can follow a robot wrapped in one
    (its flange-pose source then rides out the robot's outages too), and code
    written for a device takes the wrapper unchanged.

    Parameters
    ----------
    name : str
        Named in events and errors.
    device : Robot or Camera
        Not yet connected; `__enter__` connects it (an error there is raised: a
        device that is absent at the start is a configuration problem).
    config : ReconnectConfig
    on_event : callable(OutageEvent), optional
        Called for every outage step (default: logged).
    stop : threading.Event, optional
        Set from another thread (SIGTERM, Ctrl-C) to end an outage wait at once.
    clock, wait : callables, optional
        Monotonic clock and ``wait(seconds) -> stopped`` (tests); default
        ``time.monotonic`` and ``stop.wait``.
    retry_on : tuple of exception types
        What counts as an outage (default every `DeviceError`). A `PoseTimeError` never does: a robot pose
        asked for at a time its buffer does not hold is a question about the data; retried after a
        reconnect, whose buffer starts afresh, it could never be answered.

    Attributes
    ----------
    outages : int
        Outages ridden out so far.
    in_outage : bool
    """

    def __init__(self, name: str, device: T, config: ReconnectConfig, *,
                 on_event: Callable[[OutageEvent], None] | None = None, stop: threading.Event | None = None,
                 clock: Callable[[], float] = time.monotonic, wait: Callable[[float], bool] | None = None,
                 retry_on: tuple[type[BaseException], ...] = (DeviceError,)):
        # Names that devices use themselves (config, stop, clock ...) are spelled differently here, so
        # that the device's attributes show through (`__getattr__`).
        self.device_name, self.device, self.reconnect_config = name, device, config
        self.on_event = on_event or (lambda e: log.warning(e.message()))
        self.stop_event = stop if stop is not None else threading.Event()
        self.monotonic = clock
        self.wait_stop = wait or self.stop_event.wait
        self.retry_on = retry_on
        self.outages = 0
        self.in_outage = False

    def __getattr__(self, attr: str):
        value = getattr(self.device, attr)
        if not callable(value) or attr in ("connect", "disconnect", "reconnect"):
            return value
        return lambda *args, **kwargs: self.call(lambda d: getattr(d, attr)(*args, **kwargs))

    def __enter__(self) -> "Reconnecting[T]":
        self.device.connect()
        return self

    def __exit__(self, *exc) -> bool:
        self.device.disconnect()
        return False

    def call(self, fn: Callable[[T], R]) -> R:
        """``fn(device)``; on an outage, reopen the device with backoff and call again until it returns.

        The outage ends when ``fn`` succeeds again, not when the device reopens: a
        camera that opens but yields no frame (or whose flange-pose source is the
        dropped robot) stays in the outage, and the waits keep growing.

        Raises
        ------
        OutageError
            ``stop`` was set, or the outage outlasted ``max_outage_s``.
        PoseTimeError
            As the device raised it (the device answered: an outage it ends is over).
        """
        cfg = self.reconnect_config
        t0 = attempt = 0
        delays = None
        while True:
            try:
                result = fn(self.device)
            except PoseTimeError:
                self._end(delays, attempt, t0)
                raise
            except self.retry_on as e:
                if delays is None:
                    t0, delays, self.in_outage = self.monotonic(), cfg.delays(), True
                    self._emit("outage_start", str(e), 0, t0)
                else:
                    self._emit("reconnect_failed", str(e), attempt, t0)
                attempt = self._reopen(e, delays, attempt, t0)
                continue
            self._end(delays, attempt, t0)
            return result

    def _end(self, delays, attempt: int, t0: float) -> None:
        """The device answered: end the outage in progress, if any."""
        if delays is not None:
            self.in_outage = False
            self.outages += 1
            self._emit("outage_end", "", attempt, t0)

    def _reopen(self, error: BaseException, delays, attempt: int, t0: float) -> int:
        """Wait the next backoff step and reopen the device until that works; returns the attempt count."""
        cfg = self.reconnect_config
        for delay in delays:
            attempt += 1
            if cfg.max_outage_s and self.monotonic() - t0 + delay > cfg.max_outage_s:
                self.in_outage = False
                raise OutageError(f"{self.device_name}: away for more than reconnect.max_outage_s = "
                                  f"{cfg.max_outage_s:g} s (last error: {error})")
            if self.stop_event.is_set() or (delay > 0 and self.wait_stop(delay)):
                self.in_outage = False
                raise OutageError(f"{self.device_name}: stopped during an outage (last error: {error})")
            try:
                self.device.reconnect()
            except self.retry_on as e:
                error = e
                self._emit("reconnect_failed", str(e), attempt, t0)
                continue
            return attempt
        raise AssertionError("ReconnectConfig.delays never ends")

    def _emit(self, event: str, error: str, attempt: int, t0: float) -> None:
        self.on_event(OutageEvent(self.device_name, event, time.time(), error, attempt, self.monotonic() - t0))
