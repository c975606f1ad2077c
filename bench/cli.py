"""Command-line interface, the top floor of gridflow (imported by no other module).

Each command parses its arguments, calls one function of :mod:`gridflow.bench` and prints
what it reports: ``generate``, ``estimate``, ``evaluate`` (:mod:`gridflow.bench.single`),
``sweep`` (:mod:`gridflow.bench.sweep`), ``figures`` (:mod:`gridflow.bench.figures`),
``claims`` (:mod:`gridflow.bench.claims`), ``cube`` (:mod:`gridflow.bench.
cube_experiment`), ``peers`` (:mod:`gridflow.bench.peers`).  Choices and defaults come
from the library (:mod:`gridflow.estimator.settings` and the modules it names), so the
help cannot drift from what runs.  Errors about the user's input (:mod:`gridflow.errors`,
the estimator's ``InputError``, the operating system's) are printed in one line with exit
status 2; anything else is a bug and keeps its traceback.  Heavy libraries are imported
inside the commands that need them.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import fields
from pathlib import Path

__all__ = ["main", "build_parser"]


def _add_dataclass_args(g, cls) -> None:
    """One option per field of the parameter dataclass ``cls`` (``--wavelength-x``), its
    default in the help; None when not given (:func:`_dataclass_values`)."""
    from gridflow.generators.sinusoid import TEXTURES

    for fl in fields(cls):
        default = getattr(cls(), fl.name)
        flag = "--" + fl.name.replace("_", "-")
        if isinstance(default, tuple):
            g.add_argument(flag, type=type(default[0]), nargs=2, default=None,
                           metavar=("A", "B"), help=f"default {default[0]} {default[1]}")
        elif fl.name == "texture":
            g.add_argument(flag, choices=TEXTURES, default=None, help=f"default {default}")
        else:
            g.add_argument(flag, type=type(default), default=None, help=f"default {default}")


def _dataclass_values(a, cls) -> dict:
    """The fields of ``cls`` given on the command line (pairs as tuples)."""
    return {fl.name: tuple(v) if isinstance(v, list) else v for fl in fields(cls)
            if (v := getattr(a, fl.name, None)) is not None}


def _add_sinusoid_args(p: argparse.ArgumentParser) -> None:
    from gridflow.generators import SinusoidParams

    _add_dataclass_args(p.add_argument_group("sinusoid parameters (defaults: "
                                             "docs/reproduction.md)"), SinusoidParams)


def _add_estimator_args(p: argparse.ArgumentParser) -> None:
    from gridflow.estimator import COMBINE, DEFAULTS, FILTER_NAMES, METHODS, MOTIONS
    from gridflow.estimator.lightfield import SELECT_DEFAULTS

    lines, occl = SELECT_DEFAULTS["lines"], SELECT_DEFAULTS["coarse"]
    g = p.add_argument_group("estimator settings")
    g.add_argument("--model", type=_model_list, default=None,
                   help="brightness model: bcc, hf, full (default; bcc for a light field of "
                        "one frame), a comma-separated list, or 'all'; several models share "
                        "one structure tensor, and each is written to OUTPUT with _MODEL "
                        "before the suffix")
    g.add_argument("--motion", choices=MOTIONS, default=None,
                   help="motion model, whatever the output: the paper's translating patch "
                        "('translation', the default: the more precise motion where nothing "
                        "grows), or 'affine': a velocity varying across the surface, which "
                        "adds the maps growth (relative area rate, per frame), rotation "
                        "(rad per frame about the normal) and the slopes' rates Zx_t, Zy_t; "
                        "needs 5 frames; what gridflow growth reads (docs/model.md)")
    g.add_argument("--sigma", type=float, default=None,
                   help=f"Gaussian sigma, px (default {DEFAULTS['sigma']:g}; a refocused "
                        f"light field: {lines[0]:g}, or {occl[0]:g} with --select coarse)")
    g.add_argument("--window", type=int, default=None,
                   help=f"Gaussian taps (default {DEFAULTS['window']}; a refocused light "
                        f"field: {lines[1]}, or {occl[1]} with --select coarse)")
    g.add_argument("--filters", choices=FILTER_NAMES, default=None,
                   help=f"derivative filters (default {DEFAULTS['filters']})")
    g.add_argument("--temporal-radius", type=int, default=None,
                   help="frames either side of the reference frame in the window")
    g.add_argument("--ref-frame", type=int, default=None, help="reference frame index")
    g.add_argument("--method", choices=METHODS, default=None,
                   help=f"implementation (same results; default {DEFAULTS['method']})")
    g.add_argument("--no-slant-correction", action="store_true",
                   help="read U_Z as the paper does (no slant-motion correction)")
    g.add_argument("--no-zoom-correction", action="store_true",
                   help="read the data rows as the paper does (no zoom-blur correction; "
                        "docs/model.md)")
    g.add_argument("--combine", choices=COMBINE, default=None,
                   help="how the two estimates of v, z_x, z_y, u_z are combined "
                        f"(default {DEFAULTS['combine']})")


def _model_list(text: str) -> tuple[str, ...]:
    from gridflow.estimator import MODELS

    names = MODELS if text == "all" else tuple(t.strip() for t in text.split(","))
    bad = [t for t in names if t not in MODELS]
    if bad or not names or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"expected one of {', '.join(MODELS)}, a comma-separated list of them or "
            f"'all', got {text!r}")
    return tuple(names)


def _estimator_settings(a) -> dict:
    """The estimator settings given on the command line; those not given are left out and
    keep the library's defaults (or the light-field choice's), so that a refocused light
    field can refuse the single pass's settings instead of ignoring them."""
    s = dict(filters=a.filters, temporal_radius=a.temporal_radius, ref_frame=a.ref_frame,
             method=a.method, combine=a.combine, motion=a.motion, sigma=a.sigma,
             window=a.window)
    if a.no_slant_correction:
        s["slant_correction"] = False
    if a.no_zoom_correction:
        s["zoom_correction"] = False
    return {k: v for k, v in s.items() if v is not None}


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def _shear_range(values: list[str]):
    """``--shears MIN MAX`` (integers, px per view), ``--shears auto`` or ``--shears
    none``."""
    from gridflow.errors import UsageError

    if values in (["auto"], ["none"]):
        return values[0]
    try:
        lo, hi = (int(t) for t in values)
    except ValueError:
        raise UsageError(f"--shears: expected MIN MAX (two integers), 'auto' or 'none', got "
                         f"{' '.join(values)!r}") from None
    if lo > hi:
        raise UsageError(f"--shears: expected MIN <= MAX, got {lo} {hi}")
    return range(lo, hi + 1)          # spelt out only once checked against the views


