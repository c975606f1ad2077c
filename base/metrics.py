"""Error measures: Eq. 22 (named metrics whose ids the CSVs and plots reuse) and the HCI
4-D light field benchmark's disparity scores.

``q_rel`` is the mean absolute relative error, ``q_abs`` the mean absolute error, both over
the pixels free of border effects.  Pixels whose estimate is NaN (degenerate) inside that
region are not averaged but counted (``n_invalid``), so a breakdown is visible instead of
silently dropped.  Following the paper, the headline value ``q`` of a quantity is
``q_rel`` when its reference is bounded away from zero (non-zero and of one sign on every
pixel) and ``q_abs`` otherwise: a local ``a1 = a1x X`` that crosses zero inside the image
would make a relative error meaningless.

:func:`hci_metrics` scores a disparity map as the HCI benchmark does (Honauer et al.,
ACCV 2016): MSE x 100 and BadPix(0.07, 0.03, 0.01) over the image without a 15-pixel
border.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["Metric", "METRICS", "q_rel", "q_abs", "evaluate", "eq22_table", "hci_metrics"]


def _finite_pairs(est: np.ndarray, ref: np.ndarray, mask: np.ndarray):
    est, ref = np.asarray(est, float), np.asarray(ref, float)
    if est.shape != ref.shape or mask.shape != est.shape:
        raise ValueError(f"shape mismatch: estimate {est.shape}, reference {ref.shape}, "
                         f"mask {mask.shape}")
    e, r = est[mask], ref[mask]
    ok = np.isfinite(e)
    return e[ok], r[ok]


def q_rel(est: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    """Mean of ``|Q_i - Q_ref,i| / |Q_ref,i|`` (Eq. 22); NaN if some ``Q_ref,i = 0``.

    Parameters
    ----------
    est, ref : ndarray, shape (H, W)
    mask : ndarray of bool, shape (H, W)
        Pixels to average over.
    """
    e, r = _finite_pairs(est, ref, mask)
    if e.size == 0 or np.any(r == 0):
        return float("nan")
    return float(np.mean(np.abs(e - r) / np.abs(r)))


def q_abs(est: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    """Mean of ``|Q_i - Q_ref,i|`` (Eq. 22).  Parameters as :func:`q_rel`."""
    e, r = _finite_pairs(est, ref, mask)
    return float(np.mean(np.abs(e - r))) if e.size else float("nan")


@dataclass(frozen=True)
class Metric:
    """A named error measure: ``id`` is the CSV column and plot label key."""

    id: str
    description: str
    fn: Callable[[np.ndarray, np.ndarray, np.ndarray], float]


METRICS = {
    "q_rel": Metric("q_rel", "mean absolute relative error (Eq. 22, left)", q_rel),
    "q_abs": Metric("q_abs", "mean absolute error (Eq. 22, right)", q_abs),
}


def evaluate(maps: dict[str, np.ndarray], truth: dict[str, np.ndarray], mask: np.ndarray,
             quantities=None) -> list[dict]:
    """Eq. 22 for every quantity present in both ``maps`` and ``truth``.

    Parameters
    ----------
    maps, truth : dict of str to ndarray, each shape (H, W)
    mask : ndarray of bool, shape (H, W)
        Pixels free of border effects.  Pixels where a quantity's truth is not finite
        (e.g. off the object of a rendered scene) are left out of that quantity.
    quantities : iterable of str, optional
        Restrict to these names.

    Returns
    -------
    list of dict
        One per quantity: ``quantity, q_rel, q_abs, q, measure ('rel' or 'abs'),
        n_pixels, n_invalid``.
    """
    names = [n for n in maps if n in truth] if quantities is None else list(quantities)
    rows = []
    for name in names:
        est, ref = maps[name], np.asarray(truth[name], dtype=float)
        m = mask if np.all(np.isfinite(ref[mask])) else mask & np.isfinite(ref)
        n_inv = int(np.count_nonzero(~np.isfinite(np.asarray(est)[m])))
        rel = METRICS["q_rel"].fn(est, ref, m)
        ab = METRICS["q_abs"].fn(est, ref, m)
        r = ref[m]
        use_rel = bool(np.all(r > 0) or np.all(r < 0))
        rows.append({"quantity": name, "q_rel": rel, "q_abs": ab,
                     "q": rel if use_rel else ab, "measure": "rel" if use_rel else "abs",
                     "n_pixels": int(m.sum()), "n_invalid": n_inv})
    return rows


def eq22_table(rows: list[dict]) -> str:
    """The rows of :func:`evaluate` as a fixed-width text table (a relative error that is
    undefined is shown as '-')."""
    lines = [f"{'quantity':<9} {'Eq. 22':>11} {'measure':>7} {'Q_rel':>11} {'Q_abs':>11} "
             f"{'pixels':>8} {'invalid':>8}"]
    for r in rows:
        rel = f"{r['q_rel']:>11.4g}" if np.isfinite(r["q_rel"]) else f"{'-':>11}"
        lines.append(f"{r['quantity']:<9} {r['q']:>11.4g} {r['measure']:>7} {rel} "
                     f"{r['q_abs']:>11.4g} {r['n_pixels']:>8d} {r['n_invalid']:>8d}")
    return "\n".join(lines)


def hci_metrics(d_est: np.ndarray, d_gt: np.ndarray, border: int = 15) -> dict:
    """The HCI benchmark's scores of a disparity map, by its toolkit's rule.

    Parameters
    ----------
    d_est, d_gt : ndarray, shape (H, W)
        Estimated and true disparity (px per camera step).  Pixels where the truth has no
        (finite) value are not scored (a rendered scene's background; the benchmark's
        truth has one everywhere).  Of the rest, a pixel where the estimate has none is
        left out of the MSE and is not counted as bad in BadPix, as the benchmark's
        evaluation toolkit does (``lightfield-analysis/evaluation-toolkit``:
        ``MSE.get_score`` masks non-finite estimates, ``BadPix`` tests ``|d - gt| > tau``,
        false for NaN); ``n_nonfinite`` says how many there are, so that a sparse map
        cannot pass for a dense one.
    border : int
        Pixels left out at each side (the benchmark's 15).

    Returns
    -------
    dict
        ``mse_x100, badpix_007, badpix_003, badpix_001`` (percent of the scored pixels),
        ``n_pixels`` (scored), ``n_nonfinite`` (of those, estimates without a value).
    """
    e = np.asarray(d_est, float)[border:-border or None, border:-border or None]
    g = np.asarray(d_gt, float)[border:-border or None, border:-border or None]
    has = np.isfinite(g)
    e, g = e[has], g[has]
    ok = np.isfinite(e)
    err = np.abs(e - g)
    out = {"mse_x100": float(100.0 * np.mean(err[ok] ** 2)) if ok.any() else float("nan"),
           "n_pixels": int(g.size), "n_nonfinite": int((~ok).sum())}
    for tau, key in ((0.07, "badpix_007"), (0.03, "badpix_003"), (0.01, "badpix_001")):
        out[key] = (float(100.0 * np.mean(ok & (err > tau))) if g.size else float("nan"))
    return out
