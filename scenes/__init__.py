"""POV-Ray scene templates (the cube of Sec. 4.2) and their analytic ground truth."""

from .cube import FACE_NAMES, CubeScene, cube_truth, face_interior, scene_sdl

__all__ = ["CubeScene", "scene_sdl", "cube_truth", "face_interior", "FACE_NAMES"]
