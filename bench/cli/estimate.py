"""``gridflow generate``, ``estimate``, ``evaluate``: a sinusoid volume, the estimate of any
source into any sink (:func:`gridflow.pipeline.estimate`), and its errors against the truth
(:mod:`gridflow.bench.single`)."""

from __future__ import annotations

from ._common import (add_estimator_args, add_sinusoid_args, dataclass_values,
                      estimator_settings, positive_int, print_lines, shear_range)

__all__ = ["register"]


def cmd_generate(a) -> int:
    from gridflow.generators import SinusoidParams

    from ..single import generate

    params = SinusoidParams(**dataclass_values(a, SinusoidParams))
    return print_lines(generate(params, output=a.output, hci=a.hci, float32=a.float32))


def cmd_estimate(a) -> int:
    from gridflow.estimator import METHODS

    if a.method == "gridflow":          # the sweep's name for the built-in estimator
        a.method = None
    if (a.method and a.method not in METHODS) or a.method_cmd:
        return _estimate_with_method(a)
    from gridflow.pipeline import RunOptions, estimate

    o = RunOptions(models=a.model, settings=estimator_settings(a), every=a.every,
                   first=a.first, last=a.last, views=a.views,
                   shears=None if a.shears is None else shear_range(a.shears),
                   select=a.select, fill=False if a.no_fill else None, median=a.median,
                   workers=a.workers, memory=a.memory, band_rows=a.band_rows,
                   connect=a.connect, mask=a.mask, progress=not a.no_progress)
    return print_lines(estimate(a.input, a.output, o).lines)


# estimate's options that only the built-in estimator reads
_BUILT_IN_ONLY = ("model", "motion", "sigma", "window", "filters", "temporal_radius",
                  "growth_support", "ref_frame", "no_slant_correction", "no_zoom_correction",
                  "combine", "views", "shears", "select", "median", "no_fill", "mask",
                  "every", "first", "last", "workers", "memory", "band_rows", "connect")


def _estimate_with_method(a) -> int:
    """--method / --method-cmd: another method's maps on the whole input, as an estimate
    .npz (:func:`gridflow.bench.methods.estimate_with_method`)."""
    from gridflow.errors import UsageError

    from ..methods import DEFAULT_TIMEOUT, command_method, estimate_with_method, load_method

    if a.method and a.method_cmd:
        raise UsageError("--method and --method-cmd exclude each other (one method per "
                         "estimate)")
    if not str(a.output).lower().endswith(".npz"):
        raise UsageError(f"-o {a.output}: --method and --method-cmd write an estimate .npz "
                         "(a map series runs the built-in estimator)")
    # the built-in estimator's options mean nothing to another method: refused, not ignored
    # given: anything but the parser's default (None, or False for a flag); 0 is given
    given = [f"--{k.replace('_', '-')}" for k in _BUILT_IN_ONLY
             if getattr(a, k, None) is not None and getattr(a, k) is not False]
    if a.method and a.method_timeout != DEFAULT_TIMEOUT:
        given.append("--method-timeout (a program's, --method-cmd)")
    if given:
        which = f"--method {a.method}" if a.method else "--method-cmd"
        raise UsageError(f"{which} runs another method on the whole input; "
                         f"{', '.join(given)} set(s) gridflow's built-in estimator only "
                         "(leave it out, or give the method its own settings)")
    from gridflow.estimator import METHODS

    from ..methods import MethodError

    try:
        m = (load_method(a.method) if a.method
             else command_method(a.method_cmd, a.method_timeout))
    except MethodError as exc:
        if a.method and ":" not in a.method:
            # perhaps a mistyped implementation
            raise MethodError(f"{exc}; or an implementation of gridflow's: "
                              f"{', '.join(METHODS)}") from None
        raise
    return print_lines(estimate_with_method(a.input, a.output, m))


