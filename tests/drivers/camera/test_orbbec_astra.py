"""Orbbec Astra through the OpenNI2 backend: Orbbec ships OpenNI2 itself, as a directory holding
``libOpenNI2.so`` and ``OpenNI2/Drivers/`` (with its ``liborbbec.so``), named by ``camera.library_dir``.

Without an Astra, a directory laid out like Orbbec's redistributable around the system OpenNI2 and its
drivers (the dummy device among them) shows the backend loads OpenNI2 from ``library_dir`` and streams.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SYSTEM = Path("/usr/lib/x86_64-linux-gnu")

# A child process, as in test_cameras: OpenNI2's dummy driver corrupts the heap once its color stream ran.
_SCRIPT = r"""
import json, os, sys
from handeye.drivers.camera.base import CameraIntrinsics
from handeye.drivers.camera.intrinsics import save_intrinsics
from handeye.drivers.camera.registry import CAMERAS
from handeye.drivers.camera import openni2  # registers "openni2"
from openni import openni2 as ni

save_intrinsics(sys.argv[2], CameraIntrinsics(320, 240, 285.0, 285.0, 159.5, 119.5))
cam = CAMERAS.create({"backend": "openni2", "uri": "Dummy", "width": 320, "height": 240, "registration": False,
                      "library_dir": sys.argv[1], "intrinsics_file": sys.argv[2]})
with cam:
    f = cam.read()
print(json.dumps({"loaded_from": str(ni.loaded_dll_directory),
                  "shape": list(f.depth.shape), "max_depth": float(f.depth.max())}), flush=True)
os._exit(0)
"""


@pytest.mark.skipif(not (SYSTEM / "libOpenNI2.so.0").exists() or not (SYSTEM / "OpenNI2" / "Drivers").is_dir(),
                    reason="libopenni2-0 not installed")
def test_openni2_loads_from_an_orbbec_style_library_dir(tmp_path):
    pytest.importorskip("openni")
    sdk = tmp_path / "OpenNI_2.3.0.86_Orbbec" / "Redist"
    sdk.mkdir(parents=True)
    (sdk / "libOpenNI2.so").symlink_to(SYSTEM / "libOpenNI2.so.0")
    (sdk / "OpenNI2").mkdir()
    (sdk / "OpenNI2" / "Drivers").symlink_to(SYSTEM / "OpenNI2" / "Drivers")
    proc = subprocess.run([sys.executable, "-c", _SCRIPT, str(sdk), str(tmp_path / "i.yaml")], capture_output=True,
                          text=True, timeout=60, cwd=Path(__file__).parents[3])
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["loaded_from"] == str(sdk)  # the library in library_dir, not the system's
    assert out["shape"] == [240, 320] and 0 < out["max_depth"] <= 10.0
