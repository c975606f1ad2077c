"""``gridflow sweep``, ``claims``, ``figures``, ``readings``: parameter sweeps
(:mod:`gridflow.bench.sweep_job`), the paper's observations checked on them
(:mod:`gridflow.bench.claims`, :mod:`gridflow.bench.readings`) and Figs. 2-4
(:mod:`gridflow.bench.figures`)."""

from __future__ import annotations

import sys

from ._common import positive_int, print_lines

__all__ = ["register"]


def cmd_sweep(a) -> int:
    from ..sweep import SweepInterrupted
    from ..sweep_job import CHANGES, run_sweep_job

    spec = dict(source=a.spec, name=a.name, param=a.param, values=a.values,
                **{k: getattr(a, k) for k in CHANGES})
    try:
        r = run_sweep_job(spec, a.output, processes=a.processes, workers=a.workers,
                          scheduler=a.scheduler, connect_timeout=a.connect_timeout,
                          progress=not a.no_progress,
                          log=lambda line: print(line, file=sys.stderr))
    except SweepInterrupted as exc:
        print(f"gridflow sweep: {exc}", file=sys.stderr)
        return 143 if exc.signal_name == "SIGTERM" else 130
    print(f"wrote {r.output}: {len(r.rows)} rows in {r.seconds:.1f} s", file=sys.stderr)
    return 0


def cmd_export(a) -> int:
    from ..suites import export_suite

    options = {"cache": a.cache} if a.cache else {}
    return print_lines(export_suite(a.suite, a.folder, progress=not a.no_progress,
                                    only=a.only, **options))


def cmd_score(a) -> int:
    from ..suites import score_suite

    return print_lines(score_suite(a.folder, a.estimates, a.output, method=a.name))