def cmd_evaluate(a) -> int:
    from gridflow.metrics import eq22_table

    from ..single import evaluate_input

    r = evaluate_input(a.estimate, a.volume)
    if r.hci is not None:
        h = r.hci
        print(f"HCI benchmark scores of the disparity (the toolkit's rule: a 15-px border "
              f"left out, {h['n_pixels']} pixels scored; {h['n_nonfinite']} without a value, "
              f"left out of the MSE and not counted as bad): MSE x 100 = "
              f"{h['mse_x100']:.3f}, BadPix(0.07) = {h['badpix_007']:.2f} %, BadPix(0.03) = "
              f"{h['badpix_003']:.2f} %, BadPix(0.01) = {h['badpix_001']:.2f} %")
    print(f"model {r.model}: Eq. 22 over interior pixels with finite truth"
          + (" and the truth's own interior mask" if r.own_interior else ""))
    # Eq. 22: the relative error where the truth is non-zero (and of one sign), else the
    # absolute error
    print(eq22_table(r.rows))
    return 0


def _add_generate(sub) -> None:
    p = sub.add_parser("generate", help="render a sinusoid volume (.npz)",
                       description="Render a sinusoid volume (the paper's synthetic data, "
                                   "Sec. 4.1) with its truth, as .npz and/or an HCI scene.")
    add_sinusoid_args(p)
    p.add_argument("--float32", action="store_true",
                   help="store the volume as float32 (default float64)")
    p.add_argument("-o", "--output", help="output volume (.npz)")
    p.add_argument("--hci", metavar="FOLDER",
                   help="also (or only) write the reference frame's views as an HCI light "
                        "field scene (8-bit PNGs and gt_disp_lowres.pfm) for other tools")
    p.set_defaults(func=cmd_generate)


def _add_estimate(sub) -> None:
    from gridflow.estimator.lightfield import SELECTS

    p = sub.add_parser("estimate", help="estimate depth, slopes, motion, brightness",
                       description="Estimate depth, slopes, motion and brightness change "
                                   "from any source into any sink.")
    p.add_argument("input", help="a volume .npz, a camera-grid folder with grid.json, an HCI "
                                 "light field scene folder (input_Cam000.png ...) or a "
                                 "recording store (.zarr, gridflow record)")
    p.add_argument("--views", type=positive_int, default=None,
                   help="HCI scenes: the central VIEWS x VIEWS views to use (odd; default "
                        "all, or 5, what 5-tap camera filters reach, with --shears none or "
                        "--select coarse)")
    add_estimator_args(p)
    p.add_argument("--shears", nargs="+", default=None, metavar="MIN MAX",
                   help="a light field of one frame on a square grid is refocused by "
                        "default, over the range its parameters.cfg states, else one a "
                        "coarse pass estimates from the data (printed): 'auto' (the "
                        "default); MIN MAX: the integer disparities MIN..MAX (px per "
                        "view); 'none': the estimator's single pass, for disparities "
                        "within about +-1 px per view. A volume of several frames gets "
                        "the single pass")
    p.add_argument("--select", choices=SELECTS, default=None,
                   help="refocusing: each pixel's estimate chosen among 1-D camera "
                        "sub-grids along the centre row and column and shifted windows "
                        "('lines', the default: occlusions and thin structures), square "
                        "sub-grids ('occlusion'), or the shear nearest a coarse estimate "
                        "('coarse': meant for fine periodic texture, where a wrong "
                        "shear can alias, and smooth surfaces without thin structures, "
                        "where its wider window does better; bench/README.md measures "
                        "it worse than 'lines' on a periodic grid), or as 'lines' with "
                        "each segment of views fitted on its epipolar-plane images "
                        "('epi': structures a few px thin; bench/README.md measures it "
                        "better than 'lines' on each of its synthetic scenes, its "
                        "confidence less telling); docs/model.md")
    p.add_argument("--median", type=int, default=None, metavar="SIZE",
                   help="refocusing: a median of the disparity over SIZE x SIZE px after "
                        "the choice (default 3; 0: none): a pixel that disagrees with most of its "
                        "neighbours (a wrong shear, a fattened edge) takes theirs")
    p.add_argument("--no-fill", action="store_true",
                   help="refocusing: leave pixels without an estimate of their own NaN "
                        "(default: filled from their neighbours, marked in 'filled')")
    p.add_argument("--mask", default=None, metavar="auto|FILE",
                   help="the object's pixels (a leaf), so that each window uses only them "
                        "and pixels near its edge are measured (normalized convolution; "
                        "maps NaN off the object): 'auto' segments it per step from the "
                        "centre camera's image (Otsu's threshold, the largest part: an "
                        "object in front of a plain background), or a .npy or image file "
                        "of the reference camera's size, nonzero on the object (the same "
                        "for every step). Default: every pixel")
    p.add_argument("--no-progress", action="store_true",
                   help="no messages before long steps and no progress bar")
    from ..methods import DEFAULT_TIMEOUT

    o = p.add_argument_group("a program as the method instead of gridflow's (the README, "
                             "'Benchmark your own method'; --method takes a Python one); "
                             "writes an estimate .npz")
    o.add_argument("--method-cmd", default=None, metavar="CMD",
                   help="a program: 'PROGRAM ARGS {input} {output}' (reads the volume as an "
                        "interchange .npz at {input}, writes its maps as an .npz at "
                        "{output})")
    o.add_argument("--method-timeout", type=float, default=DEFAULT_TIMEOUT, metavar="S",
                   help=f"seconds the program may take (default {DEFAULT_TIMEOUT:g})")
    p.add_argument("-o", "--output", required=True,
                   help="output: an estimate .npz (one step, at --ref-frame or the input's "
                        "reference frame), or a map series MAPS.zarr (a step at every K-th "
                        "frame whose window fits); any input goes to either")
    _add_series_args(p)
    p.set_defaults(func=cmd_estimate)


