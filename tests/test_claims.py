"""The claims checker is held to the standard of the code it checks: on a synthetic sweep
built to satisfy every observation each check says "holds", and each of the review's
counterexamples (an effect missing, or present only by a lenient reading) turns exactly
its observation to something else."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from gridflow.bench.claims import _x_mean, breakdown, check_claims

A1 = [0, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 1.5, 2.0]
A1X = [0, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.03, 0.05, 0.07, 0.1]
A2 = [0, -0.001, -0.002, -0.005, -0.01, -0.02, -0.05, -0.07, -0.1, -0.15, -0.2, -0.3]
A2X = [0, -0.0005, -0.001, -0.002, -0.005, -0.01, -0.015, -0.02, -0.03, -0.05]
AXES = {"a1": A1, "a1x": A1X, "a2": A2, "a2x": A2X}
NOISE_AT_0 = 0.08          # the noisy U_Z error that noise alone causes ("nearly 0.1")


def _ideal(param, model, quantity, v, noisy, xm):
    """An error curve that satisfies every observation (the paper's world)."""
    a = abs(v)
    if quantity == "Uz":
        if param == "a1":
            sys_ = 1.0 if (model == "bcc" and a > 0) else 1e-4
        elif param == "a1x":
            sys_ = 1e-4
            if model == "bcc" and a >= 0.01 or model == "hf" and a >= 0.05:
                sys_ = 1.0
        elif param == "a2":
            sys_ = 100.0 if (model == "bcc" and a >= 0.1) else 1e-4 + 1.2 * a
        else:
            sys_ = 100.0 if (model == "bcc" and a >= 0.02) else 1e-4 + 1.2 * a * xm
        if not noisy:
            return sys_
        return 1.1 * sys_ if sys_ >= NOISE_AT_0 else NOISE_AT_0
    if quantity == "a1":
        if param == "a1":
            return 1e-4 if a == 0 else (0.001 if a <= 1 else 0.01 * a)
        if param == "a1x":
            return 1e-4 + (12 if model == "hf" else 5) * a
        return 2e-4                                        # no leak from a2, a2x
    if quantity == "a2":
        if param == "a2":
            return 1e-7 if a == 0 else 1.3 * a
        if param == "a2x":
            return 1e-7 + 2 * a
        if param == "a1x":
            full = 1e-7 + 1e-5 * a
            return 100 * full if model == "hf" else full
        return 1e-7
    raise AssertionError(quantity)


def _sweep(change=None) -> pd.DataFrame:
    gen = json.dumps({})
    est = json.dumps({})
    xm = _x_mean(pd.DataFrame({"generator": [gen], "estimator": [est]}))
    rows = []
    for p, values in AXES.items():
        for v in values:
            for noise in (0.0, 0.025):
                for m in ("bcc", "hf", "full"):
                    for q in (("Uz",) if m == "bcc" else ("Uz", "a1", "a2")):
                        val = _ideal(p, m, q, v, noise > 0, xm)
                        if change:
                            val = change(p, m, q, v, noise, val)
                        rows.append({"sweep": "synthetic", "param": p, "value": float(v),
                                     "noise": noise, "seed": 0, "model": m, "quantity": q,
                                     "q": val, "generator": gen, "estimator": est})
    return pd.DataFrame(rows)


def _verdicts(df) -> dict:
    return dict(zip(check_claims(df).id, check_claims(df).verdict))


def test_every_observation_holds_on_the_ideal_sweep():
    v = _verdicts(_sweep())
    assert v == {str(i): "holds" for i in range(1, 11)}, v


def _only(changed: dict, cid: str):
    assert changed[cid] != "holds", changed
    others = {k: x for k, x in changed.items() if k != cid}
    assert set(others.values()) == {"holds"}, changed


def test_breaks_down_needs_an_absolute_level():
    """The review: "breaks down" was met by any error 10x the full model's, even 2.7e-3."""
    def change(p, m, q, v, noise, val):
        if p == "a1" and m == "bcc" and q == "Uz" and noise == 0 and v > 0:
            return 2.7e-3                                  # 27x full, but 0.27 %
        return val
    _only(_verdicts(_sweep(change)), "7")


def test_one_to_two_orders_has_an_upper_bound():
    def change(p, m, q, v, noise, val):
        if p == "a1x" and m == "hf" and q == "a2":
            return val * 1000                               # 10^5 instead of 10^2
        return val
    _only(_verdicts(_sweep(change)), "6")


def test_a_breakdown_must_last():
    """The review: obs. 8 looked only at the last point."""
    def change(p, m, q, v, noise, val):
        if p == "a1x" and m == "hf" and q == "Uz" and abs(v) == 0.07:
            return 1e-4                                     # HF recovers in between
        return val
    df = _sweep(change)
    assert breakdown(df, "hf", "a1x") == (0.07, 0.1)
    assert _verdicts(df)["8"] == "holds"                    # broken for good from 0.1 on

    def change2(p, m, q, v, noise, val):
        if p == "a1x" and m in ("hf", "bcc") and q == "Uz" and abs(v) == 0.1:
            return 1e-4                                     # neither broken at the end
        return val
    _only(_verdicts(_sweep(change2)), "8")


def test_noise_must_reach_nearly_a_tenth():
    """The review: obs. 10 never checked the level reached."""
    def change(p, m, q, v, noise, val):
        if q == "Uz" and noise > 0 and val == NOISE_AT_0:
            return 0.01                                     # noise raises it to 1 % only
        return val
    _only(_verdicts(_sweep(change)), "10")


def test_a2_and_a2x_errors_are_compared():
    """The review: obs. 9 never compared the a2 and a2x errors."""
    def change(p, m, q, v, noise, val):
        if p == "a2x" and q == "Uz" and m != "bcc":
            return val * 10
        return val
    _only(_verdicts(_sweep(change)), "9")


@pytest.mark.parametrize("where, x, verdict", [(0.07, "0.05..0.07", "holds"),
                                               (0.3, "0.2..0.3", "partly")])
def test_breakdown_location_is_checked(where, x, verdict):
    """BCC breaking at |a2| ~ 0.06 is "≈ 0.1" (within a factor 2); at 0.25 it is not."""
    def change(p, m, q, v, noise, val):
        if p == "a2" and m == "bcc" and q == "Uz" and noise == 0:
            return 100.0 if abs(v) >= where else 1e-4 + 1.2 * abs(v)
        return val
    df = _sweep(change)
    lo, hi = breakdown(df, "bcc", "a2")
    assert f"{lo:g}..{hi:g}" == x
    assert _verdicts(df)["9"] == verdict


def test_a_tiny_difference_does_not_fail_observation_3():
    """The review: obs. 3 failed on a 1e-4 difference; HF within 10 % below full at small
    a1x is the estimates' scatter, not a contradiction."""
    def change(p, m, q, v, noise, val):
        if p == "a1x" and m == "hf" and q == "a1" and 0 < abs(v) < 0.1:
            return 1e-4 + 5 * abs(v) * 0.95
        return val
    assert _verdicts(_sweep(change))["3"] == "holds"
