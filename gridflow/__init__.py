"""gridflow: surface motion, depth and slopes from a camera grid under changing
illumination (Schuchert & Scharr, DAGM 2007), with the benchmark that reproduces it.

The numerics live in the top-level packages ``generators`` and ``estimator``; this
package holds the shared data container, metrics, file I/O, sweeps, figures and the CLI.
"""

__version__ = "0.1.0"
