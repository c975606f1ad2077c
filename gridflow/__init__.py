"""gridflow: surface motion, depth and slopes from a camera grid under changing
illumination (Schuchert & Scharr, DAGM 2007), with the benchmark that reproduces it.

The package stacks in layers; no module imports from a layer above its own:

- :mod:`gridflow.bench`: the benchmark (sweeps, metrics of Eq. 22, observation checks,
  figures, the cube experiment, throughput) and the command-line interface;
- :mod:`gridflow.generators`, :mod:`gridflow.scenes`: the data sources (sinusoid volumes;
  the POV-Ray cube and its rendering);
- :mod:`gridflow.estimator`: the structure-tensor estimator (numerics only);
- this package's own modules, the shared base: the volume container
  (:mod:`gridflow.volume`) and the file formats (:mod:`gridflow.io`: npz and atomic
  writes; :mod:`gridflow.loader`: camera-grid image folders).

The model, its conventions and where gridflow departs from the paper are in
``docs/model.md``.
"""

__version__ = "0.2.0"
