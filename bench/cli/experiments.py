"""``gridflow cube``, ``cube-variants``, ``leaf``, ``peers``: the rendered scenes' experiments
(:mod:`gridflow.bench.cube_experiment`, :mod:`gridflow.bench.cube_variants`,
:mod:`gridflow.bench.leaf_experiment`) and the peer methods on the same data
(:mod:`gridflow.bench.peers`)."""

from __future__ import annotations

from ._common import positive_int

__all__ = ["register"]


def _float(v) -> str:
    return f"{v:.3g}"


def cmd_cube(a) -> int:
    from gridflow.scenes import CubeScene

    from ..cube_experiment import run_cube_experiment

    scene = CubeScene(width=a.size, height=a.size, grid=(a.grid, a.grid), frames=a.frames,
                      spotlight=not a.no_spotlight, texture_scale=a.texture_scale)
    r = run_cube_experiment(scene, a.cache, csv=a.csv, fig_dir=a.fig_dir, doc=a.write_doc,
                            sigma=a.sigma, window=a.window, progress=not a.no_progress,
                            temporal_radius=a.temporal_radius, methods=a.methods or (),
                            method_cmds=a.method_cmds or ())
    print(f"scene {r.folder}: rendered {r.rendered} images in {r.render_seconds} s "
          f"(this run: {r.seconds_render:.1f} s)")
    print(f"estimated bcc, hf, full (sigma {a.sigma:g}, {a.window} taps) in "
          f"{r.seconds_estimate:.1f} s")
    print(r.table.to_string(index=False, float_format=_float))
    for c in r.checks:
        print(f"observation {c['observation']}, {c['face']} face: {c['check']}: "
              f"{'holds' if c['holds'] else 'does not hold'}")
    for p in r.written:
        print(f"wrote {p}")
    return 0


def cmd_cube_variants(a) -> int:
    from ..cube_variants import cube_variants_study

    df, written = cube_variants_study(a.cache, csv=a.csv, doc=a.write_doc,
                                      progress=not a.no_progress)
    print(df.to_string(index=False, float_format=_float))
    for p in written:
        print(f"wrote {p}")
    return 0


def cmd_leaf(a) -> int:
    from gridflow.scenes import LeafScene

    from ..leaf_experiment import run_leaf_experiment

    r = run_leaf_experiment(LeafScene(growth=a.growth), a.cache, csv=a.csv,
                            fig_dir=a.fig_dir, sigma=a.sigma, window=a.window,
                            progress=not a.no_progress, methods=a.methods or (),
                            method_cmds=a.method_cmds or ())
    print(f"scene {r.folder} ({r.seconds_render:.1f} s to render or find); estimated "
          f"translation and affine motion, bcc, hf, full in {r.seconds_estimate:.1f} s")
    print(r.table.to_string(index=False, float_format=_float))
    for p in r.written:
        print(f"wrote {p}")
    return 0


def cmd_peers(a) -> int:
    from ..peers import compare_peers

    r = compare_peers(a.cache, csv_depth=a.csv_depth, csv_motion=a.csv_motion,
                      fig_dir=a.fig_dir, write_hci=a.write_hci, hci=a.hci, env=a.peers_env,
                      progress=not a.no_progress)
    print(r.label)
    print(r.depth.drop(columns="scene").to_string(index=False,
                                                  float_format=lambda v: f"{v:.4g}"))
    wide = r.motion.pivot_table(index=["data", "quantity"], columns="method", values="q",
                                sort=False)
    print("motion: Eq. 22 of the image flow (px/frame; relative where the truth keeps one "
          "sign, else absolute)")
    print(wide.to_string(float_format=_float))
    secs = r.motion.groupby(["data", "method"], sort=False).seconds.first().unstack()
    print("seconds per volume (gridflow: the three models together)")
    print(secs.to_string(float_format=lambda v: f"{v:.2f}"))
    for p in r.written:
        print(f"wrote {p}")
    if r.hci is not None:
        desc, table = r.hci
        print(f"{desc}:")
        print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return 0


def _cache_arg(p) -> None:
    from gridflow.scenes import RENDER_CACHE

    p.add_argument("--cache", default=RENDER_CACHE,
                   help=f"render cache folder: each scene is rendered once (default "
                        f"{RENDER_CACHE})")