def cmd_generate(a) -> int:
    from gridflow.generators import SinusoidParams

    from .single import generate

    for line in generate(SinusoidParams(**_dataclass_values(a, SinusoidParams)), output=a.output, hci=a.hci,
                         float32=a.float32):
        print(line)
    return 0


def cmd_estimate(a) -> int:
    from gridflow.pipeline import RunOptions, estimate

    o = RunOptions(models=a.model, settings=_estimator_settings(a), every=a.every,
                   first=a.first, last=a.last, views=a.views,
                   shears=None if a.shears is None else _shear_range(a.shears),
                   select=a.select, fill=False if a.no_fill else None, median=a.median,
                   workers=a.workers, memory=a.memory, band_rows=a.band_rows,
                   connect=a.connect, progress=not a.no_progress)
    for line in estimate(a.input, a.output, o).lines:
        print(line)
    return 0


def cmd_record(a) -> int:
    from gridflow.generators.recording import RecordingParams

    from .recordings import make_recording

    params = RecordingParams(**_dataclass_values(a, RecordingParams))
    for line in make_recording(a.output, params,
                               progress=not a.no_progress):
        print(line)
    return 0


def cmd_record_leaf(a) -> int:
    from gridflow.scenes import LeafRecording

    from .recordings import make_leaf_recording

    scene = LeafRecording(frames=a.frames, width=a.size, height=a.size, grid=(a.grid, a.grid),
                          growth=a.growth, rhythm=a.rhythm, period=a.period,
                          spot_swing_deg=a.spot_swing, frame_interval=a.frame_interval,
                          margin=a.margin)
    for line in make_leaf_recording(a.output, scene, cache=a.cache,
                                    progress=not a.no_progress):
        print(line)
    return 0