def _add_series_args(p) -> None:
    r = p.add_argument_group("map series (-o MAPS.zarr: the estimate at every K-th frame, "
                             "out of core, on Dask, resumable; README: Long recordings)")
    r.add_argument("--every", type=positive_int, default=None, metavar="K",
                   help="frames between time steps (default 1)")
    r.add_argument("--first", type=int, default=None, metavar="FRAME",
                   help="frame of the first step (default the first whose window fits)")
    r.add_argument("--last", type=int, default=None, metavar="FRAME",
                   help="frame of the last step (default the last whose window fits)")
    r.add_argument("--workers", type=positive_int, default=None,
                   help="steps at once on this machine (default the cores, fewer where "
                        "--memory says so)")
    r.add_argument("--memory", type=float, default=None, metavar="GIB",
                   help="memory budget for the steps at once, GiB (default half the "
                        "machine's); a step whose frames exceed it is cut into row bands "
                        "that fit")
    r.add_argument("--band-rows", type=positive_int, default=None, metavar="N",
                   help="cut each step into row bands of N rows, each a task reading only "
                        "its rows and the filters' halo (default: whole steps, or the "
                        "widest bands --memory allows); the maps are the same")
    r.add_argument("--connect", default=None, metavar="ADDRESS",
                   help="a dask.distributed scheduler (tcp://HOST:PORT) whose workers see "
                        "the input and the store at the same paths (instead of --workers "
                        "and --memory, which are this machine's)")


def _add_evaluate(sub) -> None:
    p = sub.add_parser("evaluate", help="print Q_rel / Q_abs (Eq. 22) per quantity",
                       description="Print the errors of an estimate against the truth: "
                                   "Q_rel / Q_abs (Eq. 22) per quantity, and the HCI "
                                   "benchmark's scores of a disparity.")
    p.add_argument("estimate", help="estimate .npz (gridflow estimate)")
    p.add_argument("volume", help="the truth: a volume .npz, a folder (camera grid, HCI "
                                  "scene) or a recording store with truth (at the "
                                  "estimate's reference frame)")
    p.set_defaults(func=cmd_evaluate)


def register(sub) -> None:
    """The commands generate, estimate, evaluate."""
    _add_generate(sub)
    _add_estimate(sub)
    _add_evaluate(sub)
