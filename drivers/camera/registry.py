"""The camera backends by name (``[camera] backend``): ``CAMERAS.create(config)`` builds one.

Backends register with ``@CAMERAS.register(name, ConfigClass)`` on their camera
class (`drivers.camera.openni2`: ``"openni2"``; the simulators
`mocks.render.camera`: ``"rendered"`` and `mocks.recorded`: ``"recorded"``).
"""

from drivers.registry import Registry

CAMERAS = Registry("camera", "backend")
