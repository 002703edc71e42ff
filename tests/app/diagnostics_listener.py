"""A separate process that listens to /diagnostics as a plant's ROS 2 tooling would (``ros2 topic echo``).

``python -m tests.app.diagnostics_listener OUT.jsonl SECONDS``: appends one JSON line per received
``DiagnosticStatus`` named ``handeye: camera calibration`` (level, message, values, receive time),
flushed as it arrives, until SECONDS have passed or stdin closes.
"""

import json
import sys
import threading
import time

from handeye.drivers.ros2 import Ros2Node, messages


def main(out: str, seconds: float) -> int:
    (DiagnosticArray,) = messages("diagnostic_msgs", "DiagnosticArray")
    done = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
    with open(out, "a") as f, Ros2Node("diagnostics_listener") as node:
        def on_array(msg) -> None:
            for s in msg.status:
                if s.name == "handeye: camera calibration":
                    f.write(json.dumps({"t": time.time(), "level": s.level[0], "message": s.message,
                                        "values": {kv.key: kv.value for kv in s.values}}) + "\n")
                    f.flush()

        node.node.create_subscription(DiagnosticArray, "/diagnostics", on_array, 50)
        print("listening", flush=True)
        done.wait(seconds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1], float(sys.argv[2])))
