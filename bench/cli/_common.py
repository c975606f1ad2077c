"""Argument helpers the command groups share: options from a parameter dataclass (their
help read from its docstring), the estimator's settings, positive integers, shear ranges,
and printing a report's lines."""

from __future__ import annotations

import argparse
import importlib
import inspect
import re
from dataclasses import fields

__all__ = ["field_docs", "add_dataclass_args", "dataclass_values", "add_sinusoid_args",
           "add_estimator_args", "estimator_settings", "model_list", "positive_int",
           "shear_range", "print_lines"]

_RULE = re.compile(r"-{3,}")
_SENTENCE_END = re.compile(r"(?<=\.)\s{2,}|(?<=\.)\s+(?=[A-Z])")
_ROLE = re.compile(r":\w+:`~?([^`]+)`")
_AS = re.compile(r"^As :class:`~?([\w.]+)`")


def _first_sentence(text: str) -> str:
    return _SENTENCE_END.split(text.strip(), maxsplit=1)[0].strip()


def _plain(text: str) -> str:
    """Docstring markup as plain text (roles and backticks dropped)."""
    text = _ROLE.sub(lambda m: m.group(1).rpartition(".")[2], text)
    return re.sub(r"\s+", " ", text.replace("``", "").replace("`", ""))


def _resolve(path: str) -> type:
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def field_docs(cls) -> dict[str, str]:
    """``{field: first sentence of its entry}`` from the numpydoc *Attributes* or
    *Parameters* section of ``cls``'s docstring.  An entry that names several fields
    (``U_X, U_Y, U_Z : float``) gives each the same text; one that reads "As
    :class:`other`" takes the other class's entry.  Fields without a description are
    left out.  A text shared by several fields begins with their names
    (``U_X, U_Y, U_Z: Velocity, ...``), so that each reads which part is its own."""
    lines = (inspect.getdoc(cls) or "").splitlines()
    entries, shared, names, text, section = {}, {}, None, [], False
    for i, line in enumerate(lines + [""]):
        if i + 1 < len(lines) and _RULE.fullmatch(lines[i + 1].strip()):
            section = line.strip() in ("Attributes", "Parameters")
            names = None
            continue
        if not section or _RULE.fullmatch(line.strip()):
            continue
        if line and not line[0].isspace():
            names, text = [n.strip() for n in line.split(":")[0].split(",")], []
            for n in names:
                entries[n] = text                    # filled as its lines come
                shared[n] = ", ".join(names) if len(names) > 1 else ""
        elif names is not None and line.strip():
            text.append(line.strip())
    out = {}
    for name, body in entries.items():
        sentence = _first_sentence(" ".join(body))
        m = _AS.match(sentence)
        if m:
            sentence = field_docs(_resolve(m.group(1))).get(name, "")
        elif sentence and shared[name]:
            sentence = f"{shared[name]}: {sentence}"
        if sentence:
            out[name] = sentence
    return out


def add_dataclass_args(g, cls, fallback=None) -> None:
    """One option per field of the parameter dataclass ``cls`` (``--wavelength-x``): its
    help the field's description in ``cls``'s docstring (:func:`field_docs`; where it
    gives none, the same field's in ``fallback``'s) and its default; None when not given
    (:func:`dataclass_values`).

    Raises
    ------
    KeyError
        A field that neither docstring describes (the help would say nothing of it).
    """
    from gridflow.generators.sinusoid import TEXTURES

    docs = {**(field_docs(fallback) if fallback else {}), **field_docs(cls)}
    for fl in fields(cls):
        default = getattr(cls(), fl.name)
        flag = "--" + fl.name.replace("_", "-")
        if fl.name not in docs:
            raise KeyError(f"{cls.__name__}.{fl.name}: its docstring does not describe it")
        meaning = _plain(docs[fl.name]).rstrip(".").replace("%", "%%")
        if isinstance(default, tuple):
            g.add_argument(flag, type=type(default[0]), nargs=2, default=None,
                           metavar=("A", "B"),
                           help=f"{meaning} (default {default[0]} {default[1]})")
        elif fl.name == "texture":
            g.add_argument(flag, choices=TEXTURES, default=None,
                           help=f"{meaning} (default {default})")
        else:
            g.add_argument(flag, type=type(default), default=None,
                           help=f"{meaning} (default {default})")


def dataclass_values(a, cls) -> dict:
    """The fields of ``cls`` given on the command line (pairs as tuples)."""
    return {fl.name: tuple(v) if isinstance(v, list) else v for fl in fields(cls)
            if (v := getattr(a, fl.name, None)) is not None}


