"""``gridflow record``, ``record-leaf``, ``growth``: synthetic recordings with truth per
frame (:mod:`gridflow.bench.recordings`) and the growth report of a map series
(:func:`gridflow.pipeline.growth_report`)."""

from __future__ import annotations

import inspect

from ._common import add_dataclass_args, dataclass_values, positive_int, print_lines

__all__ = ["register"]


def cmd_record(a) -> int:
    from gridflow.generators.recording import RecordingParams

    from ..recordings import make_recording

    params = RecordingParams(**dataclass_values(a, RecordingParams))
    return print_lines(make_recording(a.output, params, progress=not a.no_progress))


def cmd_record_leaf(a) -> int:
    from gridflow.scenes import LeafRecording, UnevenLeafRecording

    from ..recordings import make_leaf_recording

    kind, extra = ((UnevenLeafRecording, {"tip_growth": a.tip_growth})
                   if a.tip_growth is not None else (LeafRecording, {}))
    scene = kind(**extra, frames=a.frames, width=a.size, height=a.size, grid=(a.grid, a.grid),
                          growth=a.growth, rhythm=a.rhythm, period=a.period,
                          spot_swing_deg=a.spot_swing, frame_interval=a.frame_interval,
                          margin=a.margin)
    return print_lines(make_leaf_recording(a.output, scene, cache=a.cache,
                                           progress=not a.no_progress))


def cmd_growth(a) -> int:
    from gridflow.pipeline import growth_report

    return print_lines(growth_report(a.maps, a.truth, fig_dir=a.fig_dir, csv=a.csv,
                                     times=a.times, profile_csv=a.profile_csv,
                                     axis=a.axis, sd_limit=a.sd_limit).lines)


