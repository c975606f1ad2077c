"""Command-line interface, the top floor of gridflow (imported by no other module).

``gridflow generate | estimate | evaluate`` work on single volumes; ``gridflow sweep |
figures | claims | cube`` drive the benchmark.  Heavy libraries are imported inside the
commands that need them.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

__all__ = ["main"]


def _add_sinusoid_args(p: argparse.ArgumentParser) -> None:
    from gridflow.generators import SinusoidParams

    g = p.add_argument_group("sinusoid parameters (defaults: docs/reproduction.md)")
    for fl in fields(SinusoidParams):
        default = getattr(SinusoidParams(), fl.name)
        flag = "--" + fl.name.replace("_", "-")
        if isinstance(default, tuple):
            g.add_argument(flag, type=type(default[0]), nargs=2, default=None,
                           metavar=("A", "B"), help=f"default {default[0]} {default[1]}")
        elif fl.name == "texture":
            from gridflow.generators.sinusoid import TEXTURES

            g.add_argument(flag, choices=TEXTURES, default=None, help=f"default {default}")
        else:
            g.add_argument(flag, type=type(default), default=None, help=f"default {default}")


def _add_estimator_args(p: argparse.ArgumentParser) -> None:
    from gridflow.estimator.filters import FILTER_NAMES

    g = p.add_argument_group("estimator settings")
    g.add_argument("--model", type=_model_list, default=None,
                   help="brightness model: bcc, hf, full (default; bcc for a light field of "
                        "one frame), a comma-separated list, or 'all'; several models share "
                        "one structure tensor, and each is written to OUTPUT with _MODEL "
                        "before the suffix")
    g.add_argument("--sigma", type=float, default=None,
                   help="Gaussian sigma, px (default 16; with --shears 2, or 1 with "
                        "--select lines or occlusion)")
    g.add_argument("--window", type=int, default=None,
                   help="Gaussian taps (default 65; with --shears 9, or 5 with --select "
                        "lines or occlusion)")
    g.add_argument("--filters", choices=FILTER_NAMES, default="matched5",
                   help="derivative filters (default matched5)")
    g.add_argument("--temporal-radius", type=int, default=None,
                   help="frames either side of the reference frame in the window")
    g.add_argument("--ref-frame", type=int, default=None, help="reference frame index")
    g.add_argument("--method", choices=("fast", "grouped", "reference"), default="fast",
                   help="implementation (same results; default fast)")
    g.add_argument("--no-slant-correction", action="store_true",
                   help="read U_Z as the paper does (no slant-motion correction)")
    g.add_argument("--combine", choices=("inverse_variance", "mean"),
                   default="inverse_variance",
                   help="how the two estimates of v, z_x, z_y, u_z are combined "
                        "(default inverse_variance)")


_MODELS = ("bcc", "hf", "full")


def _model_list(text: str) -> tuple[str, ...]:
    names = _MODELS if text == "all" else tuple(t.strip() for t in text.split(","))
    bad = [t for t in names if t not in _MODELS]
    if bad or not names or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"expected one of {', '.join(_MODELS)}, a comma-separated list of them or "
            f"'all', got {text!r}")
    return tuple(names)


def _model_outputs(output: str, models) -> dict[str, Path]:
    """One model: OUTPUT itself; several: OUTPUT with _MODEL before the suffix."""
    out = Path(output)
    if len(models) == 1:
        return {models[0]: out}
    return {m: out.with_name(f"{out.stem}_{m}{out.suffix}") for m in models}


def _estimator_settings(a) -> dict:
    return dict(sigma=16.0 if a.sigma is None else a.sigma,
                window=65 if a.window is None else a.window, filters=a.filters,
                temporal_radius=a.temporal_radius, ref_frame=a.ref_frame, method=a.method,
                slant_correction=not a.no_slant_correction, combine=a.combine)


def _load_input(path: str, views: int | None = None):
    from gridflow.io import load_volume

    p = Path(path)
    if p.is_dir():
        from gridflow.hci import is_hci_scene, load_hci

        if is_hci_scene(p):                      # an HCI 4-D light field benchmark scene
            return load_hci(p, views=views)
        from gridflow.loader import load_folder  # camera-grid image folder with grid.json

        return load_folder(p)
    return load_volume(p)


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def cmd_generate(a) -> int:
    from gridflow.generators import make_sinusoid
    from gridflow.io import check_output, save_volume

    if not (a.output or a.hci):
        raise ValueError("give -o OUTPUT.npz, --hci FOLDER, or both")
    if a.output:
        check_output(a.output, suffixes=".npz", what="-o")
    over = {fl: getattr(a, fl) for fl in vars(a) if fl in _sinusoid_fields()
            and getattr(a, fl) is not None}
    over = {k: tuple(v) if isinstance(v, list) else v for k, v in over.items()}
    data = make_sinusoid(dtype=np.float32 if a.float32 else np.float64, **over)
    if a.hci:
        from gridflow.hci import write_hci

        p = data.params
        if p.grid[0] != p.grid[1] or p.spacing[0] != p.spacing[1]:
            raise ValueError(f"--hci needs a square grid with equal spacing, got grid "
                             f"{list(p.grid)} spacing {list(p.spacing)}")
        views = data.volume[p.ref_frame].astype(np.float64)
        lo, hi = float(views.min()), float(views.max())
        # 8-bit views of the reference frame; an affine map onto [0, 1] does not change
        # the disparity (parallel cameras: d = f ds / Z, px per camera step)
        views = (views - lo) / (hi - lo if hi > lo else 1.0)
        disparity = data.focal_length * p.spacing[0] / data.truth["Z"]
        files = write_hci(a.hci, views, disparity=disparity)
        print(f"wrote {a.hci}: {len(files)} files (HCI layout, {p.grid[0]}x{p.grid[1]} views "
              f"of frame {p.ref_frame}, disparity {disparity.min():.3g} .. "
              f"{disparity.max():.3g} px per view)")
    if a.output:
        save_volume(a.output, data)
        print(f"wrote {a.output}: volume {data.volume.shape} {data.volume.dtype}")
    return 0


def _sinusoid_fields():
    from gridflow.generators import SinusoidParams

    return {fl.name for fl in fields(SinusoidParams)}


def _shear_range(values: list[str]):
    """``--shears MIN MAX`` (integers, px per view) or ``--shears auto``."""
    if values == ["auto"]:
        return "auto"
    try:
        lo, hi = (int(t) for t in values)
    except ValueError:
        raise ValueError(f"--shears: expected MIN MAX (two integers) or 'auto', got "
                         f"{' '.join(values)!r}") from None
    if lo > hi:
        raise ValueError(f"--shears: expected MIN <= MAX, got {lo} {hi}")
    return tuple(range(lo, hi + 1))


def _stated_shears(meta: dict):
    """The integer shears covering the disparity range an HCI scene's ``parameters.cfg``
    states (``meta["hci"]["disp_range"]``), or None where it states none."""
    rng = (meta.get("hci") or {}).get("disp_range")
    if not rng:
        return None
    return tuple(range(int(np.floor(rng[0])), int(np.ceil(rng[1])) + 1))


def _estimate_refocused(a, data, output: str) -> int:
    """``gridflow estimate --shears``: a static light field refocused over integer shears."""
    from gridflow.estimator import Estimate
    from gridflow.estimator.lightfield import SELECT_DEFAULTS, estimate_refocused
    from gridflow.io import save_estimate

    T = data.volume.shape[0]
    if T != 1:
        raise ValueError(f"--shears refocuses a light field of one frame; {a.input} has "
                         f"{T} frames")
    if a.model not in (None, ("bcc",)):
        raise ValueError(f"--shears takes model bcc (a light field of one frame), got "
                         f"{','.join(a.model)}")
    geometry = data.meta.get("hci")
    shifts = a.shears
    if shifts == "auto":
        shifts = _stated_shears(data.meta)
        if shifts is None:
            raise ValueError(f"--shears auto: {a.input} states no disparity range "
                             "(parameters.cfg [meta] disp_min, disp_max); give MIN MAX")
    views = data.volume[0]
    if views.shape[0] != views.shape[1]:
        raise ValueError(f"--shears needs a square grid of views, {a.input} has "
                         f"{views.shape[0]}x{views.shape[1]}")
    sigma = SELECT_DEFAULTS[a.select][0] if a.sigma is None else a.sigma
    window = SELECT_DEFAULTS[a.select][1] if a.window is None else a.window
    t0 = time.perf_counter()
    res = estimate_refocused(views, shifts, sigma=sigma, window=window,
                             filters=a.filters, select=a.select, fill=True)
    dt = time.perf_counter() - t0
    d = res["disparity"]
    if geometry:
        from gridflow.hci import depth_from_disparity

        Z, units = depth_from_disparity(d, geometry), "m (HCI geometry)"
    else:
        # parallel cameras: disparity = -v ds_x with v = -f / Z
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = data.focal_length * data.camera_spacing[0] / d
        units = "as camera_spacing"
    maps = {"disparity": d, "Z": Z, "model_error": res["model_error"],
            "confidence": res["confidence"], "shear": res["shear"],
            "filled": res["filled"].astype(float)}
    est = Estimate(maps=maps, model="bcc", interior=res["valid"] | res["filled"],
                   settings={"shears": list(shifts), "select": a.select, "sigma": sigma,
                             "window": window, "filters": a.filters,
                             "views": list(views.shape[:2]), "Z_units": units})
    save_estimate(output, est)
    print(f"wrote {output}: {views.shape[0]}x{views.shape[1]} views refocused over shears "
          f"{list(shifts)} ({a.select}); {int(res['valid'].sum())} pixels estimated, "
          f"{int(res['filled'].sum())} filled from their neighbours ('filled')")
    print(f"estimated in {dt:.2f} s")
    return 0


def cmd_estimate(a) -> int:
    from gridflow.estimator import EstimatorSettings, estimate_models
    from gridflow.io import check_output, save_estimate

    settings = _estimator_settings(a)
    if a.shears is None:
        EstimatorSettings(**settings)           # bad settings fail before the volume loads
    else:
        a.shears = _shear_range(a.shears)
    views = a.views
    if views is None:
        # all views where the occlusion-aware shears use the outer ones, else what the
        # 5-tap camera filters reach
        views = None if (a.shears is not None and a.select != "coarse") else 5
    data = _load_input(a.input, views=views)
    if a.shears is not None:
        check_output(a.output, suffixes=".npz", inputs=[a.input], what="-o")
        return _estimate_refocused(a, data, a.output)
    if a.model is None:
        a.model = ("bcc",) if data.volume.shape[0] == 1 else ("full",)
    outputs = _model_outputs(a.output, a.model)
    for path in outputs.values():
        check_output(path, suffixes=".npz", inputs=[a.input], what="-o")
    if settings["ref_frame"] is None:
        # an image folder's grid.json may name its reference frame (--ref-frame overrides)
        settings["ref_frame"] = data.meta.get("ref_frame")
    t0 = time.perf_counter()
    ests = estimate_models(data.volume, data.focal_length, data.camera_spacing,
                           models=a.model, principal_point=data.principal_point, **settings)
    dt = time.perf_counter() - t0
    geometry = data.meta.get("hci")
    for m, est in ests.items():
        if geometry and "disparity" in est.maps:
            # converging HCI cameras: depth in metres from the disparity and the focus
            # distance (parameters.cfg); the slopes stay those of the parallel-camera
            # reading (camera steps as the unit of length)
            from gridflow.hci import depth_from_disparity

            est.maps["Z"] = depth_from_disparity(est.maps["disparity"], geometry)
            est.settings["Z_units"] = "m (HCI geometry)"
        save_estimate(outputs[m], est)
        n_ok = int(np.isfinite(est["Z"][est.interior]).sum())
        print(f"wrote {outputs[m]}: model {m}, {n_ok}/{int(est.interior.sum())} interior "
              f"pixels valid")
    print(f"estimated {', '.join(a.model)} in {dt:.2f} s")
    return 0


def cmd_evaluate(a) -> int:
    from gridflow.io import load_estimate
    from .metrics import evaluate

    maps, interior, meta = load_estimate(a.estimate)
    truth = dict(_load_input(a.volume, views=3).truth)
    if not truth:
        raise ValueError(f"{a.volume}: holds no truth maps to evaluate against")
    shape = next(iter(truth.values())).shape
    if interior.shape != shape:
        raise ValueError(f"{a.estimate}: maps of shape {interior.shape} do not match the truth "
                         f"of {a.volume} {shape}")
    # a truth map named 'interior' (the rendered cube has one: pixels away from the faces'
    # edges) restricts the evaluation further
    own = truth.pop("interior", None)
    if own is not None:
        interior = interior & own.astype(bool)
    rows = evaluate(maps, truth, interior)
    if not rows:
        raise ValueError(f"{a.estimate} and {a.volume} share no quantity names")
    if "disparity" in maps and "disparity" in truth:
        from .peers import hci_metrics

        h = hci_metrics(maps["disparity"], truth["disparity"])
        print(f"HCI benchmark scores of the disparity (15-px border left out, "
              f"{h['n_pixels']} pixels, {h['n_nonfinite']} not finite): MSE x 100 = "
              f"{h['mse_x100']:.3f}, BadPix(0.07) = {h['badpix_007']:.2f} %, BadPix(0.03) = "
              f"{h['badpix_003']:.2f} %, BadPix(0.01) = {h['badpix_001']:.2f} %")
    print(f"model {meta.get('model', '?')}: Eq. 22 over interior pixels with finite truth"
          + (" and the truth's own interior mask" if own is not None else ""))
    # Eq. 22: the relative error where the truth is non-zero (and of one sign), else the
    # absolute error; a relative error that is undefined is shown as '-'
    print(f"{'quantity':<9} {'Eq. 22':>11} {'measure':>7} {'Q_rel':>11} {'Q_abs':>11} "
          f"{'pixels':>8} {'invalid':>8}")
    for r in rows:
        rel = f"{r['q_rel']:>11.4g}" if np.isfinite(r["q_rel"]) else f"{'-':>11}"
        print(f"{r['quantity']:<9} {r['q']:>11.4g} {r['measure']:>7} {rel} "
              f"{r['q_abs']:>11.4g} {r['n_pixels']:>8d} {r['n_invalid']:>8d}")
    return 0


def cmd_sweep(a) -> int:
    from gridflow.io import check_output

    from .sweep import SpecError, SweepInterrupted, SweepSpec, resolve_spec, run_sweep

    inputs = [resolve_spec(a.spec)] if a.spec else []
    check_output(a.output, suffixes=".csv", inputs=inputs, what="-o")
    check_output(Path(a.output).with_suffix(".json"), suffixes=".json", inputs=inputs,
                 what="the provenance sidecar of -o")
    if a.scheduler and a.workers:
        raise SpecError("--scheduler and --workers exclude each other (--workers starts a "
                        "local cluster)")
    if a.spec:
        spec = SweepSpec.from_toml(a.spec)
    else:
        from gridflow.estimator import MODELS

        spec = SweepSpec(name=a.name, models=list(MODELS), noise=[0.0], seeds=[0])
    if a.param or a.values:
        if not (a.param and a.values):
            raise SpecError("--param and --values go together")
        spec.axes = [(a.param, list(a.values))]
    for key in ("models", "noise", "seeds", "setup"):
        if getattr(a, key) is not None:
            setattr(spec, key, getattr(a, key))
    spec.validate(a.spec or "command line")
    n = len(spec.points())
    print(f"sweep {spec.name}: {n} points x {len(spec.models)} models -> {a.output}",
          file=sys.stderr)
    t0 = time.perf_counter()
    client = None
    if a.scheduler or a.workers:
        from .distributed import make_client

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
    import pandas as pd

    from gridflow.generators import make_sinusoid

    from . import figures as F

    from gridflow.io import check_output

    out = check_output(a.out, suffixes=None, what="--out")
    if not all(c.isalnum() or c in "_.-" for c in a.suffix):
        raise ValueError(f"--suffix {a.suffix!r}: use letters, digits, '_', '.' and '-' only")
    if not (a.sweep or a.fig2):
        raise ValueError("nothing to draw: give --sweep CSV (Figs. 3, 4) and/or --fig2")
    written = []
    if a.sweep:
        df = _read_sweep_csv(a.sweep)
        label = ", ".join(f"sweep {n}" for n in df["sweep"].unique()) if "sweep" in df else ""
        written += F.save(F.fig3(df, label), out, "fig3" + a.suffix)
        written += F.save(F.fig4(df, label=label), out, "fig4" + a.suffix)
    if a.fig2:
        sv = make_sinusoid(a2=-0.2, a2x=-0.002)
        c = sv.volume.shape[1] // 2, sv.volume.shape[2] // 2
        k = sv.params.ref_frame
        T = sv.volume.shape[0]
        frames = [sv.volume[i, c[0], c[1]] for i in (0, k, T - 1)]
        titles = [f"(a) first frame, t = {-k}", "reference frame, t = 0",
                  f"(b) last frame, t = {T - 1 - k}"]
        written += F.save(F.fig2(frames, titles, r"Fig. 2: $a_1 = a_{1,x} = 0$, "
                                 r"$a_2 = -0.2$, $a_{2,x} = -0.002$"),
                          out, "fig2")
    for p in written:
        print(f"wrote {p}")
    return 0


def _read_sweep_csv(path):
    """A sweep CSV as a DataFrame, or a ValueError naming the file and what is wrong."""
    import pandas as pd

    from gridflow.io import check_input_file

    check_input_file(path, "sweep CSV")
    try:
        df = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable CSV ({exc})") from None
    need = {"param", "value", "model", "quantity", "noise", "q_rel", "q_abs"}
    missing = need - set(df)
    if missing:
        raise ValueError(f"{path}: not a sweep CSV (missing columns {sorted(missing)})")
    for col in ("value", "noise", "q_rel", "q_abs"):
        if not pd.api.types.is_numeric_dtype(df[col]):
            raise ValueError(f"{path}: column {col!r} must hold numbers")
    return df


def cmd_claims(a) -> int:
    from gridflow.io import check_output

    from .claims import check_claims, write_claims

    if a.write_csv:
        check_output(a.write_csv, suffixes=".csv", inputs=[a.csv], what="--write-csv")
    if a.write_doc:
        check_output(a.write_doc, suffixes=".md", inputs=[a.csv], what="--write-doc")
    df = _read_sweep_csv(a.csv)
    table = check_claims(df)
    print(table.to_string(index=False, columns=["id", "verdict", "numbers"],
                          max_colwidth=110))
    if a.write_doc or a.write_csv:
        names = df["sweep"].unique() if "sweep" in df else []
        tag = f"claims:{names[0]}" if len(names) == 1 else "claims"
        write_claims(table, doc=a.write_doc, csv=a.write_csv, source=a.csv, tag=tag)
        for p in (a.write_doc, a.write_csv):
            if p:
                print(f"wrote {p}")
    return 0


def cmd_cube(a) -> int:
    from gridflow.scenes import CubeScene

    from . import figures as F
    from .cube import cube_table, fig1, observation11, run_cube
    from gridflow.io import atomic_write
    from gridflow.loader import load_folder
    from gridflow.scenes.render import render_cube

    from gridflow.io import check_output

    check_output(a.csv, suffixes=".csv", what="--csv")
    check_output(a.fig_dir, suffixes=None, what="--fig-dir")
    check_output(a.cache, suffixes=None, what="--cache")
    if a.write_doc:
        check_output(a.write_doc, suffixes=".md", what="--write-doc")
    scene = CubeScene(width=a.size, height=a.size, grid=(a.grid, a.grid), frames=a.frames)
    t0 = time.perf_counter()
    folder = render_cube(scene, a.cache, progress=not a.no_progress)
    data = load_folder(folder)
    src = data.meta.get("source") or {}
    print(f"scene {folder}: rendered {src.get('rendered')} images in "
          f"{src.get('render_seconds')} s (this run: {time.perf_counter() - t0:.1f} s)")
    t1 = time.perf_counter()
    results = run_cube(data, sigma=a.sigma, window=a.window)
    print(f"estimated bcc, hf, full (sigma {a.sigma:g}, {a.window} taps) in "
          f"{time.perf_counter() - t1:.1f} s")
    table = cube_table(data, results)
    with atomic_write(a.csv, "w") as fh:
        table.to_csv(fh, index=False, float_format="%.6g")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    checks = observation11(table)
    for r in checks:
        print(f"observation 11, {r['face']} face: {r['check']}: "
              f"{'holds' if r['holds'] else 'does not hold'}")
    if a.write_doc:
        from .claims import replace_block
        from .cube import render_markdown

        doc = Path(a.write_doc)
        text = doc.read_text() if doc.exists() else ""
        block = render_markdown(table, checks, f"the scene `{folder.name}`, sigma {a.sigma:g}, "
                                f"{a.window} taps")
        with atomic_write(doc, "w") as fh:
            fh.write(replace_block(text, "cube", block))
        print(f"wrote {doc}")
    for p in F.save(fig1(data, results), a.fig_dir, "fig1"):
        print(f"wrote {p}")
    print(f"wrote {a.csv}")
    return 0


def cmd_peers(a) -> int:
    import pandas as pd

    from gridflow.io import atomic_write, check_output

    from . import figures as F
    from .cube import cube_lightfield
    from .peers import DEPTH_METHODS, compare_motion, run_depth

    for path in (a.csv_depth, a.csv_motion):
        check_output(path, suffixes=".csv", what="output")
    check_output(a.fig_dir, suffixes=None, what="--fig-dir")
    # depth: the cube as a light field with disparities up to 3 px per view
    views, truth, scene = cube_lightfield(a.cache, progress=not a.no_progress)
    label = (f"cube (POV-Ray), {scene.grid[0]}x{scene.grid[1]} views, disparity "
             f"{np.nanmin(truth):.2f} .. {np.nanmax(truth):.2f} px/view")
    depth = [run_depth(m, views, truth) for m in DEPTH_METHODS]
    table = pd.DataFrame([{"scene": label, **{k: v for k, v in r.items()
                                              if k not in ("disparity", "confidence")}}
                          for r in depth])
    # run times are printed, not stored: the CSV stays the same from run to run
    with atomic_write(a.csv_depth, "w") as fh:
        table.drop(columns="seconds").to_csv(fh, index=False, float_format="%.6g")
    print(label)
    print(table.drop(columns="scene").to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    for p in F.save(F.fig_peers_depth(truth, depth, label), a.fig_dir, "peers_depth"):
        print(f"wrote {p}")
    if a.write_hci:
        from gridflow.hci import write_hci

        files = write_hci(a.write_hci, views, disparity=truth)
        print(f"wrote {a.write_hci}: the cube light field in HCI layout ({len(files)} files)")
    # motion: the centre camera's frames, sinusoids under brightness change and the cube
    from gridflow.generators import make_sinusoid
    from gridflow.loader import load_folder
    from gridflow.scenes import CubeScene
    from gridflow.scenes.render import render_cube

    rows = []
    base = dict(U_X=0.05, U_Y=0.03)
    for case, kw in (("sinusoid", {}), ("sinusoid a1=0.1", dict(a1=0.1)),
                     ("sinusoid a1x=0.002", dict(a1x=0.002)),
                     ("sinusoid a2x=-0.002", dict(a2x=-0.002)),
                     ("sinusoid noise 0.025", dict(noise=0.025))):
        for r in compare_motion(make_sinusoid(**base, **kw)):
            rows.append({"data": case, **r})
    cube = load_folder(render_cube(CubeScene(), a.cache, progress=not a.no_progress))
    for r in compare_motion(cube, sigma=8.0, window=33):
        rows.append({"data": "cube (spotlight)", **r})
    motion = pd.DataFrame(rows)
    with atomic_write(a.csv_motion, "w") as fh:
        motion.drop(columns="seconds").to_csv(fh, index=False, float_format="%.6g")
    wide = motion.pivot_table(index=["data", "quantity"], columns="method", values="q",
                              sort=False)
    print("motion: Eq. 22 of the image flow (px/frame; relative where the truth keeps one "
          "sign, else absolute)")
    print(wide.to_string(float_format=lambda v: f"{v:.3g}"))
    secs = motion.groupby(["data", "method"], sort=False).seconds.first().unstack()
    print("seconds per volume (gridflow: the three models together)")
    print(secs.to_string(float_format=lambda v: f"{v:.2f}"))
    print(f"wrote {a.csv_depth}, {a.csv_motion}")
    if a.hci:
        from gridflow.hci import load_hci

        lf = load_hci(a.hci)
        if "disparity" not in lf.truth:
            raise ValueError(f"{a.hci}: no gt_disp_lowres.pfm to score against")
        views, gt = lf.volume[0], lf.truth["disparity"]
        n = views.shape[0]
        shifts = _stated_shears(lf.meta)
        kw = {} if shifts is None else {"shifts": shifts}
        out = []
        for m in DEPTH_METHODS:
            r = run_depth(m, views, gt, **(kw if m.startswith("gridflow_") else {}))
            used = (f"{n}x{n}" if m in ("gridflow_occlusion", "epi_st") else
                    f"{n}+{n}" if m == "gridflow_lines" else f"{min(5, n)}x{min(5, n)}")
            out.append({**r, "views": used})
        if n > 5:
            # the occlusion-aware shears on the central 5 x 5 alone: what the outer views add
            for m in ("gridflow_occlusion", "gridflow_lines"):
                r = run_depth(m, views, gt, grid=5, **kw)
                out.append({**r, "views": "5x5" if m == "gridflow_occlusion" else "5+5"})
        t = pd.DataFrame([{k: v for k, v in r.items() if k not in ("disparity", "confidence")}
                          for r in out])
        print(f"{a.hci} ({n}x{n} views{'; shears ' + str(list(kw['shifts'])) if kw else ''}):")
        print(t.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from gridflow import __version__

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
    p.add_argument("input", help="volume .npz, camera-grid folder with grid.json, or an HCI "
                                 "light field scene folder (input_Cam000.png ...)")
    p.add_argument("--views", type=_positive_int, default=None,
                   help="HCI scenes: the central VIEWS x VIEWS views to use (odd; default "
                        "5, what 5-tap camera filters reach; all with --select lines or "
                        "occlusion)")
    _add_estimator_args(p)
    p.add_argument("--shears", nargs="+", default=None, metavar="MIN MAX",
                   help="light fields of one frame: refocus over the integer disparities "
                        "MIN..MAX (px per view) for disparities beyond about +-1; 'auto': "
                        "an HCI scene's stated range")
    p.add_argument("--select", choices=("coarse", "lines", "occlusion"), default="coarse",
                   help="with --shears: each pixel's shear nearest a coarse estimate "
                        "(default; fine periodic texture), or chosen among camera "
                        "sub-grids and shifted windows: 1-D ones along the centre row and "
                        "column ('lines': occlusions and thin structures) or square ones "
                        "('occlusion'); docs/model.md")
    p.add_argument("-o", "--output", required=True, help="output estimate .npz")
    p.set_defaults(func=cmd_estimate)

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

    p = sub.add_parser("cube", help="render the cube (POV-Ray), estimate, Fig. 1 and cube.csv")
    p.add_argument("--size", type=_positive_int, default=256, help="image width = height (default 256)")
    p.add_argument("--grid", type=_positive_int, default=5, help="cameras per side (default 5)")
    p.add_argument("--frames", type=_positive_int, default=9, help="frames (default 9)")
    p.add_argument("--cache", default="work/cube", help="render cache (default work/cube)")
    p.add_argument("--sigma", type=float, default=8.0,
                   help="window sigma, px (default 8: the 55-px left face of a 256-px image "
                        "needs a smaller window than the sinusoid's 16)")
    p.add_argument("--window", type=int, default=33, help="window taps (default 33)")
    p.add_argument("--csv", default="results/cube.csv", help="per-face error table")
    p.add_argument("--fig-dir", default="results/figures", help="where fig1.{png,pdf} go")
    p.add_argument("--write-doc", help="markdown file whose cube section to rewrite")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_cube)

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
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=cmd_peers)

    p = sub.add_parser("claims", help="check the paper's observations 1-10 on a sweep CSV")
    p.add_argument("csv", help="sweep CSV (e.g. results/sweep_paper.csv)")
    p.add_argument("--write-doc", help="markdown file whose claims section to rewrite")
    p.add_argument("--write-csv", help="CSV of verdicts to write")
    p.set_defaults(func=cmd_claims)
    return ap


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
    try:
        return a.func(a)
    except (ValueError, TypeError, FileNotFoundError, OSError, RuntimeError) as exc:
        print(f"gridflow {a.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
