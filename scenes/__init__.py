"""Data source: the cube of Sec. 4.2 as a POV-Ray scene, its analytic ground truth, and
its rendering into a camera-grid image folder."""

from .cube import FACE_NAMES, CubeScene, cube_truth, face_interior, scene_sdl, spot_angle
from .leaf import (LEAF_TRUTH_NAMES, LeafRecording, LeafScene, UnevenLeafRecording, leaf_truth,
                   uneven_leaf_truth)
from .render import (IMAGE_PATTERN, RENDER_CACHE, PovrayMissing, RenderError, povray_binary,
                     render_cube, render_cube_lightfield)

__all__ = ["CubeScene", "LeafScene", "LeafRecording", "UnevenLeafRecording", "LEAF_TRUTH_NAMES",
           "leaf_truth", "uneven_leaf_truth", "scene_sdl", "cube_truth", "face_interior", "spot_angle", "FACE_NAMES",
           "render_cube", "render_cube_lightfield", "povray_binary", "PovrayMissing", "RenderError",
           "IMAGE_PATTERN", "RENDER_CACHE"]