def _units(cls) -> str:
    """The docstring's paragraph on units (``Units: ...``), as one line."""
    doc = inspect.getdoc(cls) or ""
    m = re.search(r"^Units:(.*?)(?:\n\s*\n|\Z)", doc, flags=re.S | re.M)
    return _first_sentence(_plain(m.group(1))) if m else ""


def add_sinusoid_args(p: argparse.ArgumentParser) -> None:
    from gridflow.generators import SinusoidParams

    units = _units(SinusoidParams)
    add_dataclass_args(p.add_argument_group(
        "sinusoid parameters (defaults: docs/reproduction.md)",
        f"Units: {units}" if units else None), SinusoidParams)


def add_estimator_args(p: argparse.ArgumentParser) -> None:
    from gridflow.estimator import COMBINE, DEFAULTS, FILTER_NAMES, METHODS, MOTIONS
    from gridflow.estimator.lightfield import SELECT_DEFAULTS

    lines, occl = SELECT_DEFAULTS["lines"], SELECT_DEFAULTS["coarse"]
    epi = SELECT_DEFAULTS["epi"]
    g = p.add_argument_group("estimator settings")
    g.add_argument("--model", type=model_list, default=None,
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
                   help=f"Gaussian sigma of the window, px (default {DEFAULTS['sigma']:g}; "
                        f"a refocused light field: {lines[0]:g}, or {occl[0]:g} with "
                        f"--select coarse, {epi[0]:g} along the line with --select epi)")
    g.add_argument("--window", type=int, default=None,
                   help=f"the window's Gaussian taps, px (default {DEFAULTS['window']}; a "
                        f"refocused light field: {lines[1]}, or {occl[1]} with --select "
                        f"coarse, {epi[1]} along the line with --select epi)")
    g.add_argument("--filters", choices=FILTER_NAMES, default=None,
                   help=f"derivative filters (default {DEFAULTS['filters']})")
    g.add_argument("--temporal-radius", type=int, default=None,
                   help="frames either side of the reference frame in the window (default "
                        "as many as the temporal filter reaches, at most 2; 6 with "
                        "--motion affine)")
    g.add_argument("--growth-support", type=float, default=None, metavar="PX",
                   help="--motion affine: the support (sd, px) over which depth motion and "
                        "tilt rates are pooled (default 6 x --sigma; 0: each pixel alone; "
                        "docs/model.md, Pooled depth rates)")
    g.add_argument("--ref-frame", type=int, default=None,
                   help="index of the reference frame, whose maps are estimated (default "
                        "the input's: the centre frame unless it states another)")
    g.add_argument("--method", default=None, metavar="METHOD",
                   help=f"the built-in estimator's implementation, one of "
                        f"{', '.join(METHODS)} (same results; default {DEFAULTS['method']}); "
                        "or another method instead of gridflow's: MODULE:FUNCTION "
                        "(importable from here or PYTHONPATH) or an entry point of the "
                        "group gridflow.methods, written as an estimate .npz (the README, "
                        "'Benchmark your own method')")
    g.add_argument("--no-slant-correction", action="store_true",
                   help="read U_Z as the paper does (no slant-motion correction)")
    g.add_argument("--no-zoom-correction", action="store_true",
                   help="read the data rows as the paper does (no zoom-blur correction; "
                        "docs/model.md)")
    g.add_argument("--combine", choices=COMBINE, default=None,
                   help="how the two estimates of v, z_x, z_y, u_z are combined "
                        f"(default {DEFAULTS['combine']})")


def model_list(text: str) -> tuple[str, ...]:
    from gridflow.estimator import MODELS

    names = MODELS if text == "all" else tuple(t.strip() for t in text.split(","))
    bad = [t for t in names if t not in MODELS]
    if bad or not names or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"expected one of {', '.join(MODELS)}, a comma-separated list of them or "
            f"'all', got {text!r}")
    return tuple(names)


def estimator_settings(a) -> dict:
    """The estimator settings given on the command line; those not given are left out and
    keep the library's defaults (or the light-field choice's), so that a refocused light
    field can refuse the single pass's settings instead of ignoring them."""
    from gridflow.estimator import METHODS
    s = dict(filters=a.filters, temporal_radius=a.temporal_radius, ref_frame=a.ref_frame,
             method=a.method if a.method in METHODS else None, combine=a.combine,
             motion=a.motion, sigma=a.sigma,
             window=a.window, growth_support=a.growth_support)
    if a.no_slant_correction:
        s["slant_correction"] = False
    if a.no_zoom_correction:
        s["zoom_correction"] = False
    return {k: v for k, v in s.items() if v is not None}


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def shear_range(values: list[str]):
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


def print_lines(lines) -> int:
    """Print a report's lines; the command's exit status 0."""
    for line in lines:
        print(line)
    return 0
