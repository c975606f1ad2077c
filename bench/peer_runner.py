"""Run one Python light-field depth package on an HCI scene, in its own environment.

    .venv-peers/bin/python bench/peer_runner.py {depthy|plenpy} SCENE_DIR OUT.npy

Run by :func:`gridflow.bench.peers.run_external` with the interpreter of the peers'
environment (``make peers-env``: versions pinned in ``requirements-peers.lock``), so it
imports nothing of gridflow.  Each package reads the scene's views (``input_Cam000.png
...``, view ``i`` at row ``i // n``, column ``i % n``) the way its own loader does and runs
its default disparity method for the centre view; the disparity is saved as float32
``(H, W)`` and one JSON line says the method, version, the call and its seconds.

Both defaults return the HCI sign and unit (px per camera step; a centre pixel of
disparity ``d`` appears in view ``(r, c)`` at ``(x - d (c - cc), y - d (r - cc))``):
checked on textured planes of disparity -0.5, 0.2, 0.5 and 1.0 px per view, whose
medians came out 0.97 d (depthy) and 0.93-0.94 d (plenpy).
"""

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np


def _paths(scene: Path) -> tuple[list[Path], int]:
    paths = sorted(scene.glob("input_Cam*.png"))
    n = int(round(len(paths) ** 0.5))
    if not paths or n * n != len(paths):
        sys.exit(f"{scene}: expected n x n views input_Cam000.png ..., found {len(paths)}")
    return paths, n


def run_depthy(scene: Path):
    import depthy
    from depthy.lightfield import epi_depth
    from depthy.misc import load_img_file, load_lf_arr

    paths, n = _paths(scene)
    first = load_img_file(str(paths[0]))
    # its own loader (as `depthy -s DIR` does): float32 in [0, 1], each view min-max
    # normalised, shape (n, n, H, W, C); it takes colour images only, so grey views get a
    # channel axis here
    if first.ndim == 3:
        lf = load_lf_arr([str(p) for p in paths])
    else:
        lf = np.stack([load_img_file(str(p)) for p in paths])[..., None]
        lf = lf.reshape((n, n) + lf.shape[1:])
    t0 = time.perf_counter()
    disp = epi_depth(lf)                # defaults: lf_wid=1, primal_opt=True, perc_clip=1
    secs = time.perf_counter() - t0
    return disp, depthy.__version__, "depthy.lightfield.epi_depth(lf)", secs


def run_plenpy(scene: Path):
    import imageio
    import plenpy
    from plenpy.lightfields import LightField

    paths, n = _paths(scene)
    # as LightField.from_file_collection does (which would also read the truth .pfm):
    # each view read by imageio, stacked (u, v, s, t, ch); uint8 becomes float in [0, 1]
    imgs = np.asarray([np.asarray(imageio.imread(p)) for p in paths])
    if imgs.ndim == 3:
        imgs = imgs[..., None]
    imgs = imgs[..., :3]
    lf = LightField(imgs.reshape((n, n) + imgs.shape[1:]))
    t0 = time.perf_counter()
    # defaults: method='structure_tensor', fusion_method='tv_l1', vmin=-3, vmax=3
    disp, _conf = lf.get_disparity()
    secs = time.perf_counter() - t0
    return disp, plenpy.__version__, "plenpy LightField(views).get_disparity()", secs


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 3 or argv[0] not in ("depthy", "plenpy"):
        sys.exit(__doc__)
    warnings.filterwarnings("ignore")
    pkg, scene, out = argv[0], Path(argv[1]), argv[2]
    disp, version, call, secs = (run_depthy if pkg == "depthy" else run_plenpy)(scene)
    np.save(out, np.squeeze(np.asarray(disp)).astype(np.float32))
    print(json.dumps({"package": pkg, "version": version, "call": call, "seconds": secs}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
