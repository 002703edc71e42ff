"""Backends by name: one `Registry` per device kind; each backend registers itself with a decorator.

A backend module defines its config class and its device class and registers
them under the name a config file uses::

    @CAMERAS.register("openni2", OpenNI2CameraConfig)
    class OpenNI2Camera(Camera): ...

`drivers` never imports `mocks`: the simulated backends register themselves
the same way when their module is imported, and the application imports every
backend module once (`handeye.app.backends`).
"""

from __future__ import annotations

from dataclasses import dataclass

from pydantic import ValidationError

from handeye.calib.errors import ParameterError
from handeye.calib.params import describe


@dataclass(frozen=True)
class Backend:
    """One registered backend: its name, config model (a `handeye.calib.params.Params` with a ``Literal``
    name field) and device class."""

    name: str
    config: type
    device: type


class Registry:
    """The backends of one device kind, selected by the table field ``key`` (default ``default``).

    Parameters
    ----------
    kind : str
        Device kind and config table name (``"robot"``, ``"camera"``).
    key : str
        Field of the table that names the backend (``"type"``, ``"backend"``).
    default : str, optional
        Backend of a table without ``key``.
    """

    def __init__(self, kind: str, key: str, default: str | None = None):
        self.kind = kind
        self.key = key
        self.default = default
        self._backends: dict[str, Backend] = {}

    def register(self, name: str, config: type):
        """Class decorator: register the decorated device class under ``name`` with its ``config`` class."""

        def decorate(device: type) -> type:
            known = self._backends.get(name)
            if known is not None and known.device is not device:
                raise ParameterError(f"{self.kind} backend {name!r} is registered twice "
                                     f"({known.device.__name__}, {device.__name__})")
            self._backends[name] = Backend(name, config, device)
            return device

        return decorate

    def names(self) -> list[str]:
        return sorted(self._backends)

    def backends(self) -> list[Backend]:
        return [self._backends[n] for n in self.names()]

    def get(self, name) -> Backend:
        """The backend called ``name``; `ParameterError` naming the known ones otherwise."""
        try:
            return self._backends[name]
        except (KeyError, TypeError):
            raise ParameterError(f"{self.kind}.{self.key} must be one of {self.names()}, got {name!r}") from None

    def of_config(self, config) -> Backend:
        """The backend whose config class ``config`` is an instance of (exactly)."""
        for backend in self._backends.values():
            if type(config) is backend.config:
                return backend
        raise ParameterError(f"no {self.kind} backend for a config of type {type(config).__name__}")

    def config_from_dict(self, data: dict):
        """Validate a config table into its backend's config model.

        Raises
        ------
        ParameterError
            Unknown backend, unknown key or a bad field, named as ``kind.field``.
        """
        if not isinstance(data, dict):
            raise ParameterError(f"[{self.kind}] must be a table, got {data!r}")
        backend = self.get(data.get(self.key, self.default))
        try:
            return backend.config.model_validate(data)
        except ValidationError as e:
            raise ParameterError(describe(e, self.kind)) from None

    def create(self, config, *args, **kwargs):
        """The (unconnected) device for a config object or table; extra arguments go to the device class."""
        if isinstance(config, dict):
            config = self.config_from_dict(config)
        return self.of_config(config).device(config, *args, **kwargs)
