"""The camera transform for a UR robot program, over RTDE registers, and the version the program reports back.

The monitor gives the calibration in use to the program that picks with the
camera (docs/monitor-service.md, "The robot program"). ur_rtde's
``RTDEIOInterface`` writes the input registers of one range only (18-22),
five integers and five doubles, so the transform goes as:

| register | holds |
|---|---|
| ``input_double_register_18..20`` | rotation vector rx, ry, rz (rad) |
| ``input_int_register_19..21`` | translation x, y, z (um, integers: 0.5 um rounding) |
| ``input_int_register_18`` | its version (written last) |
| ``output_int_register_18`` | the version the program has taken (the program writes it) |

Nothing here moves the robot or uploads a program: the registers are the
controller's general-purpose ones, which the program reads when it wants.
"""

from __future__ import annotations

import json
import math
import os
import select
import subprocess
import sys

from handeye.drivers.errors import ConnectionLostError, DeviceError

VERSION_REGISTER = 18
TRANSLATION_REGISTERS = (19, 20, 21)
ROTATION_REGISTERS = (18, 19, 20)
TAKEN_REGISTER = 18
#: Translation unit on the integer registers (m per count).
TRANSLATION_UNIT_M = 1e-6


def encode(pose) -> tuple[list[int], list[float]]:
    """``(x, y, z, rx, ry, rz)`` (m, rad) as the integer translation (um) and the double rotation registers."""
    x, y, z, rx, ry, rz = (float(v) for v in pose)
    return [int(round(v / TRANSLATION_UNIT_M)) for v in (x, y, z)], [rx, ry, rz]


def decode(ints, doubles) -> list[float]:
    """The inverse of `encode`: ``[x, y, z, rx, ry, rz]`` (m, rad)."""
    return [float(v) * TRANSLATION_UNIT_M for v in ints] + [float(v) for v in doubles]


#: How long a request to the client process may take (s) before the connection counts as lost.
REQUEST_TIMEOUT_S = 3.0


class URCalibrationRegisters:
    """RTDE connection to the controller at ``host`` that writes the calibration registers and reads the version
    the program has taken (module docstring). Errors are `DeviceError` (cannot connect) or
    `ConnectionLostError` (a write or read failed: connect again).

    ur_rtde runs in a child process (as `handeye.drivers.robot.ur_client` does, for the same reason): after a dropped
    connection its teardown can abort the process that runs it. The child never tears down; it exits."""

    def __init__(self, host: str, frequency: float = 10.0):
        self.host, self.frequency = host, frequency
        self._proc: subprocess.Popen | None = None

    @property
    def is_connected(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def connect(self) -> None:
        self.close()
        # Its own session: a terminal's Ctrl-C is for the monitor, which closes this.
        self._proc = subprocess.Popen([sys.executable, "-m", "handeye.drivers.robot.ur_registers", self.host,
                                       str(self.frequency)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=subprocess.DEVNULL, text=True, start_new_session=True)
        try:
            self._answer()
        except ConnectionLostError as e:
            self.close()
            raise DeviceError(f"robot program registers on {self.host}: cannot open RTDE: {e}") from None

    def write(self, version: int, pose) -> None:
        """The transform, then its version (the program takes a version whose values are all written)."""
        ints, doubles = encode(pose)
        if not all(map(math.isfinite, doubles)):
            raise DeviceError(f"robot program registers: a rotation vector that is not finite: {doubles}")
        if not self._request({"op": "write", "version": int(version), "ints": ints, "doubles": doubles})["ok"]:
            raise ConnectionLostError(f"robot program registers on {self.host}: the controller did not take them")

    def taken(self) -> int:
        """The version the program reports in ``output_int_register_18`` (0: none yet)."""
        return int(self._request({"op": "taken"})["taken"])

    def _request(self, request: dict) -> dict:
        if not self.is_connected:
            raise ConnectionLostError(f"robot program registers on {self.host}: not connected")
        try:
            self._proc.stdin.write(json.dumps(request) + "\n")
            self._proc.stdin.flush()
        except OSError as e:
            self.close()
            raise ConnectionLostError(f"robot program registers on {self.host}: {e}") from None
        return self._answer()

    def _answer(self) -> dict:
        ready, _, _ = select.select([self._proc.stdout], [], [], REQUEST_TIMEOUT_S)
        line = self._proc.stdout.readline() if ready else ""
        answer = json.loads(line) if line.startswith("{") else {"error": "no answer" if ready else "timed out"}
        if "error" in answer:
            self.close()
            raise ConnectionLostError(f"robot program registers on {self.host}: {answer['error']}")
        return answer

    def close(self) -> None:
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            for pipe in (self._proc.stdin, self._proc.stdout):
                try:
                    pipe.close()
                except OSError:
                    pass
        self._proc = None


def _serve(host: str, frequency: float) -> None:
    """The child: one JSON request per line on stdin, one answer per line on stdout; on any error it says so and
    exits without ur_rtde's teardown."""
    import rtde_io
    import rtde_receive

    def say(answer: dict) -> None:
        print(json.dumps(answer), flush=True)

    try:
        io = rtde_io.RTDEIOInterface(host)
        receive = rtde_receive.RTDEReceiveInterface(host, frequency, [f"output_int_register_{TAKEN_REGISTER}"])
    except RuntimeError as e:
        say({"error": str(e)})
        os._exit(1)
    say({"ready": True})
    for line in sys.stdin:
        request = json.loads(line)
        try:
            if request["op"] == "write":
                ok = all([io.setInputDoubleRegister(r, v) for r, v in zip(ROTATION_REGISTERS, request["doubles"])]
                         + [io.setInputIntRegister(r, v) for r, v in zip(TRANSLATION_REGISTERS, request["ints"])])
                say({"ok": bool(ok and io.setInputIntRegister(VERSION_REGISTER, request["version"]))})
            elif not receive.isConnected():
                raise RuntimeError("the RTDE stream dropped")
            else:
                say({"taken": int(receive.getOutputIntRegister(TAKEN_REGISTER))})
        except RuntimeError as e:
            say({"error": str(e) or "RTDE failed"})
            os._exit(1)
    os._exit(0)


if __name__ == "__main__":
    _serve(sys.argv[1], float(sys.argv[2]))
