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
                                               (0.3, "0.2..0.3", "does not hold")])
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


# --- every level of the checker, just below and just above ---------------------------------
#
# The levels are written here as numbers (not imported from the module under test), so a
# level changed in bench/claims.py fails here.  Each case sets one value of the ideal
# sweep to the level times (1 - 1 %) and times (1 + 1 %) and says which side holds.

BELOW, ABOVE = 0.99, 1.01


def _at(param, model, quantity, value, noise, fn):
    """A change of the ideal sweep: ``fn(val, xm)`` at one point of one curve."""
    def change(p, m, q, v, n, val):
        if (p, m, q, noise) == (param, model, quantity, n) and abs(v) == value:
            return fn(val)
        return val
    return change


def _curve_change(param, model, quantity, noise, fn):
    """``fn(|value|, val)`` over a whole curve."""
    def change(p, m, q, v, n, val):
        if (p, m, q, n) == (param, model, quantity, noise):
            return fn(abs(v), val)
        return val
    return change


FULL_A1_ON_A1X = {a: 1e-4 + 5 * a for a in A1X}       # _ideal's full-model a1 error on a1x


LEVELS = [
    # (observation, what, change at the level times k, verdict below, verdict above); a
    # failing core part (the sentence's number) gives "does not hold", another "partly"
    ("1", "Q_rel(a1) < 0.25 % for 0.1 <= a1 < 1",
     lambda k: _at("a1", "full", "a1", 0.5, 0.0, lambda v: 0.0025 * k), "holds",
     "does not hold"),
    ("1", "beyond a1 = 1 at most 5 %",
     lambda k: _at("a1", "full", "a1", 2.0, 0.0, lambda v: 0.05 * k), "holds", "partly"),
    ("2", "log-log slope at least 0.8",
     lambda k: _curve_change("a2", "full", "a2", 0.0,
                             lambda a, v: 1.3 * a ** (0.8 * k) if a else v),
     "does not hold", "holds"),
    ("2", "log-log slope at most 1.2",
     lambda k: _curve_change("a2", "full", "a2", 0.0,
                             lambda a, v: 1.3 * a ** (1.2 * k) if a else v),
     "holds", "does not hold"),
    ("3", "HF's a1 error at the largest a1x twice full's",
     lambda k: _at("a1x", "hf", "a1", 0.1, 0.0, lambda v: 2 * k * FULL_A1_ON_A1X[0.1]),
     "partly", "holds"),
    ("3", "HF's a1 error at least 0.9 x full's at every a1x",
     lambda k: _at("a1x", "hf", "a1", 0.01, 0.0, lambda v: 0.9 * k * FULL_A1_ON_A1X[0.01]),
     "partly", "holds"),
    ("3", "strong cross-talk: 10x the error at a1x = 0",
     lambda k: _at("a1x", "full", "a1", 0.1, 0.0, lambda v: 10 * k * 1e-4), "does not hold",
     "holds"),
    ("4", "HF/full a2 error ratio at most 2",
     lambda k: _at("a2x", "hf", "a2", 0.01, 0.0, lambda v: 2 * k * v), "holds", "does not hold"),
    ("4", "HF/full a2 error ratio at least 1/2",
     lambda k: _at("a2x", "hf", "a2", 0.01, 0.0, lambda v: 0.5 * k * v), "does not hold", "holds"),
    ("5", "leak below 1 % of the perturbation",
     lambda k: _at("a2", "hf", "a1", 0.3, 0.0, lambda v: v + 0.01 * k * 0.3),
     "holds", "partly"),
    ("6", "top decade ratio at least 10",
     lambda k: _curve_change("a1x", "hf", "a2", 0.0,
                             lambda a, v: 10 * k * (1e-7 + 1e-5 * a) if a >= 0.01 else v),
     "does not hold", "holds"),
    ("6", "top decade ratio at most 10^2.5",
     lambda k: _curve_change("a1x", "hf", "a2", 0.0,
                             lambda a, v: 10 ** 2.5 * k * (1e-7 + 1e-5 * a) if a >= 0.01
                             else v),
     "holds", "does not hold"),
    ("7", "breaks down: U_Z error above 0.1",
     # (the noisy curve follows, 10 % above, as _ideal has it: obs. 10 unchanged)
     lambda k: lambda p, m, q, v, n, val: (
         0.1 * k * (1.1 if n else 1.0) if (p, m, q) == ("a1", "bcc", "Uz") and v else val),
     "does not hold", "holds"),
    ("7", "does not react: HF's U_Z error below 0.01 for a1 <= 0.1",
     lambda k: _at("a1", "hf", "Uz", 0.1, 0.0, lambda v: 0.01 * k), "holds", "does not hold"),
    ("8", "full stable: U_Z error below 0.01 at every a1x",
     lambda k: _at("a1x", "full", "Uz", 0.05, 0.0, lambda v: 0.01 * k), "holds",
     "does not hold"),
    ("9", "the three models agree within a factor 2 at the smallest |a2|",
     lambda k: _at("a2", "bcc", "Uz", 0.001, 0.0, lambda v: 2 * k * (1e-4 + 1.2 * 0.001)),
     "holds", "partly"),
    ("10", "noise changes the largest values by at most 1.5x",
     lambda k: _at("a2", "full", "Uz", 0.3, 0.025, lambda v: 1.5 * k * (1e-4 + 1.2 * 0.3)),
     "holds", "partly"),
    ("10", "small a1: noise-free U_Z error below 0.005",
     lambda k: _at("a1", "full", "Uz", 0.02, 0.0, lambda v: 0.005 * k), "holds",
     "does not hold"),
    ("10", "small a1: noisy U_Z error at least 0.05",
     lambda k: _at("a1", "full", "Uz", 0.01, 0.025, lambda v: 0.05 * k), "does not hold",
     "holds"),
    ("10", "small a1: noisy U_Z error at most 0.2",
     lambda k: _at("a1", "full", "Uz", 0.01, 0.025, lambda v: 0.2 * k), "holds",
     "does not hold"),
]


