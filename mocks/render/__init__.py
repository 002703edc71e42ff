"""Rendered RGB-D frames of a marker with known truth (a `Camera` selected by ``backend = "rendered"``)."""

from mocks.render.camera import RenderedCamera, RenderedCameraConfig
from mocks.render.scene import MarkerSceneRenderer, RenderNoise

__all__ = ["MarkerSceneRenderer", "RenderNoise", "RenderedCamera", "RenderedCameraConfig"]
