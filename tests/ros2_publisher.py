"""A driver stand-in the ROS 2 tests command from another process: it publishes what they ask, through DDS.

``python -m tests.ros2_publisher PREFIX`` creates the publishers of a camera (``PREFIX/color``,
``PREFIX/depth``, ``PREFIX/info``) and of ur_robot_driver (``PREFIX/joint_states``, ``PREFIX/pose``),
prints ``ready`` and then runs one JSON command per stdin line, answering a JSON line when done:

- ``{"cmd": "camera", "n": N, "rate": HZ, ...}``: N frames (160 x 120, colour rgb8, depth 16UC1 1 m,
  CameraInfo) at HZ; ``shuffle`` (stamps out of order), ``depth_frame`` (another frame_id),
  ``depth_offset_s`` (depth stamped off colour), ``stamp_offset_s`` (stamps off the clock);
  answers the stamps it published;
- ``{"cmd": "robot", "n": N, "rate": HZ, "q": [6], "qd": [6], "tcp_pose": [6 (UR pose)]}``: joint
  states and the TCP pose; ``names`` overrides the joint names;
- ``{"cmd": "quit"}``.

A command's stream starts once its topics have a subscriber (at most `MATCH_WAIT_S` later): a stream shorter
than a new node's discovery (seconds on a loaded machine) would otherwise be gone before the node under test
sees its first message.
"""

import json
import sys
import time

import numpy as np

from handeye.calib import transforms as tf
from handeye.drivers.camera.base import CameraIntrinsics
from handeye.drivers.robot.ros2 import UR_JOINTS
from handeye.drivers.ros2 import Ros2Node, messages
from handeye.mocks.ros2_cell import camera_info_message, image_message, joint_state_message, pose_message

INTR = CameraIntrinsics(160, 120, 140.0, 140.0, 79.5, 59.5)
MATCH_WAIT_S = 10.0


def main(prefix: str) -> int:
    Image, CameraInfo, JointState = messages("sensor_msgs", "Image", "CameraInfo", "JointState")
    PoseStamped, = messages("geometry_msgs", "PoseStamped")
    rng = np.random.default_rng(0)
    with Ros2Node("test_publisher") as node:
        pub = {k: node.publisher(t, f"{prefix}/{k}", depth=20) for k, t in
               (("color", Image), ("depth", Image), ("info", CameraInfo), ("joint_states", JointState),
                ("pose", PoseStamped))}
        color = rng.integers(0, 255, (INTR.height, INTR.width, 3), dtype=np.uint8)
        depth = np.full((INTR.height, INTR.width), 1000, np.uint16)
        print("ready", flush=True)
        for line in sys.stdin:
            cmd = json.loads(line)
            if cmd["cmd"] == "quit":
                break
            n, period = int(cmd["n"]), 1.0 / float(cmd["rate"])
            # The camera reads all three topics; the robot one of its two (the pose or the joint states).
            topics = [pub[k] for k in (("color", "depth", "info") if cmd["cmd"] == "camera" else
                                       ("joint_states", "pose"))]
            matched = all if cmd["cmd"] == "camera" else any
            deadline = time.monotonic() + MATCH_WAIT_S
            while not matched(p.get_subscription_count() for p in topics) and time.monotonic() < deadline:
                time.sleep(0.01)
            stamps = []
            for k in range(n):
                t = time.time() + cmd.get("stamp_offset_s", 0.0)
                if cmd.get("shuffle") and k % 3 == 2:
                    t -= 0.2  # every third message stamped before the ones already sent
                if cmd["cmd"] == "camera":
                    pub["info"].publish(camera_info_message(CameraInfo, INTR, t, "cam"))
                    pub["depth"].publish(image_message(Image, depth, "16UC1", t + cmd.get("depth_offset_s", 0.0),
                                                       cmd.get("depth_frame", "cam")))
                    pub["color"].publish(image_message(Image, color, "rgb8", t, "cam"))
                else:
                    pub["joint_states"].publish(joint_state_message(JointState, cmd["q"], cmd["qd"], t,
                                                                    cmd.get("names", UR_JOINTS)))
                    pub["pose"].publish(pose_message(PoseStamped, tf.from_ur_pose(np.asarray(cmd["tcp_pose"])),
                                                     t, "base"))
                stamps.append(t)
                time.sleep(period)
            print(json.dumps({"stamps": stamps}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1]))