@pytest.mark.parametrize("cid, what, change, below, above", LEVELS,
                         ids=[f"obs{c}: {w}" for c, w, *_ in LEVELS])
def test_each_level_just_below_and_just_above(cid, what, change, below, above):
    for k, want in ((BELOW, below), (ABOVE, above)):
        got = _verdicts(_sweep(change(k)))
        assert got[cid] == want, (cid, what, k, got[cid])
        assert {c: v for c, v in got.items() if c != cid} == {
            c: "holds" for c in got if c != cid}, (cid, what, k, got)


def test_breakdown_needs_ten_times_the_full_models_error():
    """"Breaks down" needs Q_rel(U_Z) at least 10x the full model's, besides above 0.1
    (that level: obs. 7 in LEVELS).  On the a2 axis from |a2| = 0.1 on, where the full
    model's ideal error 1e-4 + 1.2 |a2| is itself above 0.1, BCC at 10.1x it is broken
    from 0.1 on, at 9.9x nowhere (below 0.1 BCC keeps the full model's error)."""
    def bcc_times(k):
        def change(p, m, q, v, noise, val):
            if p == "a2" and m == "bcc" and q == "Uz" and noise == 0 and abs(v) >= 0.1:
                return 10 * k * (1e-4 + 1.2 * abs(v))
            return val
        return breakdown(_sweep(change), "bcc", "a2")

    assert bcc_times(ABOVE) == (0.07, 0.1)
    assert bcc_times(BELOW) == (0.3, float("inf"))


def test_breakdown_location_boundaries():
    """"≈ 0.1": the breakdown interval (lo, hi] meets [0.1 / 2, 0.1 * 2]; on the sweep's
    grid of |a2| (.., 0.02, 0.05, 0.07, 0.1, 0.15, 0.2, 0.3) a breakdown from 0.2 on is
    (0.15, 0.2] (lo 0.15 < 0.2: holds), from 0.3 on (0.2, 0.3] (lo not below 0.2: does
    not), from 0.05 on (0.02, 0.05] (hi 0.05 >= 0.05: holds), from 0.02 on (0.01, 0.02]
    (hi below 0.05: does not)."""
    for where, verdict in ((0.2, "holds"), (0.3, "does not hold"), (0.05, "holds"),
                           (0.02, "does not hold")):
        def change(p, m, q, v, noise, val, where=where):
            if p == "a2" and m == "bcc" and q == "Uz" and noise == 0:
                return 100.0 if abs(v) >= where else 1e-4 + 1.2 * abs(v)
            return val
        assert _verdicts(_sweep(change))["9"] == verdict, where


# --- the growth sweep's claims ---------------------------------------------------------------