def _add_export(sub) -> None:
    from gridflow.scenes.render import RENDER_CACHE

    from ..suites import EXPERIMENTS

    p = sub.add_parser("export", help="write a suite's volumes (a sweep, the cube, the "
                                      "leaf, the growth leaves) as interchange .npz files "
                                      "with their truth apart and a manifest",
                       description="Write a suite (every point of a sweep spec, or one of "
                                   f"the experiments {', '.join(EXPERIMENTS)}) as "
                                   "interchange volumes (DIR/volumes/ID.npz, no truth), "
                                   "their truth and scored pixels (DIR/truth/ID.npz) and "
                                   "DIR/manifest.json (the spec or the experiment's "
                                   "settings, gridflow's version, checksums), for methods "
                                   "run outside gridflow; gridflow score scores their "
                                   "estimates into the suite's own table.")
    p.add_argument("suite", help="a sweep spec (a shipped spec's name: smoke, paper, "
                                 "growth, ...; or a TOML file) or an experiment: "
                                 f"{', '.join(EXPERIMENTS)} (cube and leaf render with "
                                 "POV-Ray the first time)")
    p.add_argument("folder", help="a new (or empty) folder")
    p.add_argument("--only", metavar="PATTERN",
                   help="export only the items whose id matches this shell pattern "
                        "(e.g. 'still_*' of growth_maps)")
    p.add_argument("--cache", default=None,
                   help=f"render cache of cube and leaf (default {RENDER_CACHE}, where "
                        "make figures renders them)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_export)


def _add_score(sub) -> None:
    p = sub.add_parser("score", help="score a folder of estimates of an exported suite",
                       description="Score ESTIMATES/ID.npz (maps under gridflow's quantity "
                                   "names) for every volume of a suite written by gridflow "
                                   "export, with the code that scores the suite in "
                                   "gridflow, into its table: a sweep's columns, "
                                   "cube.csv's, leaf.csv's or growth_maps.csv's.")
    p.add_argument("folder", help="the suite (gridflow export)")
    p.add_argument("estimates", help="folder of ID.npz estimates, one per volume")
    p.add_argument("-o", "--output", required=True, help="output CSV")
    p.add_argument("--name", default=None,
                   help="the method column (default the estimates folder's name)")
    p.set_defaults(func=cmd_score)


def cmd_figures(a) -> int:
    from ..figures import figures_from_csv

    return print_lines(f"wrote {p}" for p in figures_from_csv(
        a.out, sweep_csv=a.sweep, fig2=a.fig2, suffix=a.suffix))


def cmd_claims(a) -> int:
    from ..claims import claims_report

    return print_lines(claims_report(a.csv, doc=a.write_doc, csv=a.write_csv,
                                     terms=a.write_terms))


def cmd_readings(a) -> int:
    from ..readings import readings_report

    return print_lines(readings_report(a.csv, csv_verdicts=a.csv_verdicts,
                                       csv_terms=a.csv_terms, doc=a.write_doc))


def _add_sweep(sub) -> None:
    from gridflow.estimator import MODELS, MOTIONS

    from ..setups import SETUPS

    p = sub.add_parser("sweep", help="run a parameter sweep, write a tidy CSV",
                       description="Run a parameter sweep (every point a sinusoid volume, "
                                   "every model on it) and write a tidy CSV with a "
                                   "provenance sidecar (.json); resumable.")
    p.add_argument("spec", nargs="?",
                   help="sweep spec: a TOML file, or the name of a shipped spec "
                        "('paper': the paper's sweeps; 'smoke': a seconds-long check)")
    p.add_argument("-o", "--output", required=True,
                   help="output CSV (and its provenance sidecar, the same name with .json)")
    p.add_argument("--name", default="sweep",
                   help="sweep name, without a spec (default sweep)")
    p.add_argument("--param", help="generator parameter to sweep (a SinusoidParams field; "
                                   "replaces the spec's axes)")
    p.add_argument("--values", type=float, nargs="+",
                   help="values of --param, in that parameter's unit")
    p.add_argument("--models", nargs="+",
                   help=f"brightness models, of {', '.join(MODELS)} (default: the spec's, "
                        "else all three)")
    p.add_argument("--motions", nargs="+",
                   help=f"motion models, of {', '.join(MOTIONS)}, each run with every model "
                        "(default: the spec's, else translation)")
    p.add_argument("--noise", type=float, nargs="+",
                   help="noise levels sigma_n, standard deviations in the texture's "
                        "intensity units (default: the spec's, else 0)")
    p.add_argument("--seeds", type=int, nargs="+",
                   help="noise seeds, one point each (default: the spec's, else 0)")
    p.add_argument("--setup", choices=sorted(SETUPS), default=None,
                   help="named setup the spec starts from (default: the spec's, else "
                        "gridflow; see bench/setups.py)")
    p.add_argument("--method", dest="methods", action="append", metavar="METHOD",
                   help="a method to run on every point instead of the spec's (repeat for "
                        "several): 'gridflow' (the built-in estimator, every model and "
                        "motion), MODULE:FUNCTION (importable from here or PYTHONPATH) or "
                        "an entry point of the group gridflow.methods; see the README, "
                        "'Benchmark your own method'")
    p.add_argument("--method-cmd", dest="method_cmds", action="append", metavar="CMD",
                   help="a program run as a method: 'PROGRAM ARGS {input} {output}' (reads "
                        "the volume as an interchange .npz at {input}, writes its maps as "
                        "an .npz at {output}); repeat for several")
    p.add_argument("--method-timeout", type=float, default=None, metavar="S",
                   help="seconds a --method-cmd program may take per point (default: the "
                        "spec's, else 600)")
    p.add_argument("--connect-timeout", type=float, default=10.0,
                   help="seconds to wait for --scheduler or --workers to answer (default 10)")
    p.add_argument("--processes", type=positive_int, default=None,
                   help="size of the default in-process pool (default: all cores)")
    p.add_argument("--workers", type=positive_int, default=None,
                   help="start a local dask.distributed cluster of N single-threaded workers")
    p.add_argument("--scheduler", help="address of a running dask scheduler (tcp://HOST:PORT)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)


def _add_figures(sub) -> None:
    p = sub.add_parser("figures", help="draw Figs. 2-4 into a folder",
                       description="Draw Figs. 3 and 4 from a sweep CSV (a growth sweep: "
                                   "its own figure) and/or Fig. 2, as PNG and PDF.")
    p.add_argument("--sweep", help="sweep CSV for Figs. 3 and 4 (gridflow sweep)")
    p.add_argument("--fig2", action="store_true", help="draw Fig. 2")
    p.add_argument("--out", default="results/figures",
                   help="output folder (default results/figures)")
    p.add_argument("--suffix", default="",
                   help="appended to the figure names (fig3_SETUP_setupSUFFIX.png; default "
                        "none)")
    p.set_defaults(func=cmd_figures)


def _add_readings(sub) -> None:
    p = sub.add_parser("readings", help="the paper's observations under other readings of "
                                        "its unstated parameters, side by side",
                       description="The paper's observations under other readings of its "
                                   "unstated parameters (one sweep each, bench/readings.py), "
                                   "side by side.")
    p.add_argument("csv", nargs="+", help="sweep CSVs of the readings (bench/readings.py)")
    p.add_argument("--csv-verdicts", default="results/readings_verdicts.csv",
                   help="CSV to write: the verdict per reading and observation (default "
                        "results/readings_verdicts.csv)")
    p.add_argument("--csv-terms", default="results/readings.csv",
                   help="CSV to write: the paper's statements, gridflow's number under each "
                        "reading (default results/readings.csv)")
    p.add_argument("--write-doc", help="markdown file whose readings section to rewrite")
    p.set_defaults(func=cmd_readings)


def _add_claims(sub) -> None:
    p = sub.add_parser("claims", help="check the paper's observations 1-10 on a sweep CSV",
                       description="Check the paper's observations 1-10 (a growth sweep: "
                                   "G1, G2) on sweep CSVs; print the verdicts.")
    p.add_argument("csv", nargs="+", help="sweep CSV (e.g. results/sweep_paper.csv); with "
                   "several (one per setup), the paper's statements side by side")
    p.add_argument("--write-doc", help="markdown file whose claims sections to rewrite "
                   "(and, with several sweeps, its paper-terms table)")
    p.add_argument("--write-csv", help="CSV of verdicts to write (one sweep)")
    p.add_argument("--write-terms", metavar="CSV", help="CSV of the paper's quantitative "
                   "statements with gridflow's number for each under each sweep's setup")
    p.set_defaults(func=cmd_claims)


def register(sub) -> None:
    """The commands sweep, export, score, figures, readings, claims."""
    _add_sweep(sub)
    _add_export(sub)
    _add_score(sub)
    _add_figures(sub)
    _add_readings(sub)
    _add_claims(sub)
