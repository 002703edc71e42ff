"""Marker detection and 3D lifting from RGB-D frames (image processing only, no device I/O)."""