def _growth_sweep(tr_uz, af_uz):
    """Rows of a growth sweep: the full model's U_Z error under each motion model, as
    functions of the rate, on the growth and the rotation axes."""
    rows = []
    for p in ("growth", "rotation"):
        for v in (0.0, 1e-4, 1e-3, 3e-3, 1e-2):
            for motion, fn in (("translation", tr_uz), ("affine", af_uz)):
                rows.append({"sweep": "growth", "param": p, "value": v, "noise": 0.0,
                             "seed": 0, "model": "full", "motion": motion, "quantity": "Uz",
                             "q": fn(p, v), "q_rel": fn(p, v), "q_abs": 0.0})
    return pd.DataFrame(rows)


@pytest.mark.parametrize("k, tr_verdict", [(BELOW, "does not hold"), (ABOVE, "holds")])
def test_growth_breakdown_level(k, tr_verdict):
    """G1 and G2 read "breaks down" as the paper's observations do: above 0.1 (and 10x
    the affine model's) from some rate on; here at 0.1 x (1 -/+ 1 %) from 1e-3 on."""
    df = _growth_sweep(lambda p, v: 0.1 * k if v >= 1e-3 else 1e-4, lambda p, v: 1e-4)
    got = dict(zip(check_claims(df).id, check_claims(df).verdict))
    assert got == {"G1": tr_verdict, "G2": tr_verdict}


@pytest.mark.parametrize("k, verdict", [(BELOW, "holds"), (ABOVE, "does not hold")])
def test_growth_stability_level(k, verdict):
    """The affine model's U_Z "does not break down": below 0.01 at every rate."""
    df = _growth_sweep(lambda p, v: 1.0 if v >= 1e-3 else 1e-4,
                       lambda p, v: 0.01 * k if v == 1e-2 else 1e-4)
    got = dict(zip(check_claims(df).id, check_claims(df).verdict))
    assert got == {"G1": verdict, "G2": verdict}


def _table(df) -> pd.DataFrame:
    return check_claims(df).set_index("id")


def test_parts_name_what_failed():
    """The verdict says k of n sub-checks and names the failed ones, the core marked."""
    def change(p, m, q, v, noise, val):
        if p == "a1" and m == "hf" and q == "Uz" and noise == 0 and abs(v) == 0.1:
            return 0.02                        # HF reacts on small a1 (a core part of 7)
        return val
    row = _table(_sweep(change)).loc["7"]
    assert row.verdict == "does not hold"
    assert row.parts.startswith("2/3 hold; failed: HF, full below 0.01 for a1 <= 0.1 (core)")
    assert _table(_sweep()).loc["7"].parts == "3/3 hold"


def test_a_reference_mismatch_is_true_by_construction():
    """Measured against the global a1, the full model's a1 error on the a1x axis is
    a1x * mean|X| whatever the estimate does (the review: obs. 3 held by construction
    under the paper setup): that part is named and not counted, and the observation
    cannot hold on it."""
    df = _sweep()
    xm = _x_mean(df)

    def change(p, m, q, v, noise, val):
        if p == "a1x" and q == "a1" and m == "full":
            return 1e-4 + abs(v) * xm
        return val
    row = _table(_sweep(change)).loc["3"]
    assert row.verdict == "partly"
    assert "true by construction, not counted: strong cross-talk, full" in row.parts
    assert "true by construction" not in _table(df).loc["3"].parts


def test_the_u_z_side_of_a2x_not_helping_is_checked():
    """The review: "modelling a2x does not help" was only checked on a2; on U_Z the data
    contradicted it.  HF's U_Z error 10x full's under a2x: obs. 4 partly."""
    def change(p, m, q, v, noise, val):
        if p == "a2x" and q == "Uz" and m == "hf" and v:
            return val * 10
        return val
    row = _table(_sweep(change)).loc["4"]
    assert row.verdict == "partly" and "a2x does not help U_Z" in row.parts


def test_pairs_broken_in_both_runs_are_not_counted_as_unchanged():
    """The review: "largest values unchanged 22/22" counted pairs where both runs had
    broken down.  In the ideal sweep BCC is broken at the two largest |a2| and |a2x| (and
    a1, a1x) with and without noise: those pairs are left out of the count."""
    numbers = _table(_sweep()).loc["10"].numbers
    import re

    k, n = map(int, re.search(r"unchanged by noise: (\d+)/(\d+)", numbers).groups())
    broken = int(re.search(r"(\d+) pairs broken down in both runs", numbers).group(1))
    assert broken >= 4 and k == n
    # every pair of the two largest values of 4 axes x 3 models is counted once
    # (those below the noise floor aside, as the check says)
    assert n + broken <= 4 * 3 * 2