def _add_cube(sub) -> None:
    from gridflow.estimator import DEFAULTS
    from gridflow.scenes import CubeScene

    from ..cube_experiment import CUBE_SIGMA, CUBE_WINDOW

    d = CubeScene()
    p = sub.add_parser("cube", help="render the cube (POV-Ray), estimate, Fig. 1 and cube.csv",
                       description="Render the cube of Sec. 4.2 (POV-Ray), estimate the "
                                   "three models, score each face (cube.csv), check "
                                   "observations 11 and 12 and draw Fig. 1.")
    p.add_argument("--size", type=positive_int, default=d.width,
                   help=f"image width = height, px (default {d.width})")
    p.add_argument("--grid", type=positive_int, default=d.grid[0],
                   help=f"cameras per side, odd (default {d.grid[0]})")
    p.add_argument("--frames", type=positive_int, default=d.frames,
                   help=f"time instances (default {d.frames})")
    _cache_arg(p)
    p.add_argument("--sigma", type=float, default=CUBE_SIGMA,
                   help=f"the window's Gaussian sigma, px (default {CUBE_SIGMA:g}: the 67-px left "
                        f"face of a 256-px image needs a smaller window than the "
                        f"sinusoid's {DEFAULTS['sigma']:g})")
    p.add_argument("--window", type=int, default=CUBE_WINDOW,
                   help=f"the window's Gaussian taps, px (default {CUBE_WINDOW})")
    p.add_argument("--temporal-radius", type=positive_int, default=None, metavar="R",
                   help="Omega over frames -R..R (default: the estimator's, 2 for 9 frames)")
    p.add_argument("--texture-scale", type=float, default=d.texture_scale, metavar="MM",
                   help=f"the noise texture's feature size, mm (default "
                        f"{d.texture_scale:g}: ~6 px)")
    p.add_argument("--no-spotlight", action="store_true",
                   help="ambient and a fixed light only (isolates the spotlight's effect)")
    p.add_argument("--csv", default="results/cube.csv",
                   help="per-face error table to write (default results/cube.csv)")
    p.add_argument("--fig-dir", default="results/figures",
                   help="where fig1.{png,pdf} go (default results/figures)")
    p.add_argument("--write-doc", help="markdown file whose cube section to rewrite")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _method_args(p, "per face and region")
    p.set_defaults(func=cmd_cube)


def _add_cube_variants(sub) -> None:
    p = sub.add_parser("cube-variants",
                       help="what sets the cube's motion directions: window, image size, "
                            "Omega in time, spotlight, texture varied one at a time",
                       description="What sets the cube's motion directions: the window, "
                                   "the image size, Omega in time, the spotlight and the "
                                   "texture varied one at a time (full model).")
    _cache_arg(p)
    p.add_argument("--csv", default="results/cube_variants.csv",
                   help="per-variant table to write (default results/cube_variants.csv)")
    p.add_argument("--write-doc", help="markdown file whose cube-variants section to rewrite")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_cube_variants)


def _add_leaf(sub) -> None:
    from gridflow.scenes import LeafScene

    from ..cube_experiment import CUBE_SIGMA, CUBE_WINDOW

    d = LeafScene()
    p = sub.add_parser("leaf", help="render a growing leaf (POV-Ray), estimate its growth "
                                    "map, per-region table and figure",
                       description=f"Render a growing leaf (POV-Ray, {d.frames} frames), "
                                   "estimate it "
                                   "with translation and affine motion and every model, "
                                   "and score the growth map per region.")
    p.add_argument("--growth", type=float, default=d.growth,
                   help=f"relative area growth, per frame (default {d.growth:g})")
    _cache_arg(p)
    p.add_argument("--sigma", type=float, default=CUBE_SIGMA,
                   help=f"the window's Gaussian sigma, px (default {CUBE_SIGMA:g}, as the cube's)")
    p.add_argument("--window", type=int, default=CUBE_WINDOW,
                   help=f"the window's Gaussian taps, px (default {CUBE_WINDOW})")
    p.add_argument("--csv", default="results/leaf.csv",
                   help="per-region table to write (default results/leaf.csv)")
    p.add_argument("--fig-dir", default="results/figures",
                   help="where fig_leaf.{png,pdf} go (default results/figures)")
    _method_args(p, "per region")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_leaf)


def _add_peers(sub) -> None:
    from ..peers import PEERS_ENV

    p = sub.add_parser("peers", help="gridflow and peer methods on the same data: depth on "
                                     "a light field, motion on sinusoids and the cube",
                       description="gridflow and peer methods on the same data: depth on "
                                   "the cube's light field, motion on sinusoids and the "
                                   "cube (needs the 'peers' extra).")
    _cache_arg(p)
    p.add_argument("--csv-depth", default="results/peers_depth.csv",
                   help="depth table to write (default results/peers_depth.csv)")
    p.add_argument("--csv-motion", default="results/peers_motion.csv",
                   help="motion table to write (default results/peers_motion.csv)")
    p.add_argument("--fig-dir", default="results/figures",
                   help="where peers_depth.{png,pdf} go (default results/figures)")
    p.add_argument("--write-hci", metavar="FOLDER",
                   help="also write the cube light field as an HCI scene")
    p.add_argument("--hci", metavar="SCENE",
                   help="also score the depth methods on an HCI scene (printed only)")
    p.add_argument("--peers-env", default=PEERS_ENV, metavar="VENV",
                   help=f"with --hci: the environment depthy and plenpy run in (default "
                        f"{PEERS_ENV}, made by make peers-env); without it they are left "
                        f"out with a message")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_peers)


def _method_args(p, scored: str) -> None:
    p.add_argument("--method", dest="methods", action="append", metavar="METHOD",
                   help="also run this method (MODULE:FUNCTION or an entry point of "
                        "gridflow.methods; the README, 'Benchmark your own method'), scored "
                        f"{scored} alike; repeat for several")
    p.add_argument("--method-cmd", dest="method_cmds", action="append", metavar="CMD",
                   help="also run this program ('PROG {input} {output}')")


def register(sub) -> None:
    """The commands cube, cube-variants, leaf, peers."""
    _add_cube(sub)
    _add_cube_variants(sub)
    _add_leaf(sub)
    _add_peers(sub)
