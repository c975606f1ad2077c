"""gridflow: surface motion, depth and slopes from a camera grid under changing
illumination (Schuchert & Scharr, DAGM 2007), with the benchmark that reproduces it.

One installed namespace, ``gridflow``, made of the repository's top-level folders (a
setuptools ``package-dir`` mapping; README, *Layout*).  The layers, bottom to top; no
module imports from a layer above its own, nor in a circle:

- ``gridflow`` itself (the folder ``base/``): the shared base: the volume container
  (:mod:`gridflow.volume`), the errors reported to users (:mod:`gridflow.errors`) and the
  file formats (:mod:`gridflow.io`: npz and atomic writes; :mod:`gridflow.loader`:
  camera-grid image folders; :mod:`gridflow.hci`: HCI light field scenes);
- :mod:`gridflow.estimator` (``estimator/``): the structure-tensor estimator (numerics
  only; imports nothing of the project);
- :mod:`gridflow.generators`, :mod:`gridflow.scenes` (``generators/``, ``scenes/``): the
  data sources (sinusoid volumes; the POV-Ray cube and its rendering);
- :mod:`gridflow.bench` (``bench/``): the benchmark (sweeps, metrics of Eq. 22, the
  paper's observations, figures, the cube experiment, peers, throughput) and, on top,
  the command-line interface :mod:`gridflow.bench.cli`.

The model, its conventions and where gridflow departs from the paper are in
``docs/model.md``; how the code is organised, with the path of one estimate through it,
in ``docs/architecture.md``.
"""

__version__ = "0.2.0"
