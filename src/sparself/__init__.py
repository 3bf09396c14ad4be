"""sparself: densify sparse photo captures with novel views for better 3D reconstruction."""

__version__ = "0.1.0"
