"""The implementations of the estimator's data passes, behind one interface.

The driver (:mod:`estimator.driver`) does the same three things for every band of image
rows, whatever the method: filter the volume into the derivative signals, form the
structure tensor J, and find each model's null space.  A :class:`Backend` does those three
passes (and the input scan):

================  ==============================  ==================  ===================
backend           signals                         tensor J            null space
================  ==============================  ==================  ===================
``reference``     numpy                           entry by entry,     LAPACK ``eigh``
                                                  65-tap FIR
``grouped``       numpy                           grouped products,   LAPACK ``eigh``
                                                  65-tap FIR
``fft``           numpy                           FFT (numpy.fft)     LAPACK ``eigh``
``numba``         numba kernels                   FFT (scipy.fft),    numba lane solver
                                                  numba products
================  ==============================  ==================  ===================

:func:`select_backend` maps the user's ``method`` onto one of them, in one place:
``"reference"`` and ``"grouped"`` onto themselves, ``"fast"`` onto ``numba`` from
:data:`NUMBA_MIN_PIXELS` image pixels on and onto ``fft`` below (loading the numba
kernels from their cache costs 0.5-0.8 s per process, measured, more than they save on a
small image).  All four give the same answers to the fast path's tolerance
(``tests/test_estimator_properties.py``); ``Estimate.settings["backend"]`` records which
one ran.

Threads: the numba backend runs its kernels on ``numba.get_num_threads()`` threads and its
FFTs on as many ``scipy.fft`` workers; the numpy backends filter the signals on a pool of
:func:`thread_count` threads.  Both follow ``NUMBA_NUM_THREADS``, so one variable (with
the BLAS ones, :data:`gridflow.bench.executors.WORKER_ENV`) bounds a worker process.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from . import signals as sig
from .disentangle import solve_affine
from .models import Model
from .nullspace import NullSpace, null_space
from .tensor import DenseTensor, PackedTensor, structure_tensor, structure_tensor_reference

__all__ = ["Backend", "TensorPlan", "select_backend", "backend_class", "BACKENDS",
           "NUMBA_MIN_PIXELS", "thread_count"]

# The "fast" method runs on numba from this many image pixels on (see the module
# docstring and bench/README.md).
NUMBA_MIN_PIXELS = 128 * 128


def thread_count() -> int:
    """Threads for the estimator's own parallel work outside numba: ``NUMBA_NUM_THREADS``
    where set (as numba itself reads it), else every core."""
    env = os.environ.get("NUMBA_NUM_THREADS", "")
    return int(env) if env.strip().isdigit() and int(env) > 0 else (os.cpu_count() or 1)


@dataclass(frozen=True)
class TensorPlan:
    """What the tensor of a band is made of.

    Attributes
    ----------
    tvals : ndarray, shape (F,)
        Frame offsets of the temporal window from the reference frame.
    rows : tuple of str
        The data rows (those of every model estimated).
    kernels : ndarray, shape (3, window)
        Gaussian-moment kernels (:func:`estimator.tensor.gaussian_moment_kernels`).
    radius : int
        The window's radius: rows of a band's signals beyond the spatial filters' reach
        that each kept row's window needs.
    spatial_radius : int
        Rows at a band's edges whose signals are not valid (the 5-tap filters' reach).
    cols : slice
        The image columns kept (the interior).
    combine : tuple, optional
        ``(rows, terms)`` of :func:`estimator.tensor.zoom_terms`: the tensor wanted is
        over these rows, each the sum of the ``terms`` of ``rows`` above (the zoom-blur
        correction).  The FFT backends sum in the spectral domain; the others return
        J over ``rows`` above, which the driver then combines.
    """

    tvals: np.ndarray
    rows: tuple[str, ...]
    kernels: np.ndarray
    radius: int
    spatial_radius: int
    cols: slice
    combine: tuple | None = None


class Backend:
    """The numpy signals and LAPACK null space that every backend but ``numba`` shares;
    subclasses supply the tensor.

    Methods (each backend gives the same results to its tolerance):

    ``scan(volume)``
        ``(non-finite count, max |V|)`` in one pass, or None to let the driver check the
        volume frame by frame.
    ``signals(volume, plan, rows)``
        The base signals of a band of image rows (:mod:`estimator.signals`):
        ``from_sums(camera_sums(volume, plan, rows), plan)``.
    ``camera_sums(volume, plan, rows)``
        The camera sums of the band, shape (C, len(plan.needed), h, W), float64
        (:func:`estimator.signals.camera_sums`; each frame's independent of the others).
    ``from_sums(sums, plan)``
        The base signals from the camera sums (the temporal taps, then x and y).
    ``tensor(signals, plan)``
        J of the band's kept pixels, a :class:`~estimator.tensor.DenseTensor` or
        :class:`~estimator.tensor.PackedTensor`.
    ``null_space(J, model)``
        The model's :class:`~estimator.nullspace.NullSpace` from its sub-block of J.
    ``null_space_parts(J, model, stops)``
        The same, part by part (a generator): the NullSpace of pixels ``[0, stops[0])``,
        then ``[stops[0], stops[1])``, ..., each the same bits as those pixels of
        ``null_space``'s; the numba backend solves the pixels as the parts reach them,
        so that a band's outputs are not all held at once.
    ``solve_affine(obs, Z, Zx, Zy, x0, y0, f, var_obs=None, sensitivity=False)``
        The affine model's per-pixel 9 x 9 systems
        (:func:`estimator.disentangle.solve_affine`).
    """

    name = "numpy"
    # whether tensor() returns a PackedTensor (estimator.driver.band_rows sizes its bands)
    packed = False
    # whether tensor() takes signals given frame by frame (estimator.signals.FrameStack:
    # a recording's frames kept across its steps, estimator.driver)
    frame_stacks = False
    solve_affine = staticmethod(solve_affine)

    def scan(self, volume: np.ndarray):
        return None

    def signals(self, volume: np.ndarray, plan: sig.SignalPlan, rows: slice) -> dict:
        return self.from_sums(self.camera_sums(volume, plan, rows), plan)

    def camera_sums(self, volume: np.ndarray, plan: sig.SignalPlan, rows: slice):
        return sig.camera_sums(volume, plan, rows)

    def from_sums(self, sums: np.ndarray, plan: sig.SignalPlan) -> dict:
        ct = sig.temporal_taps(sums, plan)
        del sums
        jobs = sig.spatial_jobs(ct, plan.spatial, plan.extra)
        del ct
        from concurrent.futures import ThreadPoolExecutor

        # numpy releases the GIL in its loops: the six signals are filtered on all cores
        with ThreadPoolExecutor(max_workers=thread_count()) as ex:
            return dict(zip(jobs, ex.map(lambda job: sig.separable(*job), jobs.values())))

    def tensor(self, signals: dict, plan: TensorPlan):
        raise NotImplementedError

    def null_space(self, J, model: Model) -> NullSpace:
        return null_space(J.block(model.rows), model)

    def null_space_parts(self, J, model: Model, stops):
        ns = self.null_space(J, model)
        a = 0
        for b in stops:
            yield NullSpace(*(x[a:b] for x in ns[:4]), ns.fallbacks)
            a = b


class _DenseBackend(Backend):
    """A 65-tap FIR tensor (``_fir``), full matrices per pixel."""

    _fir = None

    def tensor(self, signals: dict, plan: TensorPlan) -> DenseTensor:
        J = self._fir(signals, plan.tvals, plan.rows, plan.kernels, plan.radius)
        rs, n = plan.spatial_radius, len(plan.rows)
        # the window's rows are dropped already; the filters' rows and the border columns
        # here
        return DenseTensor(J[rs:J.shape[0] - rs, plan.cols].reshape(-1, n, n), plan.rows)


class ReferenceBackend(_DenseBackend):
    """The straightforward implementation: every entry of J its own separable correlation,
    LAPACK for every pixel (the baseline of ``bench/``)."""

    name = "reference"
    _fir = staticmethod(structure_tensor_reference)


class GroupedBackend(_DenseBackend):
    """Direct 65-tap smoothing of the grouped products, LAPACK for every pixel."""

    name = "grouped"
    _fir = staticmethod(structure_tensor)


class FFTBackend(Backend):
    """The FFT tensor with ``numpy.fft`` and LAPACK: the fast method on small images."""

    name = "fft"
    packed = True

    def tensor(self, signals: dict, plan: TensorPlan) -> PackedTensor:
        from .spectral import structure_tensor_fft

        planes, idx = structure_tensor_fft(signals, plan.tvals, plan.rows, plan.kernels,
                                           plan.radius + plan.spatial_radius,
                                           cols=plan.cols, fft="numpy", combine=plan.combine)
        return PackedTensor(planes.reshape(planes.shape[0], -1), idx,
                            plan.combine[0] if plan.combine else plan.rows)


class NumbaBackend(Backend):
    """Numba kernels for the input scan, the camera sums, the x/y filtering and the FFT
    tensor's products (:mod:`estimator._kernels`), ``scipy.fft`` for the transforms, and
    the numba null-space solver (:mod:`estimator._solver`) and affine solve
    (:mod:`estimator._affine`)."""

    name = "numba"
    packed = True

    def __init__(self):
        from . import _affine, _kernels, _solver, jit

        # before the first kernel is called: compiling them takes 20-40 s the first time
        jit.announce_compilation((_kernels, _solver, _affine))
        self._kernels, self._solver = _kernels, _solver
        self.solve_affine = _affine.solve_affine_kernel
        import numba

        self.threads = numba.get_num_threads()

    def scan(self, volume: np.ndarray):
        return self._kernels.scan_volume(volume)

    def camera_sums(self, volume: np.ndarray, plan: sig.SignalPlan, rows: slice):
        r0, r1, step = rows.indices(volume.shape[3])
        if step != 1:
            raise ValueError(f"rows must be a contiguous band, got {rows}")
        return self._kernels.camera_sums(volume, plan.needed, plan.iy0, plan.ix0, r0, r1,
                                         plan.weights)

    def from_sums(self, sums: np.ndarray, plan: sig.SignalPlan) -> dict:
        ct = sig.temporal_taps(sums, plan)
        del sums
        return {k: self._kernels.spatial_filter(a, kx, ky)
                for k, (a, kx, ky) in sig.spatial_jobs(ct, plan.spatial, plan.extra).items()}

    frame_stacks = True

    def _frames_product(self):
        """The tensor's ``product`` over :class:`~estimator.signals.FrameStack` signals."""
        made = {}

        def frames(stack):
            # each signal's frames checked and addressed once for all its products
            if id(stack) not in made:
                made[id(stack)] = (stack, self._kernels.frames_of(stack.frames))
            return made[id(stack)][1]

        def product(coefs, a, b, shape, out):
            # the scales into the frame weights: ((c s_a s_b) a) b rounds as
            # (c (s_a a)) (s_b b) does, for powers of two within the normal range
            return self._kernels.weighted_product_frames(
                coefs * (a.scale * b.scale), frames(a), frames(b), shape, out)
        return product

    def tensor(self, signals: dict, plan: TensorPlan) -> PackedTensor:
        from .spectral import structure_tensor_fft

        framed = isinstance(next(iter(signals.values())), sig.FrameStack)
        product = self._frames_product() if framed else self._kernels.weighted_product
        planes, idx = structure_tensor_fft(signals, plan.tvals, plan.rows, plan.kernels,
                                           plan.radius + plan.spatial_radius,
                                           cols=plan.cols, fft="scipy", workers=self.threads,
                                           product=product,
                                           cmul=self._kernels.complex_multiply,
                                           cmul2=self._kernels.complex_multiply_2d,
                                           combine=plan.combine)
        return PackedTensor(planes.reshape(planes.shape[0], -1), idx,
                            plan.combine[0] if plan.combine else plan.rows)

    def null_space(self, J: PackedTensor, model: Model) -> NullSpace:
        return self._solver.null_space_packed(J.planes, J.sub_index(model.rows), model)

    def null_space_parts(self, J: PackedTensor, model: Model, stops):
        return self._solver.null_space_parts(J.planes, J.sub_index(model.rows), model,
                                             stops, ahead=max(16, 8 * self.threads))


BACKENDS = {b.name: b for b in (ReferenceBackend, GroupedBackend, FFTBackend, NumbaBackend)}


def backend_class(method: str, shape) -> type:
    """The class of :func:`select_backend`'s backend, without making one (the numba
    backend's loads numba and its kernels): for planning."""
    if method == "fast":
        large = len(shape) == 5 and shape[-1] * shape[-2] >= NUMBA_MIN_PIXELS
        return NumbaBackend if large else FFTBackend
    if method in ("grouped", "reference"):
        return BACKENDS[method]
    raise ValueError(f"method must be one of 'fast', 'grouped', 'reference', got {method!r}")


def select_backend(method: str, shape) -> Backend:
    """The backend that runs ``method`` on a volume of ``shape`` (T, Sy, Sx, H, W).

    Parameters
    ----------
    method : {"fast", "grouped", "reference"}
        :data:`estimator.settings.METHODS`.
    shape : tuple of int
    """
    return backend_class(method, shape)()
