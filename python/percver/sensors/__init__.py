"""Canonical sensor models: first-principles measurement functions g_c of the state."""

from percver.sensors import camera, lidar

__all__ = ["camera", "lidar"]