def cmd_growth(a) -> int:
    from gridflow.io import check_output

    from gridflow.pipeline import draw_growth, growth_table

    if a.csv:
        check_output(a.csv, suffixes=".csv", inputs=[a.maps], what="--csv")
    check_output(a.fig_dir, suffixes=None, inputs=[a.maps], what="--fig-dir")
    table = growth_table(a.maps, a.truth)
    files = draw_growth(a.maps, table, a.fig_dir, times=a.times)
    pd_cols = ["frame", "median", "mean", "p10", "p90"] + (["truth", "q_rel"] if a.truth
                                                           else [])
    print(table[pd_cols].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if a.truth:
        print(f"Q_rel(growth) over the steps: median {table['q_rel'].median():.3g}, max "
              f"{table['q_rel'].max():.3g}; correlation with the truth: of the median "
              f"{table['median'].corr(table['truth']):.4f}, of the mean "
              f"{table['mean'].corr(table['truth']):.4f}")
    if a.csv:
        from gridflow.io import atomic_write

        with atomic_write(a.csv, "w") as fh:
            table.to_csv(fh, index=False, float_format="%.6g")
        files.append(Path(a.csv))
    for f in files:
        print(f"wrote {f}")
    return 0


def cmd_evaluate(a) -> int:
    from gridflow.metrics import eq22_table
    from .single import evaluate_input

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


def cmd_sweep(a) -> int:
    from gridflow.errors import UsageError
    from gridflow.io import check_output

    from .spec import SweepSpec, resolve_spec
    from .sweep import SweepInterrupted, run_sweep

    inputs = [resolve_spec(a.spec)] if a.spec else []
    check_output(a.output, suffixes=".csv", inputs=inputs, what="-o")
    check_output(Path(a.output).with_suffix(".json"), suffixes=".json", inputs=inputs,
                 what="the provenance sidecar of -o")
    if a.scheduler and a.workers:
        raise UsageError("--scheduler and --workers exclude each other (--workers starts a "
                         "local cluster)")
    if a.spec:
        spec = SweepSpec.from_toml(a.spec)
    else:
        from gridflow.estimator import MODELS

        spec = SweepSpec(name=a.name, models=list(MODELS), noise=[0.0], seeds=[0])
    if a.param or a.values:
        if not (a.param and a.values):
            raise UsageError("--param and --values go together")
        spec.axes = [(a.param, list(a.values))]
    for key in ("models", "motions", "noise", "seeds", "setup"):
        if getattr(a, key) is not None:
            setattr(spec, key, getattr(a, key))
    spec.validate(a.spec or "command line")
    n = len(spec.points())
    print(f"sweep {spec.name}: {n} points x {len(spec.models)} models -> {a.output}",
          file=sys.stderr)
    t0 = time.perf_counter()
    client = None
    if a.scheduler or a.workers:
        from gridflow.pipeline.executors import make_client

        client = make_client(a.scheduler, a.workers, timeout=a.connect_timeout)
        print(f"dask: {len(client.scheduler_info()['workers'])} workers", file=sys.stderr)
    try:
        df = run_sweep(spec, a.output, workers=a.processes, progress=not a.no_progress,
                       executor=client)
    except SweepInterrupted as exc:
        print(f"gridflow sweep: {exc}", file=sys.stderr)
        return 143 if exc.signal_name == "SIGTERM" else 130
    finally:
        if client is not None:
            client.close()
    print(f"wrote {a.output}: {len(df)} rows in {time.perf_counter() - t0:.1f} s",
          file=sys.stderr)
    return 0


def cmd_figures(a) -> int:
    from gridflow.errors import UsageError
    from gridflow.io import check_output

    from .figures import draw_figures
    from .sweep import read_sweep_csv

    out = check_output(a.out, suffixes=None, what="--out")
    if not all(c.isalnum() or c in "_.-" for c in a.suffix):
        raise UsageError(f"--suffix {a.suffix!r}: use letters, digits, '_', '.' and '-' only")
    if not (a.sweep or a.fig2):
        raise UsageError("nothing to draw: give --sweep CSV (Figs. 3, 4) and/or --fig2")
    df = read_sweep_csv(a.sweep) if a.sweep else None
    for p in draw_figures(out, sweep=df, fig2_too=a.fig2, suffix=a.suffix):
        print(f"wrote {p}")
    return 0


def cmd_claims(a) -> int:
    from gridflow.errors import UsageError
    from gridflow.io import atomic_write, check_output

    from .claims import check_claims, paper_terms, paper_terms_markdown, write_claims
    from .figures import setup_label
    from .markdown import rewrite_block
    from .sweep import read_sweep_csv

    if a.write_csv:
        if len(a.csv) > 1:
            raise UsageError("--write-csv takes the verdicts of one sweep; got "
                             f"{len(a.csv)} sweep CSVs (use --write-terms to compare them)")
        check_output(a.write_csv, suffixes=".csv", inputs=a.csv, what="--write-csv")
    if a.write_terms:
        check_output(a.write_terms, suffixes=".csv", inputs=a.csv, what="--write-terms")
    if a.write_doc:
        check_output(a.write_doc, suffixes=".md", inputs=a.csv, what="--write-doc")
    tables = {}
    for path in a.csv:
        df = read_sweep_csv(path)
        table = check_claims(df)
        setup = setup_label(df)
        label = setup.replace(" setup", "", 1)
        if label in tables:
            raise UsageError(f"{path}: a second sweep of the {label} setup; --write-terms "
                             "compares one sweep per setup")
        tables[label] = table
        print(f"{path} ({setup}):")
        print(table.to_string(index=False, columns=["id", "verdict", "parts", "numbers"],
                              max_colwidth=110))
        if a.write_doc or a.write_csv:
            names = df["sweep"].unique() if "sweep" in df else []
            tag = f"claims:{names[0]}" if len(names) == 1 else "claims"
            write_claims(table, doc=a.write_doc, csv=a.write_csv, source=path, tag=tag)
    if a.write_terms or (a.write_doc and len(a.csv) > 1):
        terms = paper_terms(tables)
        if terms.empty:
            raise UsageError("--write-terms: none of the sweeps tests the paper's "
                             "observations (a growth sweep has no paper terms)")
        if a.write_terms:
            with atomic_write(a.write_terms, "w") as fh:
                terms.to_csv(fh, index=False)
        if a.write_doc:
            rewrite_block(a.write_doc, "paper-terms",
                          paper_terms_markdown(terms, list(tables), " ".join(a.csv)))
    for p in (a.write_doc, a.write_csv, a.write_terms):
        if p:
            print(f"wrote {p}")
    return 0


def cmd_readings(a) -> int:
    from gridflow.errors import UsageError
    from gridflow.io import atomic_write, check_output

    from .markdown import rewrite_block
    from .readings import READINGS, readings_markdown, readings_table
    from .sweep import read_sweep_csv

    for path, what in ((a.csv_verdicts, "--csv-verdicts"), (a.csv_terms, "--csv-terms")):
        check_output(path, suffixes=".csv", inputs=a.csv, what=what)
    if a.write_doc:
        check_output(a.write_doc, suffixes=".md", inputs=a.csv, what="--write-doc")
    sweeps = {}
    for path in a.csv:
        df = read_sweep_csv(path)
        names = df["sweep"].unique() if "sweep" in df else []
        if len(names) != 1 or names[0] not in READINGS:
            raise UsageError(f"{path}: expected the sweep of one reading ("
                             f"{', '.join(READINGS)}), got {', '.join(map(str, names)) or 'none'}")
        sweeps[names[0]] = df
    verdicts, terms = readings_table(sweeps)
    with atomic_write(a.csv_verdicts, "w") as fh:
        verdicts.to_csv(fh, index=False)
    with atomic_write(a.csv_terms, "w") as fh:
        terms.to_csv(fh, index=False)
    print(verdicts.to_string(index=False, max_colwidth=100))
    print(f"wrote {a.csv_verdicts}, {a.csv_terms}")
    if a.write_doc:
        import pandas as pd

        # from the files as written, so that the doc and the CSVs agree digit for digit
        rewrite_block(a.write_doc, "readings", readings_markdown(
            pd.read_csv(a.csv_verdicts), pd.read_csv(a.csv_terms, keep_default_na=False)))
        print(f"wrote {a.write_doc}")
    return 0


def cmd_cube(a) -> int:
    from gridflow.io import check_output
    from gridflow.scenes import CubeScene

    from .cube_experiment import run_cube_experiment

    check_output(a.csv, suffixes=".csv", what="--csv")
    check_output(a.fig_dir, suffixes=None, what="--fig-dir")
    check_output(a.cache, suffixes=None, what="--cache")
    if a.write_doc:
        check_output(a.write_doc, suffixes=".md", what="--write-doc")
    scene = CubeScene(width=a.size, height=a.size, grid=(a.grid, a.grid), frames=a.frames,
                      spotlight=not a.no_spotlight, texture_scale=a.texture_scale)
    r = run_cube_experiment(scene, a.cache, csv=a.csv, fig_dir=a.fig_dir, doc=a.write_doc,
                            sigma=a.sigma, window=a.window, progress=not a.no_progress,
                            temporal_radius=a.temporal_radius)
    print(f"scene {r.folder}: rendered {r.rendered} images in {r.render_seconds} s "
          f"(this run: {r.seconds_render:.1f} s)")
    print(f"estimated bcc, hf, full (sigma {a.sigma:g}, {a.window} taps) in "
          f"{r.seconds_estimate:.1f} s")
    print(r.table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    for c in r.checks:
        print(f"observation {c['observation']}, {c['face']} face: {c['check']}: "
              f"{'holds' if c['holds'] else 'does not hold'}")
    for p in r.written:
        print(f"wrote {p}")
    return 0


def cmd_cube_variants(a) -> int:
    from gridflow.io import atomic_write, check_output

    from .cube_variants import run_cube_variants, variants_markdown
    from .markdown import rewrite_block

    check_output(a.csv, suffixes=".csv", what="--csv")
    check_output(a.cache, suffixes=None, what="--cache")
    if a.write_doc:
        check_output(a.write_doc, suffixes=".md", what="--write-doc")
    print("the cube in 6 variants, one option changed at a time: each scene rendered with "
          "POV-Ray once (cached in the --cache folder; 1-5 min each the first time) and "
          "estimated (full model)")
    df = run_cube_variants(a.cache, progress=not a.no_progress)
    with atomic_write(a.csv, "w") as fh:
        df.to_csv(fh, index=False, float_format="%.6g")
    print(df.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    print(f"wrote {a.csv}")
    if a.write_doc:
        # the markdown from the CSV as written, so the doc and the file agree digit for digit
        import pandas as pd
        rewrite_block(a.write_doc, "cube-variants", variants_markdown(pd.read_csv(a.csv)))
        print(f"wrote {a.write_doc}")
    return 0


def cmd_leaf(a) -> int:
    from gridflow.io import check_output
    from gridflow.scenes import LeafScene

    from .leaf_experiment import run_leaf_experiment

    check_output(a.csv, suffixes=".csv", what="--csv")
    check_output(a.fig_dir, suffixes=None, what="--fig-dir")
    check_output(a.cache, suffixes=None, what="--cache")
    scene = LeafScene(growth=a.growth)
    r = run_leaf_experiment(scene, a.cache, csv=a.csv, fig_dir=a.fig_dir, sigma=a.sigma,
                            window=a.window, progress=not a.no_progress)
    print(f"scene {r.folder} ({r.seconds_render:.1f} s to render or find); estimated "
          f"translation and affine motion, bcc, hf, full in {r.seconds_estimate:.1f} s")
    print(r.table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    for p in r.written:
        print(f"wrote {p}")
    return 0


def cmd_peers(a) -> int:
    from gridflow.errors import UsageError
    from gridflow.io import check_output

    try:                                # the optical-flow peers: the 'peers' extra
        import cv2  # noqa: F401
        import skimage.registration  # noqa: F401
    except ImportError as e:
        raise UsageError(f"gridflow peers needs the peer methods' packages ({e.name} is "
                         "missing): pip install 'gridflow[peers]'") from None

    from .peers import check_hci_scene, run_peers, score_hci_scene

    for path in (a.csv_depth, a.csv_motion):
        check_output(path, suffixes=".csv", what="output")
    check_output(a.fig_dir, suffixes=None, what="--fig-dir")
    # a bad --hci scene is refused before the minutes of the other peers and their files
    scene = check_hci_scene(a.hci) if a.hci else None
    r = run_peers(a.cache, csv_depth=a.csv_depth, csv_motion=a.csv_motion,
                  fig_dir=a.fig_dir, write_hci=a.write_hci, progress=not a.no_progress)
    print(r.label)
    print(r.depth.drop(columns="scene").to_string(index=False,
                                                  float_format=lambda v: f"{v:.4g}"))
    wide = r.motion.pivot_table(index=["data", "quantity"], columns="method", values="q",
                                sort=False)
    print("motion: Eq. 22 of the image flow (px/frame; relative where the truth keeps one "
          "sign, else absolute)")
    print(wide.to_string(float_format=lambda v: f"{v:.3g}"))
    secs = r.motion.groupby(["data", "method"], sort=False).seconds.first().unstack()
    print("seconds per volume (gridflow: the three models together)")
    print(secs.to_string(float_format=lambda v: f"{v:.2f}"))
    for p in r.written:
        print(f"wrote {p}")
    if a.hci:
        desc, table = score_hci_scene(a.hci, env=a.peers_env, progress=not a.no_progress,
                                      scene=scene)
        print(f"{desc}:")
        print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from gridflow import __version__
    from gridflow.estimator.lightfield import SELECTS

    from .setups import SETUPS

    ap = argparse.ArgumentParser(
        prog="gridflow",
        description="Surface motion, depth and slopes from a camera grid under changing "
                    "illumination (Schuchert & Scharr, DAGM 2007), and the benchmark that "
                    "reproduces the paper's figures.")
    ap.add_argument("--version", action="version", version=f"gridflow {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("generate", help="render a sinusoid volume (.npz)")
    _add_sinusoid_args(p)
    p.add_argument("--float32", action="store_true", help="store the volume as float32")
    p.add_argument("-o", "--output", help="output .npz")
    p.add_argument("--hci", metavar="FOLDER",
                   help="also (or only) write the reference frame's views as an HCI light "
                        "field scene (8-bit PNGs and gt_disp_lowres.pfm) for other tools")
    p.set_defaults(func=cmd_generate)

    p = sub.add_parser("estimate", help="estimate depth, slopes, motion, brightness")
    p.add_argument("input", help="a volume .npz, a camera-grid folder with grid.json, an HCI "
                                 "light field scene folder (input_Cam000.png ...) or a "
                                 "recording store (.zarr, gridflow record)")
    p.add_argument("--views", type=_positive_int, default=None,
                   help="HCI scenes: the central VIEWS x VIEWS views to use (odd; default "
                        "all, or 5, what 5-tap camera filters reach, with --shears none or "
                        "--select coarse)")
    _add_estimator_args(p)
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
                        "('coarse': fine periodic texture, where a wrong shear can "
                        "alias, and smooth surfaces without thin structures, where its "
                        "wider window does better); docs/model.md")
    p.add_argument("--median", type=int, default=None, metavar="SIZE",
                   help="refocusing: a SIZE x SIZE median of the disparity after the choice "
                        "(default 3; 0: none): a pixel that disagrees with most of its "
                        "neighbours (a wrong shear, a fattened edge) takes theirs")
    p.add_argument("--no-fill", action="store_true",
                   help="refocusing: leave pixels without an estimate of their own NaN "
                        "(default: filled from their neighbours, marked in 'filled')")
    p.add_argument("--no-progress", action="store_true",
                   help="no messages before long steps and no progress bar")
    p.add_argument("-o", "--output", required=True,
                   help="output: an estimate .npz (one step, at --ref-frame or the input's "
                        "reference frame), or a map series MAPS.zarr (a step at every K-th "
                        "frame whose window fits); any input goes to either")
    r = p.add_argument_group("map series (-o MAPS.zarr: the estimate at every K-th frame, "
                             "out of core, on Dask, resumable; README: Long recordings)")
    r.add_argument("--every", type=_positive_int, default=None, metavar="K",
                   help="frames between time steps (default 1)")
    r.add_argument("--first", type=int, default=None, metavar="FRAME",
                   help="frame of the first step (default the first whose window fits)")
    r.add_argument("--last", type=int, default=None, metavar="FRAME",
                   help="frame of the last step (default the last whose window fits)")
    r.add_argument("--workers", type=_positive_int, default=None,
                   help="steps at once on this machine (default the cores, fewer where "
                        "--memory says so)")
    r.add_argument("--memory", type=float, default=None, metavar="GIB",
                   help="memory budget for the steps at once (default half the machine's); "
                        "a step whose frames exceed it is cut into row bands that fit")
    r.add_argument("--band-rows", type=_positive_int, default=None, metavar="N",
                   help="cut each step into row bands of N rows, each a task reading only "
                        "its rows and the filters' halo (default: whole steps, or the "
                        "widest bands --memory allows); the maps are the same")
    r.add_argument("--connect", default=None, metavar="ADDRESS",
                   help="a dask.distributed scheduler (tcp://HOST:PORT) whose workers see "
                        "the input and the store at the same paths (instead of --workers "
                        "and --memory, which are this machine's)")
    p.set_defaults(func=cmd_estimate)

    p = sub.add_parser("record", help="render a synthetic growth recording (Zarr): a plane "
                                      "growing with a day/night rhythm, truth per frame")
    from gridflow.generators.recording import RecordingParams

    _add_dataclass_args(p, RecordingParams)
    p.add_argument("-o", "--output", required=True, help="output recording store (.zarr)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("record-leaf", help="render the POV-Ray leaf as a recording (Zarr): "
                                           "growing with a day/night rhythm under a "
                                           "swinging spotlight, truth per frame")
    from gridflow.scenes import LeafRecording

    d = LeafRecording()
    p.add_argument("--frames", type=_positive_int, default=d.frames,
                   help=f"time instances (default {d.frames})")
    p.add_argument("--size", type=_positive_int, default=d.width,
                   help=f"image width = height, px (default {d.width})")
    p.add_argument("--grid", type=_positive_int, default=d.grid[0],
                   help=f"cameras per side, odd (default {d.grid[0]})")
    p.add_argument("--growth", type=float, default=d.growth,
                   help=f"mean relative area rate per frame (default {d.growth:g})")
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
                   help=f"the growth truth is given this far inside the leaf's edge "
                        f"(default {d.margin:g}: the default window's radius)")
    p.add_argument("--cache", default="work/cube", help="render cache (default work/cube)")
    p.add_argument("-o", "--output", required=True, help="output recording store (.zarr)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_record_leaf)

    p = sub.add_parser("growth", help="a map series' growth: maps at chosen frames, the "
                                      "median over time with its spread and the mean (and "
                                      "against truth)")
    p.add_argument("maps", help="map series (.zarr) from gridflow estimate RECORDING -o MAPS.zarr "
                   "--motion affine")
    p.add_argument("--truth", metavar="RECORDING", help="a recording with growth truth per "
                   "frame (gridflow record): Q_rel per step")
    p.add_argument("--times", type=int, nargs="+", metavar="FRAME",
                   help="frames whose growth maps to draw (default six spread over the run)")
    p.add_argument("--fig-dir", default="growth", help="where growth_maps.png and "
                   "growth_series.png go (default ./growth)")
    p.add_argument("--csv", help="also write the per-step table")
    p.set_defaults(func=cmd_growth)

    p = sub.add_parser("evaluate", help="print Q_rel / Q_abs (Eq. 22) per quantity")
    p.add_argument("estimate", help="estimate .npz")
    p.add_argument("volume", help="volume .npz or folder with truth")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("sweep", help="run a parameter sweep, write a tidy CSV")
    p.add_argument("spec", nargs="?",
                   help="sweep spec: a TOML file, or the name of a shipped spec "
                        "('paper': the paper's sweeps; 'smoke': a seconds-long check)")
    p.add_argument("-o", "--output", required=True, help="output CSV")
    p.add_argument("--name", default="sweep", help="sweep name (without a spec)")
    p.add_argument("--param", help="parameter to sweep (replaces the spec's axes)")
    p.add_argument("--values", type=float, nargs="+", help="values of --param")
    p.add_argument("--models", nargs="+", help="models (default: all three)")
    p.add_argument("--motions", nargs="+",
                   help="motion models, each run with every model (default translation)")
    p.add_argument("--noise", type=float, nargs="+", help="noise levels sigma_n")
    p.add_argument("--seeds", type=int, nargs="+", help="noise seeds")
    p.add_argument("--setup", choices=sorted(SETUPS), default=None,
                   help="named setup the spec starts from (default: the spec's, else "
                        "gridflow; see bench/setups.py)")
    p.add_argument("--connect-timeout", type=float, default=10.0,
                   help="seconds to wait for --scheduler or --workers to answer (default 10)")
    p.add_argument("--processes", type=_positive_int, default=None,
                   help="size of the default in-process pool (default: all cores)")
    p.add_argument("--workers", type=_positive_int, default=None,
                   help="start a local dask.distributed cluster of N single-threaded workers")
    p.add_argument("--scheduler", help="address of a running dask scheduler (tcp://HOST:PORT)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("figures", help="draw Figs. 2-4 into a folder")
    p.add_argument("--sweep", help="sweep CSV for Figs. 3 and 4")
    p.add_argument("--fig2", action="store_true", help="draw Fig. 2")
    p.add_argument("--out", default="results/figures", help="folder (default results/figures)")
    p.add_argument("--suffix", default="", help="appended to the figure names (fig3SUFFIX.png)")
    p.set_defaults(func=cmd_figures)

    p = sub.add_parser("readings", help="the paper's observations under other readings of "
                                        "its unstated parameters, side by side")
    p.add_argument("csv", nargs="+", help="sweep CSVs of the readings (bench/readings.py)")
    p.add_argument("--csv-verdicts", default="results/readings_verdicts.csv",
                   help="verdict per reading and observation")
    p.add_argument("--csv-terms", default="results/readings.csv",
                   help="the paper's statements, gridflow's number under each reading")
    p.add_argument("--write-doc", help="markdown file whose readings section to rewrite")
    p.set_defaults(func=cmd_readings)

    p = sub.add_parser("cube", help="render the cube (POV-Ray), estimate, Fig. 1 and cube.csv")
    p.add_argument("--size", type=_positive_int, default=256, help="image width = height (default 256)")
    p.add_argument("--grid", type=_positive_int, default=5, help="cameras per side (default 5)")
    p.add_argument("--frames", type=_positive_int, default=9, help="frames (default 9)")
    p.add_argument("--cache", default="work/cube", help="render cache (default work/cube)")
    p.add_argument("--sigma", type=float, default=8.0,
                   help="window sigma, px (default 8: the 67-px left face of a 256-px image "
                        "needs a smaller window than the sinusoid's 16)")
    p.add_argument("--window", type=int, default=33, help="window taps (default 33)")
    p.add_argument("--temporal-radius", type=_positive_int, default=None, metavar="R",
                   help="Omega over frames -R..R (default: the estimator's, 2 for 9 frames)")
    p.add_argument("--texture-scale", type=float, default=4.0, metavar="MM",
                   help="the noise texture's feature size, mm (default 4: ~6 px)")
    p.add_argument("--no-spotlight", action="store_true",
                   help="ambient and a fixed light only (isolates the spotlight's effect)")
    p.add_argument("--csv", default="results/cube.csv", help="per-face error table")
    p.add_argument("--fig-dir", default="results/figures", help="where fig1.{png,pdf} go")
    p.add_argument("--write-doc", help="markdown file whose cube section to rewrite")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_cube)

    p = sub.add_parser("cube-variants",
                       help="what sets the cube's motion directions: window, image size, "
                            "Omega in time, spotlight, texture varied one at a time")
    p.add_argument("--cache", default="work/cube", help="render cache (default work/cube)")
    p.add_argument("--csv", default="results/cube_variants.csv",
                   help="per-variant table (default results/cube_variants.csv)")
    p.add_argument("--write-doc", help="markdown file whose cube-variants section to rewrite")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_cube_variants)

    p = sub.add_parser("leaf", help="render a growing leaf (POV-Ray), estimate its growth "
                                    "map, per-region table and figure")
    p.add_argument("--growth", type=float, default=2e-3,
                   help="relative area growth per frame (default 2e-3)")
    p.add_argument("--cache", default="work/cube", help="render cache (default work/cube)")
    p.add_argument("--sigma", type=float, default=8.0, help="window sigma, px (default 8)")
    p.add_argument("--window", type=int, default=33, help="window taps (default 33)")
    p.add_argument("--csv", default="results/leaf.csv", help="per-region table")
    p.add_argument("--fig-dir", default="results/figures", help="where fig_leaf.{png,pdf} go")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_leaf)

    p = sub.add_parser("peers", help="gridflow and peer methods on the same data: depth on "
                                     "a light field, motion on sinusoids and the cube")
    p.add_argument("--cache", default="work/cube", help="render cache (default work/cube)")
    p.add_argument("--csv-depth", default="results/peers_depth.csv")
    p.add_argument("--csv-motion", default="results/peers_motion.csv")
    p.add_argument("--fig-dir", default="results/figures", help="where peers_depth.{png,pdf} go")
    p.add_argument("--write-hci", metavar="FOLDER",
                   help="also write the cube light field as an HCI scene")
    p.add_argument("--hci", metavar="SCENE",
                   help="also score the depth methods on an HCI scene (printed only)")
    p.add_argument("--peers-env", default=".venv-peers", metavar="VENV",
                   help="with --hci: the environment depthy and plenpy run in (default "
                        ".venv-peers, made by make peers-env); without it they are left "
                        "out with a message")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_peers)

    p = sub.add_parser("claims", help="check the paper's observations 1-10 on a sweep CSV")
    p.add_argument("csv", nargs="+", help="sweep CSV (e.g. results/sweep_paper.csv); with "
                   "several (one per setup), the paper's statements side by side")
    p.add_argument("--write-doc", help="markdown file whose claims sections to rewrite "
                   "(and, with several sweeps, its paper-terms table)")
    p.add_argument("--write-csv", help="CSV of verdicts to write (one sweep)")
    p.add_argument("--write-terms", metavar="CSV", help="CSV of the paper's quantitative "
                   "statements with gridflow's number for each under each sweep's setup")
    p.set_defaults(func=cmd_claims)
    return ap


def _user_errors() -> tuple[type, ...]:
    """The exceptions that are about the user's input, not bugs in gridflow."""
    from gridflow.errors import GridflowError
    from gridflow.estimator import InputError
    from gridflow.scenes.render import PovrayMissing, RenderError

    from gridflow.pipeline.executors import ClusterError

    return (GridflowError, InputError, OSError, PovrayMissing, RenderError, ClusterError)


def main(argv=None) -> int:
    import logging

    ap = build_parser()
    a = ap.parse_args(argv)
    # the library reports long silent steps (first-run kernel compilation) at INFO level
    log = logging.getLogger("gridflow")
    if not log.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("gridflow: %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.INFO)
    from gridflow.pipeline.executors import Terminated, signals_raise

    try:
        # SIGTERM raises like Ctrl-C, so that a file being written is removed (atomic
        # writes) and the interruption reads as one line, not a traceback
        with signals_raise():
            return a.func(a)
    except _user_errors() as exc:
        print(f"gridflow {a.command}: error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Terminated) as exc:
        name = "SIGTERM" if isinstance(exc, Terminated) else "SIGINT"
        print(f"gridflow {a.command}: interrupted ({name}); outputs already written are "
              "complete, the one being written was not left behind", file=sys.stderr)
        return 143 if name == "SIGTERM" else 130


if __name__ == "__main__":
    sys.exit(main())
