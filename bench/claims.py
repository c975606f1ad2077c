"""The paper's observations 1-10 (docs/model.md, Sec. 4.1), checked on a sweep CSV.

Each observation is a function of the sweep table returning the numbers behind it and a
verdict: ``holds``, ``partly`` or ``does not hold``.  The thresholds that turn the paper's
words into numbers are fixed here, in the text of each check, not chosen per result:

* "well below x"      : below x/2
* "barely reacts"     : stays below 0.01 (1 %)
* "breaks down"       : error at least 10x the full model's at the same value, or > 1
* "the same", "similar": within a factor 2
* "almost independent": the quantity's error grows by less than 1 % of the perturbing
  parameter's size (for a2x: of its size times the rms material X of the interior)
* "linear growth"     : log-log slope within 0.8 .. 1.2

The error measure is Eq. 22: relative for a quantity against its own parameter, absolute
for cross-talk.  All checks use noise-free rows unless the observation is about noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["check_claims", "render_markdown", "write_claims", "CLAIMS", "missing_data"]

START, END = "<!-- claims:start -->", "<!-- claims:end -->"


@dataclass
class Result:
    verdict: str
    numbers: str


def _curve(df, model, quantity, param, noise=0.0, measure=None) -> pd.Series:
    """Error of ``quantity`` against ``param`` (index: value, sorted by |value|)."""
    measure = measure or ("q_rel" if quantity == param else "q_abs")
    d = df[(df.model == model) & (df.quantity == quantity) & (df.param == param)
           & (df.noise == noise)]
    s = d.groupby("value")[measure].mean()
    return s.iloc[np.argsort(np.abs(s.index.to_numpy()))]


def _fmt(x) -> str:
    return "nan" if not np.isfinite(x) else f"{x:.2g}"


def _pairs(s: pd.Series, n=None) -> str:
    items = [(v, q) for v, q in s.items() if v != 0]
    if n:
        items = items[:: max(1, len(items) // n)]
    return ", ".join(f"{v:g}: {_fmt(q)}" for v, q in items)


def _slope(s: pd.Series) -> float:
    s = s[(s.index != 0) & (s > 0)]
    if len(s) < 2:
        return float("nan")
    return float(np.polyfit(np.log(np.abs(s.index.to_numpy())), np.log(s.to_numpy()), 1)[0])


def _verdict(checks: list[bool]) -> str:
    if all(checks):
        return "holds"
    return "partly" if any(checks) else "does not hold"


def _x_rms(df) -> float:
    """rms material X over the interior, from the generator settings of the sweep."""
    import json

    from gridflow.generators import SinusoidParams

    g = json.loads(df.generator.iloc[0]) if "generator" in df else {}
    base = SinusoidParams()
    p = base.replace(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in g.items()
                        if k in base.as_dict()})
    half = (p.width - 1) / 2 - 34           # interior half-width (window 65, 5-tap filters)
    return float(half / math.sqrt(3) * p.Z0 / p.f)


def obs1(df) -> Result:
    s = _curve(df, "full", "a1", "a1")
    below1 = s[(s.index > 0) & (s.index < 1)]
    above = s[s.index > 1]
    ok_from = next((v for v in below1.index if (below1[below1.index >= v] < 0.0025).all()), None)
    checks = [bool((below1 < 0.0025).all()),
              bool(len(above) and (above > below1.iloc[-1]).all() and (above < 0.05).all())]
    return Result(_verdict(checks),
                  f"Q_rel(a1), full: {_pairs(s)}; below 0.25 % from a1 = {ok_from} on")


def obs2(df) -> Result:
    s = _curve(df, "full", "a2", "a2")
    k = _slope(s)
    return Result(_verdict([0.8 <= k <= 1.2]),
                  f"Q_rel(a2), full: {_pairs(s, 5)}; log-log slope {k:.2f}")


def obs3(df) -> Result:
    hf, full = _curve(df, "hf", "a1", "a1x"), _curve(df, "full", "a1", "a1x")
    nz = hf.index != 0
    stronger = bool((hf[nz] >= full[nz]).all())
    hf_grows = bool(hf.iloc[-1] > 10 * hf.iloc[0])
    full_grows = bool(full.iloc[-1] > 10 * full.iloc[0])
    return Result(_verdict([stronger, hf_grows, full_grows]),
                  f"Q_abs(a1) vs a1x, HF: {_pairs(hf, 4)}; full: {_pairs(full, 4)}; "
                  f"cross-talk in HF {'yes' if hf_grows else 'no'}, in full "
                  f"{'yes' if full_grows else 'no'}")


def obs4(df) -> Result:
    hf, full = _curve(df, "hf", "a2", "a2x"), _curve(df, "full", "a2", "a2x")
    r = (hf / full)[hf.index != 0]
    return Result(_verdict([bool(((r >= 0.5) & (r <= 2)).all())]),
                  f"Q_abs(a2) HF/full vs a2x: {_pairs(r)}")


def obs5(df) -> Result:
    xr = _x_rms(df)
    parts, checks = [], []
    for model in ("hf", "full"):
        for q, p, scale in (("a1", "a2", 1.0), ("a1", "a2x", xr), ("a2", "a1", 1.0)):
            s = _curve(df, model, q, p)
            leak = float((s - s.iloc[0]).max() / (np.abs(s.index).max() * scale))
            checks.append(leak < 0.01)
            parts.append(f"{model} {q}<-{p}: {leak:.1e}")
    return Result(_verdict(checks), "leak (error growth / perturbation): " + ", ".join(parts))


def obs6(df) -> Result:
    hf, full = _curve(df, "hf", "a2", "a1x"), _curve(df, "full", "a2", "a1x")
    r = (hf / full)[hf.index != 0]
    top = r.iloc[-3:]
    return Result(_verdict([bool((top >= 10).all())]),
                  f"Q_abs(a2) HF/full vs a1x: {_pairs(r)}")


def obs7(df) -> Result:
    b, h, f = (_curve(df, m, "Uz", "a1", measure="q_rel") for m in ("bcc", "hf", "full"))
    first = b.index[1]
    checks = [bool(b.iloc[1] >= 10 * f.iloc[1]),
              bool((h[h.index <= 1] < 0.01).all() and (f[f.index <= 1] < 0.01).all()),
              bool((h < 0.1).all() and (f < 0.1).all())]
    return Result(_verdict(checks),
                  f"Q_rel(U_Z) at a1 = {first:g}: BCC {_fmt(b.iloc[1])}, HF {_fmt(h.iloc[1])}, "
                  f"full {_fmt(f.iloc[1])}; HF/full at a1 = 1: {_fmt(h.get(1.0, np.nan))}/"
                  f"{_fmt(f.get(1.0, np.nan))}, at a1 = {b.index[-1]:g}: "
                  f"{_fmt(h.iloc[-1])}/{_fmt(f.iloc[-1])}")


def obs8(df) -> Result:
    b, h, f = (_curve(df, m, "Uz", "a1x", measure="q_rel") for m in ("bcc", "hf", "full"))
    checks = [bool((f < 0.01).all()), bool(b.iloc[-1] > 10 * f.iloc[-1] and b.iloc[-1] > 0.1),
              bool(h.iloc[-1] > 10 * f.iloc[-1] and h.iloc[-1] > 0.1)]
    return Result(_verdict(checks),
                  f"Q_rel(U_Z) at a1x = {f.index[-1]:g}: BCC {_fmt(b.iloc[-1])}, HF "
                  f"{_fmt(h.iloc[-1])}, full {_fmt(f.iloc[-1])}; full max {_fmt(f.max())}")


def _breakdown(df, param) -> tuple[float, float]:
    b = _curve(df, "bcc", "Uz", param, measure="q_rel")
    f = _curve(df, "full", "Uz", param, measure="q_rel")
    broken = (b > 10 * f) | (b > 1)
    vals = np.abs(b.index.to_numpy())
    idx = np.flatnonzero(broken.to_numpy())
    if idx.size == 0:
        return float("nan"), float("nan")
    i = idx[0]
    return float(vals[i - 1]) if i else 0.0, float(vals[i])


def obs9(df) -> Result:
    curves = {p: [_curve(df, m, "Uz", p, measure="q_rel") for m in ("bcc", "hf", "full")]
              for p in ("a2", "a2x")}
    agree = []
    for cs in curves.values():
        first = [c.iloc[1] for c in cs]
        agree.append(max(first) <= 2 * min(first))
    lin = [0.8 <= _slope(curves[p][2][np.abs(curves[p][2].index) <= lim]) <= 1.2
           for p, lim in (("a2", 0.1), ("a2x", 0.02))]
    (a_lo, a_hi), (x_lo, x_hi) = _breakdown(df, "a2"), _breakdown(df, "a2x")
    near = [a_lo <= 0.1 * 2 and a_hi >= 0.1 / 2, x_lo <= 0.02 * 2 and x_hi >= 0.02 / 2]
    yn = lambda flags: "/".join("yes" if f else "no" for f in flags)  # noqa: E731
    return Result(_verdict(agree + lin + near),
                  f"models agree at the smallest |a2|, |a2x|: {yn(agree)}; full's U_Z error "
                  f"linear in |a2|, |a2x|: {yn(lin)}; BCC breaks down between |a2| = {a_lo:g} "
                  f"and {a_hi:g} (paper ~0.1), |a2x| = {x_lo:g} and {x_hi:g} (paper ~0.02)")


def obs10(df) -> Result:
    n = min(v for v in df.noise.unique() if v > 0)
    same, parts, changed = [], [], []
    for p in ("a1", "a1x", "a2", "a2x"):
        for m in ("bcc", "hf", "full"):
            c0 = _curve(df, m, "Uz", p, 0.0, "q_rel")
            c1 = _curve(df, m, "Uz", p, n, "q_rel")
            for v in c0.index[-2:]:
                if c0[v] >= 0.05:                       # systematic error dominates
                    same.append(bool(c1[v] <= 1.5 * c0[v] and c0[v] <= 1.5 * c1[v]))
                    if not same[-1]:
                        changed.append(f"{m} {p}={v:g}: {_fmt(c0[v])} -> {_fmt(c1[v])}")
    small = []
    for p, vmax in (("a1", 0.02), ("a1x", 0.002)):
        f0 = _curve(df, "full", "Uz", p, 0.0, "q_rel")
        f1 = _curve(df, "full", "Uz", p, n, "q_rel")
        sel = np.abs(f0.index) <= vmax
        small.append(bool((f0[sel] < 0.005).all() and (f1[sel] >= 3 * f0[sel]).all()))
        parts.append(f"{p} <= {vmax:g}: full {_fmt(f0[sel].max())} -> {_fmt(f1[sel].max())}")
    return Result(_verdict([all(same)] + small),
                  f"large values (systematic error >= 0.05) unchanged by noise: "
                  f"{sum(same)}/{len(same)}" + (f" (changed: {'; '.join(changed)})" if changed
                                                 else "")
                  + f"; small values, noise-free -> sigma_n={n:g}: "
                  + "; ".join(parts) + " (paper: from well below 0.01 to nearly 0.1)")


CLAIMS = [
    ("1", "Relative error of a1 well below 0.5 % for a1 < 1, rising moderately beyond", obs1),
    ("2", "Error of a2 grows linearly with |a2|", obs2),
    ("3", "Strong cross-talk from a1x into a1, stronger for HF", obs3),
    ("4", "Cross-talk from a2x into a2 is the same for HF and full", obs4),
    ("5", "a1 almost independent of a2 and a2x, and a2 of a1", obs5),
    ("6", "With a1x present, the error of a2 is 1-2 orders smaller when a1x is modelled", obs6),
    ("7", "U_Z: BCC breaks down as soon as a1 > 0; HF and full barely react", obs7),
    ("8", "With a1x present only the full model stays stable", obs8),
    ("9", "a2, a2x cause similar U_Z errors; models agree for small values; BCC breaks "
          "down at |a2| ~ 0.1, |a2x| ~ 0.02", obs9),
    ("10", "Noise: little change for large values; for small a1, a1x the U_Z error rises "
           "from well below 0.01", obs10),
]

_ALL = ("bcc", "hf", "full")
# what each observation's check reads: (swept parameters, models, quantities, needs noise)
NEEDS = {
    "1": (("a1",), ("full",), ("a1",), False),
    "2": (("a2",), ("full",), ("a2",), False),
    "3": (("a1x",), ("hf", "full"), ("a1",), False),
    "4": (("a2x",), ("hf", "full"), ("a2",), False),
    "5": (("a1", "a2", "a2x"), ("hf", "full"), ("a1", "a2"), False),
    "6": (("a1x",), ("hf", "full"), ("a2",), False),
    "7": (("a1",), _ALL, ("Uz",), False),
    "8": (("a1x",), _ALL, ("Uz",), False),
    "9": (("a2", "a2x"), _ALL, ("Uz",), False),
    "10": (("a1", "a1x", "a2", "a2x"), _ALL, ("Uz",), True),
}
MIN_VALUES = 3      # non-zero values per curve, besides 0 itself (slopes, first/last points)


def missing_data(df: pd.DataFrame, cid: str) -> str | None:
    """Why the sweep cannot test observation ``cid``, or None when it has every curve."""
    params, models, quantities, noisy = NEEDS[cid]
    lacking = []
    for p in params:
        if not (df.param == p).any():
            lacking.append(f"no {p} axis")
            continue
        for m in models:
            if not ((df.param == p) & (df.model == m)).any():
                lacking.append(f"no {m} rows on the {p} axis")
                continue
            for q in quantities:
                d = df[(df.param == p) & (df.model == m) & (df.quantity == q) & (df.noise == 0)]
                values = set(d.value)
                if 0 not in values or len(values - {0}) < MIN_VALUES:
                    lacking.append(f"{m} {q} on the {p} axis needs 0 and at least "
                                   f"{MIN_VALUES} other noise-free values")
                elif noisy and (df.noise > 0).any():
                    n = df.noise[df.noise > 0].min()
                    dn = df[(df.param == p) & (df.model == m) & (df.quantity == q)
                            & (df.noise == n)]
                    if not values <= set(dn.value):
                        lacking.append(f"{m} {q} on the {p} axis lacks noisy rows "
                                       f"(sigma_n = {n:g}) at some values")
    if noisy and not (df.noise > 0).any():
        lacking.append("no noisy rows")
    return "; ".join(dict.fromkeys(lacking)) or None


def check_claims(df: pd.DataFrame) -> pd.DataFrame:
    """Evaluate every observation; returns a table ``id, observation, verdict, numbers``.

    An observation whose data the sweep does not hold is ``not tested``, with the reason.
    """
    rows = []
    for cid, text, fn in CLAIMS:
        why = missing_data(df, cid)
        r = Result("not tested", f"the sweep lacks its data: {why}") if why else fn(df)
        rows.append({"id": cid, "observation": text, "verdict": r.verdict, "numbers": r.numbers})
    return pd.DataFrame(rows)


def render_markdown(table: pd.DataFrame, source: str) -> str:
    lines = [START, "", f"Checked by `gridflow claims {source}` (thresholds: "
             "`bench/claims.py`).", "",
             "| # | observation | verdict | measured |", "|---|---|---|---|"]
    for r in table.itertuples():
        cells = [str(c).replace("|", "\\|") for c in (r.observation, r.numbers)]
        lines.append(f"| {r.id} | {cells[0]} | **{r.verdict}** | {cells[1]} |")
    lines += ["", END]
    return "\n".join(lines)


def write_claims(table: pd.DataFrame, doc=None, csv=None, source: str = "") -> None:
    """Rewrite the claims section of ``doc`` (between the markers) and/or write ``csv``."""
    from gridflow.io import atomic_write

    if csv:
        with atomic_write(csv, "w") as fh:
            table[["id", "verdict", "numbers"]].to_csv(fh, index=False)
    if doc:
        doc = Path(doc)
        text = doc.read_text() if doc.exists() else ""
        block = render_markdown(table, source)
        if START in text and END in text:
            text = text[:text.index(START)] + block + text[text.index(END) + len(END):]
        else:
            text = text + ("\n" if text else "") + block + "\n"
        with atomic_write(doc, "w") as fh:
            fh.write(text)
