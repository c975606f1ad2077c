"""What a sweep table is, read from its rows: the setup it was run under and whether it
is a sweep of the affine motion model (used by the claims and the figures alike)."""

from __future__ import annotations

import pandas as pd

from gridflow.estimator.models import AFFINE

__all__ = ["setup_label", "is_growth_sweep"]


def is_growth_sweep(df: pd.DataFrame) -> bool:
    """A sweep of the affine motion model (``gridflow sweep growth``): its claims are
    :data:`GROWTH_CLAIMS`, the paper's observations are about the translation model."""
    return "motion" in df and (df.motion == AFFINE.name).any()


def setup_label(df: pd.DataFrame) -> str:
    """The setup a sweep table was run under (``bench.setups``), read from the generator
    and estimator settings its rows record: the named setup whose every entry they carry,
    or the one whose entries they mostly carry with the entries that differ named
    (``"paper setup, zoom_correction True"``); ``"gridflow setup"`` otherwise."""
    import json

    from gridflow.estimator import EstimatorSettings
    from gridflow.generators import SinusoidParams

    from .setups import SETUPS

    # the rows record the settings that differ from the defaults: the rest are these
    gen = {k: (list(v) if isinstance(v, tuple) else v)
           for k, v in SinusoidParams().as_dict().items()}
    est = dict(EstimatorSettings().as_dict())
    if "generator" in df and len(df):
        gen.update(json.loads(df.generator.iloc[0]))
    if "estimator" in df and len(df):
        est.update(json.loads(df.estimator.iloc[0]))

    def same(a, b):
        return (list(a) if isinstance(a, tuple) else a) == b

    best = None
    for name, st in SETUPS.items():
        entries = [(k, v, gen) for k, v in st.base.items()] + \
            [(k, v, est) for k, v in st.estimator.items()]
        if not entries:
            continue
        differ = [(k, got.get(k)) for k, v, got in entries if not same(v, got.get(k))]
        if not differ:
            return f"{name} setup"
        if len(differ) < len(entries) / 2 and (best is None or len(differ) < len(best[1])):
            best = (name, differ)
    if best:
        return f"{best[0]} setup, " + ", ".join(f"{k} {v}" for k, v in best[1])
    return "gridflow setup"