def _add_record(sub) -> None:
    from gridflow.generators import SinusoidParams
    from gridflow.generators.recording import RecordingParams

    summary = inspect.getdoc(RecordingParams).splitlines()[0]
    p = sub.add_parser("record", help="render a synthetic growth recording (Zarr): a plane "
                                      "growing with a day/night rhythm, truth per frame",
                       description="Render a synthetic growth recording (Zarr): a textured "
                                   "plane growing with a day/night rhythm under a light "
                                   "that follows it, with truth per frame.")
    add_dataclass_args(p.add_argument_group("recording parameters", summary),
                       RecordingParams, fallback=SinusoidParams)
    p.add_argument("-o", "--output", required=True, help="output recording store (.zarr)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_record)


def _add_record_leaf(sub) -> None:
    from gridflow.estimator import DEFAULTS
    from gridflow.scenes import RENDER_CACHE, LeafRecording

    d = LeafRecording()
    p = sub.add_parser("record-leaf", help="render the POV-Ray leaf as a recording (Zarr): "
                                           "growing with a day/night rhythm under a "
                                           "swinging spotlight, truth per frame",
                       description="Render the POV-Ray leaf (scenes/leaf.py) as a recording "
                                   "(Zarr): growing with a day/night rhythm under a "
                                   "swinging spotlight, with truth per frame (depth, "
                                   "motion, and the growth on the leaf's interior).")
    p.add_argument("--frames", type=positive_int, default=d.frames,
                   help=f"time instances (default {d.frames})")
    p.add_argument("--size", type=positive_int, default=d.width,
                   help=f"image width = height, px (default {d.width})")
    p.add_argument("--grid", type=positive_int, default=d.grid[0],
                   help=f"cameras per side, odd (default {d.grid[0]})")
    p.add_argument("--growth", type=float, default=d.growth,
                   help=f"mean relative area rate, per frame (default {d.growth:g}); "
                        "with --tip-growth, the rate at the leaf's base")
    p.add_argument("--tip-growth", type=float, metavar="RATE",
                   help="grow unevenly: the relative area rate falls linearly along the "
                        "leaf from --growth at its base to this at its tip, per frame "
                        "(a mesh of material points; default: uniform growth)")
    p.add_argument("--rhythm", type=float, default=d.rhythm,
                   help=f"relative day/night amplitude of the rate, in [0, 1) "
                        f"(default {d.rhythm:g})")
    p.add_argument("--period", type=float, default=d.period,
                   help=f"frames per day (default {d.period:g})")
    p.add_argument("--spot-swing", type=float, default=d.spot_swing_deg, metavar="DEG",
                   help=f"the spotlight's azimuth amplitude over the day, degrees "
                        f"(default {d.spot_swing_deg:g})")
    p.add_argument("--frame-interval", type=float, default=d.frame_interval, metavar="S",
                   help=f"seconds between frames (default {d.frame_interval:g})")
    p.add_argument("--margin", type=float, default=d.margin, metavar="PX",
                   help=f"the growth truth is given on the leaf's pixels at least this far "
                        f"inside its edge in the centre camera's image, px, and is NaN "
                        f"nearer the edge, so that growth --truth scores only those "
                        f"(default {d.margin:g}; the default window has sigma "
                        f"{DEFAULTS['sigma']:g} px and reaches {DEFAULTS['window'] // 2} px)")
    p.add_argument("--cache", default=RENDER_CACHE,
                   help=f"render cache folder (default {RENDER_CACHE})")
    p.add_argument("-o", "--output", required=True, help="output recording store (.zarr)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_record_leaf)


def _add_growth(sub) -> None:
    p = sub.add_parser("growth", help="a map series' growth: the median over the interior "
                                      "per step with its spread and the mean (and against "
                                      "truth), maps at chosen frames",
                       description="The growth of a map series per step: the median over "
                                   "the interior (read the median: a few pixels where the "
                                   "estimate breaks down move the mean), its 10-90 % "
                                   "spread and the mean, in relative area per frame; with "
                                   "--truth, the truth and Q_rel (Eq. 22). Draws the growth "
                                   "maps at chosen frames and the median and mean against "
                                   "time.")
    p.add_argument("maps", help="map series (.zarr) from gridflow estimate RECORDING -o "
                                "MAPS.zarr --motion affine")
    p.add_argument("--truth", metavar="RECORDING", help="a recording with growth truth per "
                   "frame (gridflow record, record-leaf): Q_rel per step")
    p.add_argument("--times", type=int, nargs="+", metavar="FRAME",
                   help="frames whose growth maps to draw (default six spread over the run)")
    p.add_argument("--fig-dir", default="growth", help="where growth_maps.png, "
                   "growth_series.png and growth_kymograph.png go (default ./growth)")
    p.add_argument("--axis", choices=("x", "y"), default="x",
                   help="the leaf's axis in the image, for the growth profile along it "
                        "(the kymograph; default x: image columns)")
    p.add_argument("--profile-csv", metavar="CSV",
                   help="also write the growth profile along --axis per step (CSV: step, "
                        "frame, time_s (s), position_px, median (per frame), per_hour, "
                        "n_pixels)")
    p.add_argument("--csv", help="also write the observations table, a row per leaf and "
                                 "step (CSV: leaf, step, frame, time_s (s), mean, median, "
                                 "median_per_hour, p10, p90 (growth per frame over the "
                                 "leaf's confident pixels, the median also per hour), "
                                 "n_pixels (used), n_uncertain (left out); with --truth "
                                 "also truth, q_rel)")
    from gridflow.pipeline.growth import SD_LIMIT

    p.add_argument("--sd-limit", type=float, default=SD_LIMIT, metavar="K",
                   help="leave out the pixels whose growth_sd exceeds K times the step's "
                        f"median over the leaf (default {SD_LIMIT:g}; 0 keeps every pixel)")
    p.set_defaults(func=cmd_growth)


def register(sub) -> None:
    """The commands record, record-leaf, growth."""
    _add_record(sub)
    _add_record_leaf(sub)
    _add_growth(sub)
