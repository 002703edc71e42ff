"""Rendered RGB-D frames of a marker with known truth (a `Camera` selected by ``backend = "rendered"``)."""

from handeye.mocks.render.camera import RenderedCamera, RenderedCameraConfig
from handeye.mocks.render.scene import MarkerSceneRenderer, RenderNoise

__all__ = ["MarkerSceneRenderer", "RenderNoise", "RenderedCamera", "RenderedCameraConfig"]
