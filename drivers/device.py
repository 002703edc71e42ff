"""What every device has in common: a connection, used as a context manager."""

from __future__ import annotations

import abc
import logging

from handeye.drivers.errors import DeviceError

log = logging.getLogger(__name__)


class Device(abc.ABC):
    """A device with a connection. ``with ROBOTS.create(cfg) as robot:`` connects and always disconnects.

    ``simulated`` is True for the simulators (`mocks`), which the demo may
    move without asking.
    """

    simulated: bool = False

    @abc.abstractmethod
    def connect(self) -> None: ...

    @abc.abstractmethod
    def disconnect(self) -> None: ...

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool: ...

    def identity(self) -> dict:
        """What identifies the connected device in a report, as far as it can read it (model, serial number,
        firmware or controller software: plain strings by name); ``{}`` when it can read nothing."""
        return {}

    def reconnect(self) -> None:
        """Connect again after the connection was lost: ``disconnect()`` (errors of a half-dead device
        ignored), then ``connect()``. A backend with more state to keep overrides this."""
        try:
            self.disconnect()
        except DeviceError as e:
            log.debug("disconnect during an outage: %s", e)
        self.connect()

    def __enter__(self):
        self.connect()
        return self

    def __exit__(self, *exc):
        self.disconnect()
        return False
