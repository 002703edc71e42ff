"""The camera backends by name (``[camera] backend``): ``CAMERAS.create(config)`` builds one.

Backends register with ``@CAMERAS.register(name, ConfigClass)`` on their camera
class (`handeye.drivers.camera.openni2`: ``"openni2"``; the simulators
`handeye.mocks.render.camera`: ``"rendered"`` and `handeye.mocks.recorded`: ``"recorded"``).
"""

from handeye.drivers.registry import Registry

CAMERAS = Registry("camera", "backend")
