"""Every device backend the application can build.

Importing a backend module registers it by name (`handeye.drivers.robot.registry.ROBOTS`,
`handeye.drivers.camera.registry.CAMERAS`); `drivers` never imports the simulators,
so the application imports them here, once. Adding a backend is its module
plus one line below (docs/architecture.md has a worked example).
"""

from handeye.drivers.camera import openni2  # noqa: F401  camera "openni2"
from handeye.drivers.camera import realsense  # noqa: F401  camera "realsense"
from handeye.drivers.camera import ros2  # noqa: F401  camera "ros2"
from handeye.drivers.robot import ros2 as robot_ros2  # noqa: F401  robot "ros2"
from handeye.drivers.robot import ur  # noqa: F401  robot "ur"
from handeye.mocks import recorded  # noqa: F401  camera "recorded"
from handeye.mocks import ros2_cell  # noqa: F401  camera "ros2_sim", robot "ros2_sim"
from handeye.mocks.render import camera  # noqa: F401  camera "rendered"
from handeye.mocks.ur_sim import robot  # noqa: F401  robot "ur_sim"
