"""The robot backends by name (``[robot] type``): ``ROBOTS.create(config)`` builds one.

Backends register with ``@ROBOTS.register(name, ConfigClass)`` on their robot
class (`drivers.robot.ur`: ``"ur"``; the simulator `mocks.ur_sim.robot`:
``"ur_sim"``). A table without ``type`` means ``"ur"``.
"""

from drivers.registry import Registry

ROBOTS = Registry("robot", "type", default="ur")
