"""Build the parts a run needs from a `Config`: robot, camera, extraction, online estimator, outputs.

The only place the app knows the other layers' config classes; each section
(``[robot]``, ``[camera]``, ``[marker]``) is validated by its owner's
dataclass, which rejects unknown keys naming them.
"""

from __future__ import annotations

import numpy as np

from app.config import Config
from app.pipeline import Measurement


def make_measure(cfg: Config):
    """``measure(frame) -> Measurement`` for the configured target (``[marker]``).

    Raises ``ExtractionError`` (marker not found, bad depth) so the caller skips the frame.
    """
    from calib.vision.extract import TargetConfig, extract

    target = TargetConfig.from_dict(cfg.marker)

    def measure(frame) -> Measurement:
        m = extract(frame.color, frame.depth, frame.intrinsics, target)
        info = {k: float(v) for k, v in m.info.items() if isinstance(v, (int, float, np.floating, np.integer))}
        return Measurement(m.point_cam, m.point_cov, m.T_cam_marker, m.pose_cov,
                           pixel=(float(m.center_px[0]), float(m.center_px[1])),
                           meta={"marker_kind": m.kind, "extract": info})

    return measure
