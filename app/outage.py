"""A device that goes away is an outage, not an exit: reconnect with bounded exponential backoff.

Over a production shift a camera gets unplugged and plugged back, a robot
controller reboots or a switch drops the connection. `Reconnecting` holds one
device (a robot or camera of `app.devices.open_robot` / `open_camera`, not yet
connected) and runs every call on it through `Reconnecting.call`: a
`drivers.errors.DeviceError` starts an outage, the device is reopened in place
(``reconnect()`` where the driver has one, else ``disconnect()`` then
``connect()``) after waits of ``initial_s``, ``initial_s * factor``, ... up to
``max_s``, and the call is retried once it is back. The device object stays the
same, so whatever holds it (the camera follows the robot's flange pose) keeps
working. Each outage start, failed attempt and end goes to ``on_event`` (an
`OutageEvent`: the session's events, the console, MQTT), and a ``stop`` event
ends the wait at once (`OutageError`), as does an outage longer than
``max_outage_s`` when that is set.

Usage (the monitor loop)::

    with Reconnecting("robot", devices.open_robot(cfg, read_only=True), cfg.reconnect,
                      on_event=record, stop=stop) as robot, \\
         Reconnecting("camera", devices.open_camera(cfg, robot.device), cfg.reconnect,
                      on_event=record, stop=stop) as camera:
        state = robot.call(lambda r: r.read())
        frame = camera.call(lambda c: c.read())
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Generic, Literal, TypeVar

from pydantic import Field

from app.errors import OutageError
from calib.params import Float, NonNegativeFloat, Params, PositiveFloat
from drivers.errors import DeviceError

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
        Reconnect attempts so far in this outage.
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
        return f"{self.device} back after {self.outage_s:.1f} s ({self.attempt} reconnect attempts)"


def reopen(device) -> None:
    """Reconnect ``device`` in place: its ``reconnect()`` if it has one (the UR driver keeps a simulated
    controller running), else ``disconnect()`` (errors of a half-dead device ignored) and ``connect()``."""
    if callable(getattr(device, "reconnect", None)):
        device.reconnect()
        return
    try:
        device.disconnect()
    except DeviceError as e:
        log.debug("disconnect during an outage: %s", e)
    device.connect()


class Reconnecting(Generic[T]):
    """One device whose outages are ridden out (see the module docstring); a context manager.

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
        What counts as an outage (default every `DeviceError`).

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
        self.name, self.device, self.config = name, device, config
        self.on_event = on_event or (lambda e: log.warning(e.message()))
        self.stop = stop if stop is not None else threading.Event()
        self.clock = clock
        self.wait = wait or self.stop.wait
        self.retry_on = retry_on
        self.outages = 0
        self.in_outage = False

    def __enter__(self) -> "Reconnecting[T]":
        self.device.connect()
        return self

    def __exit__(self, *exc) -> bool:
        self.device.disconnect()
        return False

    def call(self, fn: Callable[[T], R]) -> R:
        """``fn(device)``; on an outage, reconnect (`recover`) and call again until it returns.

        Raises
        ------
        OutageError
            ``stop`` was set, or the outage outlasted ``max_outage_s``.
        """
        while True:
            try:
                return fn(self.device)
            except self.retry_on as e:
                self.recover(e)

    def recover(self, error: BaseException) -> None:
        """Ride out an outage that ``error`` began: reopen the device with backoff until it is back."""
        t0 = self.clock()
        self.in_outage = True
        self._emit("outage_start", str(error), 0, t0)
        cfg = self.config
        for attempt, delay in enumerate(cfg.delays(), start=1):
            if cfg.max_outage_s and self.clock() - t0 + delay > cfg.max_outage_s:
                self.in_outage = False
                raise OutageError(f"{self.name}: away for more than reconnect.max_outage_s = {cfg.max_outage_s:g} s "
                                  f"(last error: {error})")
            if self.stop.is_set() or (delay > 0 and self.wait(delay)):
                self.in_outage = False
                raise OutageError(f"{self.name}: stopped during an outage (last error: {error})")
            try:
                reopen(self.device)
            except self.retry_on as e:
                error = e
                self._emit("reconnect_failed", str(e), attempt, t0)
                continue
            self.in_outage = False
            self.outages += 1
            self._emit("outage_end", "", attempt, t0)
            return

    def _emit(self, event: str, error: str, attempt: int, t0: float) -> None:
        self.on_event(OutageEvent(self.name, event, time.time(), error, attempt, self.clock() - t0))
