"""Other readings of the paper's unstated parameters, measured side by side.

``docs/reproduction.md`` argues for the ``paper`` setup's reading by what the alternatives
do to the paper's observations: offset 1 (a positive image), 3-tap derivative filters,
gridflow's inverse-variance combination (each one entry changed in
``bench/sweeps/paper_setup.toml``), and offset 1 under the ``gridflow`` setup.
:func:`readings_table` checks the observations on each reading's sweep
(:func:`~gridflow.bench.claims.check_claims`) and returns, per observation, each reading's
verdict with its sub-checks, and per quantitative statement of the paper gridflow's number
under each (:func:`~gridflow.bench.claims.paper_terms`); :func:`readings_markdown` writes
both as the documentation's block, so the prose there states no number of its own.
``gridflow readings`` (``make readings``) runs :func:`readings_report`.
"""

from __future__ import annotations

import pandas as pd

from .claims import check_claims, paper_terms

__all__ = ["READINGS", "readings_table", "readings_markdown", "readings_report"]

# sweep name -> what it reads differently (the sweeps' own spec files say how)
READINGS = {
    "paper_setup": "the `paper` setup",
    "paper_setup_offset1": "`paper`, offset 1",
    "paper_setup_matched3": "`paper`, 3-tap filters",
    "paper_setup_ivw": "`paper`, inverse-variance weights",
    "paper_offset1": "`gridflow`, offset 1 (noise-free)",
}


def readings_table(sweeps: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Check the observations on each reading's sweep.

    Parameters
    ----------
    sweeps : dict of str to DataFrame
        Sweep name (a key of :data:`READINGS`) to its tidy sweep table.

    Returns
    -------
    verdicts : DataFrame
        One row per (``reading``, observation ``id``): ``verdict``, ``parts``.
    terms : DataFrame
        :func:`~gridflow.bench.claims.paper_terms` with one column pair per reading.
    """
    tables, rows = {}, []
    for name, df in sweeps.items():
        t = check_claims(df)
        tables[name] = t
        rows += [{"reading": name, "id": r.id, "verdict": r.verdict, "parts": r.parts}
                 for r in t.itertuples()]
    return pd.DataFrame(rows), paper_terms(tables)


def readings_markdown(verdicts: pd.DataFrame, terms: pd.DataFrame) -> str:
    """The block of ``docs/reproduction.md``: the verdicts (``k/n``) per observation and
    reading, the readings' summary lines, and the paper's statements with gridflow's
    number under each reading."""
    import re

    names = list(dict.fromkeys(verdicts.reading))
    lines = ["Made by `gridflow readings` (`make readings`: each reading's sweep, "
             "`bench/sweeps/<name>.toml`, into `work/sweeps/`, then the checks of "
             "`bench/claims.py`; `results/readings_verdicts.csv`, `results/readings.csv`).",
             "", "| # | " + " | ".join(READINGS.get(n, n) for n in names) + " |",
             "|---|" + "---|" * len(names)]
    by = verdicts.set_index(["reading", "id"])
    for cid in dict.fromkeys(verdicts.id):
        cells = []
        for n in names:
            r = by.loc[(n, cid)]
            k = re.match(r"(\d+/\d+) hold", str(r.parts))
            cells.append(f"{r.verdict}" + (f" ({k.group(1)})" if k else ""))
        lines.append(f"| {cid} | " + " | ".join(cells) + " |")
    lines.append("")
    for n in names:
        v = verdicts[verdicts.reading == n]
        groups = {w: [str(i) for i in v[v.verdict == w].id]
                  for w in ("holds", "partly", "does not hold", "not tested")}
        said = "; ".join(f"{w}: {', '.join(ids)}" for w, ids in groups.items() if ids)
        lines.append(f"- {READINGS.get(n, n)} (`{n}`): {said}.")
    lines += ["", "The paper's quantitative statements, gridflow's number under each "
              "reading (sub-check verdict in brackets):", "",
              "| # | the paper | " + " | ".join(READINGS.get(n, n) for n in names) + " |",
              "|---|---|" + "---|" * len(names)]
    for r in terms.to_dict("records"):
        cells = [r["id"], r["statement"]] + [f"{r[n]} (**{r[n + ' verdict']}**)"
                                              if r[n] != "" and not pd.isna(r[n])
                                              else f"(**{r[n + ' verdict']}**)"
                                              for n in names]
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)


def readings_report(csvs, *, csv_verdicts, csv_terms, doc=None) -> list[str]:
    """What ``gridflow readings`` does: each sweep CSV of ``csvs`` is the sweep of one
    reading (a name of :data:`READINGS`); :func:`readings_table` on them, written to
    ``csv_verdicts`` and ``csv_terms`` and, with ``doc``, that markdown file's
    ``readings`` block rewritten from the files as written (so the doc and the CSVs agree
    digit for digit).  Every output is checked before anything is read.

    Returns the report's lines: the verdicts, then the files written."""
    from gridflow.errors import UsageError
    from gridflow.io import atomic_write, check_output

    from .markdown import rewrite_block
    from .sweep import read_sweep_csv

    for path, what in ((csv_verdicts, "--csv-verdicts"), (csv_terms, "--csv-terms")):
        check_output(path, suffixes=".csv", inputs=csvs, what=what)
    if doc:
        check_output(doc, suffixes=".md", inputs=csvs, what="--write-doc")
    sweeps = {}
    for path in csvs:
        df = read_sweep_csv(path)
        names = df["sweep"].unique() if "sweep" in df else []
        if len(names) != 1 or names[0] not in READINGS:
            raise UsageError(f"{path}: expected the sweep of one reading ("
                             f"{', '.join(READINGS)}), got "
                             f"{', '.join(map(str, names)) or 'none'}")
        sweeps[names[0]] = df
    verdicts, terms = readings_table(sweeps)
    with atomic_write(csv_verdicts, "w") as fh:
        verdicts.to_csv(fh, index=False)
    with atomic_write(csv_terms, "w") as fh:
        terms.to_csv(fh, index=False)
    lines = [verdicts.to_string(index=False, max_colwidth=100),
             f"wrote {csv_verdicts}, {csv_terms}"]
    if doc:
        rewrite_block(doc, "readings", readings_markdown(
            pd.read_csv(csv_verdicts), pd.read_csv(csv_terms, keep_default_na=False)))
        lines.append(f"wrote {doc}")
    return lines
