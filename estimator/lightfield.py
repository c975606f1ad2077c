"""Static light fields with disparities beyond the derivative filters' range.

The camera-axis derivative filters see a point's displacement between neighbouring views
only while it is well below one wavelength of the texture: in practice disparities of
about +-1 px per view.  Beyond that this field shears (refocuses) the light field: view
``(r, c)`` shifted by ``s (c - cc)`` pixels in x and ``s (r - cc)`` in y brings points of
disparity ``s`` to disparity 0, so the estimator sees the residual ``d - s`` only.
:func:`estimate_refocused` does so for a set of integer shears (integer shifts move
pixels exactly, with no interpolation) and chooses, per pixel, one shear's estimate
(admissible: within half a pixel of its shear).  Four ways to choose:

``select="coarse"``
    The shear nearest to a coarse disparity, from the same estimator on the light field
    low-passed in x and y (a Gaussian of ``coarse_sigma`` px): without fine texture the
    views' shifts stay within the filters' range even at several pixels per view, where
    fine periodic texture aliases (a shear far from the truth can then fit the data as
    well as the right one, which a choice by model error alone falls for).  The coarse
    pass's wide window carries a bright foreground's disparity over thin background
    next to it (fattening), and where the low-pass leaves little it does not help: on
    the periodic grid of ``bench/README.md`` it does worse than ``"lines"``.
``select="occlusion"``
    For scenes with occlusions.  Per shear, the estimate is taken from whichever of
    (a) the camera sub-grids at the centre, edges and corners of the grid (on 9 x 9
    views, nine 5 x 5 sub-grids: all 81 views; a point near an occluding edge is
    unoccluded in the sub-grid on its own side) and (b) the windows shifted by up to
    their radius that still cover the pixel (one of them lies on the pixel's own side
    of an edge) fits best, i.e. has the smallest model error.  Across shears, the log
    model errors are aggregated by a guided filter (He, Sun and Tang, ECCV 2010) on the
    centre view, so each pixel pools the costs of neighbours of its own brightness,
    and the smallest wins.
``select="lines"`` (the default)
    As ``"occlusion"``, with 1-D camera sub-grids instead of square ones: segments of
    ``subgrid`` views along the centre row and the centre column of the grid (on 9 x 9
    views: three of each, 17 views).  A row of cameras moves a point along x only, so
    an occluding edge running along x hides nothing from it (and likewise a column for
    edges along y): thin structures between foreground stripes, where every square
    sub-grid has views in which the gap is covered, keep their own disparity.  This is
    the light-field counterpart of estimating on horizontal and vertical epipolar-plane
    images and keeping the more confident (Wanner and Goldluecke).
``select="epi"``
    As ``"lines"``, but each segment of views estimated on its epipolar-plane images
    themselves (:func:`_epi_line`): a row of views is a stack of EPIs, one per image
    row, and its disparity is the total-least-squares fit of ``d I_x = I_s`` (``s`` the
    camera along the row) over a window along x alone, with no filtering across the
    rows; the windows are shifted along the line only.  The 5 x 5 window and the
    y-prefilter of the estimator mix every structure thinner than about 9 px with what
    lies next to it; an EPI row does not.  ``bench/README.md`` (*Light fields*)
    measures it beside ``"lines"``.

With ``"lines"``, ``"epi"`` and ``"occlusion"``, a region whose shear the data leave open (smooth or
texture-poor: every shear fits about as well, or a shear two or more steps from the best
fits as well as it) takes the shear nearest the confirmed coarse disparity of the
decimated light field (``smooth``; :func:`_prior_cost`).

``gridflow peers`` scores them side by side (``results/peers_depth.csv`` for the
rendered cube).
"""

from __future__ import annotations

import numpy as np

from .driver import estimate
from .portable import gaussian_taps, log10
from .result import Estimate
from .settings import DEFAULTS, EstimatorSettings, InputError

__all__ = ["shear", "estimate_refocused", "REFOCUS_TUNING", "SELECT_DEFAULTS", "SELECTS",
           "stated_shears", "estimate_shear_range", "check_shears"]

# (sigma px, window taps) of each shear choice when not given: the occlusion-aware choices
# work with small windows (their shifted windows and sub-grids handle the edges), the
# coarse one keeps the estimator's usual light-field window
SELECT_DEFAULTS = {"lines": (1.0, 5), "occlusion": (1.0, 5), "coarse": (2.0, 9),
                   "epi": (3.5, 21)}
# (the EPI window lies along the line alone, so its length costs no thin structure
# across it: of sigma 1.5 ... 6 px measured on bench/README.md's synthetic scenes, 3.5 px
# left no smooth-wall pixel off by a pixel and the fewest of the periodic grid and the
# faint bar; bench/README.md, *Light fields*)
# the ways to choose a pixel's shear, the default first: the 1-D sub-grids handle
# occlusions and thin structures, where most light-field scenes lose their depth
SELECTS = ("lines", "occlusion", "coarse", "epi")


def stated_shears(disp_range) -> range | None:
    """The integer shears covering a stated disparity range ``(min, max)`` (px per view;
    an HCI scene's ``parameters.cfg`` states one), or None where none is stated.  A range
    object: a wild statement is refused by :func:`check_shears` before it is spelt out."""
    if not disp_range:
        return None
    lo, hi = (float(x) for x in disp_range)
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise InputError(f"disparity range must be finite with min <= max, got "
                         f"{disp_range[0]!r} .. {disp_range[1]!r}")
    return range(int(np.floor(lo)), int(np.ceil(hi)) + 1)


def check_shears(shears, n: int, H: int, W: int, what: str = "shears") -> None:
    """Refuse shears that move the outer views' pixels out of the image: at ``|s| (n // 2)
    >= min(H, W) / 2`` px no pixel has all its views, so nothing could be estimated
    (and sweeping them would only cost time)."""
    reach = max(1, (min(H, W) // 2 - 1) // max(1, n // 2))
    # a range by its ends, without spelling it out
    ends = (shears[0], shears[-1]) if isinstance(shears, range) else shears
    lo, hi = min(ends), max(ends)
    if max(abs(lo), abs(hi)) > reach:
        raise InputError(f"{what} {lo} .. {hi}: beyond +-{reach} px per view a {n}x{n} grid "
                         f"of {H}x{W} views moves every pixel's outer views out of the "
                         "image")


def estimate_shear_range(views: np.ndarray, *, filters: str = DEFAULTS["filters"],
                         coverage: float = 2.0) -> tuple[tuple[int, ...], dict]:
    """The integer shears covering a light field's disparities, from the data: a coarse
    pass where no range is stated (an HCI scene's ``parameters.cfg`` states one).

    The views are low-passed and decimated by ``k`` in x and y, which divides every
    disparity by ``k``; the estimator (model ``bcc``, sigma 1 px, 5 taps, the central
    5 x 5 views) then follows disparities of up to about ``k`` px per view within its
    camera filters' reach of about 1 px.  Starting at the coarsest level (``k = 8``, or
    as coarse as leaves 32 px), the next finer level is tried while the disparities found
    stay within that reach there, and kept unless its own go far beyond it (over twice
    the reach: the estimator has failed there): the range comes from the finest level
    that resolves it (the finer the level, the less a low-pass mixes thin structures
    with what lies behind them).

    Only confirmed estimates count: the same estimator on the centre row of views alone
    and on the centre column alone must agree with the grid's estimate and with each
    other, pixel by pixel and as an RMS over the window, within a quarter of the filters'
    reach (:data:`_AGREE`).  In a smooth or texture-poor region the data do not fix the
    disparity and the two disagree (noise, the aperture problem); near an occluding edge
    and on aliased texture the row and the column see different things.  Without this
    a large smooth wall's estimates, within the filters' reach but anywhere in it, set
    the range's tails (shears -12 .. 14 for a scene of -3 .. 2.4 px per view;
    ``tests/test_lightfield.py``).

    Parameters
    ----------
    views : ndarray, shape (n, n, H, W)
        A static light field (HCI sign, camera steps as the unit of disparity), n odd.
    filters : str
        Derivative filters of the coarse pass.
    coverage : float
        The range spans the central ``100 - coverage`` per cent of the confirmed coarse
        disparities (``coverage / 2`` per cent left out at each end: single wild pixels
        do not widen it).

    Returns
    -------
    shears : tuple of int
        ``floor(lo) .. ceil(hi)``, as for a stated range (:func:`stated_shears`).
    info : dict
        ``lo``, ``hi`` (the confirmed coarse disparities' percentiles, px per view),
        ``k`` (the decimation used) and ``levels``: each level tried as a tuple ``(k,
        lo, hi, confirmed)``, ``confirmed`` the fraction of its estimated pixels
        confirmed; ``lo`` and ``hi`` are None at a level with fewer than 16 confirmed.
    """
    v = np.asarray(views, dtype=np.float64)
    if v.ndim != 4 or v.shape[0] != v.shape[1] or v.shape[0] % 2 == 0:
        raise InputError(f"views must have shape (n, n, H, W) with n odd, got {v.shape}")
    H, W = v.shape[-2:]
    v = _central(v)
    ks = [k for k in (8, 4, 2, 1) if min(H, W) // k >= 32] or [1]
    levels = []
    chosen = None
    for k in ks:
        d, confirmed = _confirmed(_decimated(v, k), filters)
        estimated = int(np.isfinite(d).sum())
        d = d[confirmed]
        if d.size < 16:
            levels.append((k, None, None, d.size / max(estimated, 1)))
            continue
        lo, hi = (float(q) * k for q in np.percentile(d, [coverage / 2, 100 - coverage / 2]))
        levels.append((k, lo, hi, d.size / max(estimated, 1)))
        if chosen is not None and max(abs(lo), abs(hi)) / k > 2 * _REACH:
            # far beyond this level's filters (aliasing, the texture lost in the
            # decimation): the coarser level's range stands
            break
        chosen = (k, lo, hi)
        if max(abs(lo), abs(hi)) / (k / 2) > _REACH:
            break           # the next finer level would not follow these disparities
    if chosen is None:
        raise InputError(f"views of {H}x{W} px: too few pixels with a confirmed coarse "
                         "disparity (texture the row and the column of views agree on); "
                         "state the range (shears MIN MAX)")
    k, lo, hi = chosen
    shears = tuple(range(int(np.floor(lo)), int(np.ceil(hi)) + 1))
    return shears, {"lo": lo, "hi": hi, "k": k, "levels": levels}


# How far (in multiples of the level's decimation k, full-resolution px) a coarse estimate
# reaches: the low-pass before decimating (3 sigma = 1.5 k, :func:`_lowpass`), the coarse
# estimator's window (5 taps: 2 coarse px = 2 k) and its derivative filters (5 taps: 2 k)
_COARSE_SUPPORT = 1.5 + 2.0 + 2.0
# Where the data leave a pixel's shear open: the aggregated cost of its best shear within
# a factor of two (log10 2 decades) of its median over the shears, or of its best rival
_OPEN_DECADES = float(np.log10(2.0))
# A rival of the best shear: a shear at least this many steps from it (a neighbouring
# shear fits a disparity between the two about as well: no rival).  On a texture-poor
# surface every shear's cost is noise, and the least of a pixel's many windows and
# sub-grids at one shear can undercut the others'; near texture the wrong shears cost
# more and the spread looks decided, while the far shear of such a lucky window and the
# right one still tie (bench/README.md, *Light fields*)
_RIVAL_STEPS = 2
# The coarse disparity's cost, decades of model error per px per view between a shear
# and it: where the data leave the shear open (costs within _OPEN_DECADES) it decides
_PRIOR_DECADES = 1.0


def _central(views: np.ndarray) -> np.ndarray:
    """The views the coarse pass uses, shape (m, m, H, W): the camera filters need 5
    views along each axis, so the central 5 x 5 of ``views`` (n, n, H, W), or all of
    3 x 3."""
    m = min(views.shape[0], 5)
    c0 = (views.shape[0] - m) // 2
    return views[c0:c0 + m, c0:c0 + m]


def _decimated(views: np.ndarray, k: int) -> np.ndarray:
    """``views`` (m, m, H, W) low-passed (a Gaussian of ``k / 2`` px) and decimated by
    ``k`` in x and y (which divides every disparity by ``k``); contiguous.  ``k = 1``:
    the views themselves."""
    if k == 1:
        return np.ascontiguousarray(views)
    return np.ascontiguousarray(_lowpass(views, 0.5 * k)[..., k // 2::k, k // 2::k])


def _coarse_prior(views: np.ndarray, filters: str) -> list:
    """The confirmed coarse disparities at full resolution, for the smooth regions.

    The coarse pass of :func:`estimate_shear_range` at every level ``k`` in (32, 16, 8,
    4, 2) that leaves at least 16 px (:func:`_confirmed`: the grid's, the centre row's and
    the centre column's estimates agree), each value times ``k`` (px per view) and
    repeated over the ``k x k`` full-resolution pixels of its coarse pixel.

    Returns
    -------
    list of (ndarray, float)
        Coarsest level first: its disparity, shape (H, W), NaN where it confirms none,
        and how far (px) its data reach, ``_COARSE_SUPPORT * k``.
    """
    H, W = views.shape[-2:]
    v = _central(views)
    levels = []
    for k in (32, 16, 8, 4, 2):
        if min(H, W) // k < 16:
            continue
        d, confirmed = _confirmed(_decimated(v, k), filters)
        d = np.where(confirmed, d * k, np.nan)
        # full-resolution pixel i lies in the coarse pixel centred nearest to it
        iy = np.clip(np.round((np.arange(H) - k // 2) / k).astype(int), 0, d.shape[0] - 1)
        ix = np.clip(np.round((np.arange(W) - k // 2) / k).astype(int), 0, d.shape[1] - 1)
        levels.append((d[np.ix_(iy, ix)], _COARSE_SUPPORT * k))
    return levels


def _prior_cost(C: np.ndarray, lo: np.ndarray, prior, aggregate: int,
                data: np.ndarray) -> tuple:
    """The cost of the shears ``lo`` (``C``, shape (S, H, W), aggregated log model
    errors) with the coarse disparity added where the data leave the shear open.

    Open: a pixel with an admissible estimate at some shear (``data``, bool (H, W))
    at least half of whose aggregation box (itself among them; beyond the image counts
    as not open) has its best shear's cost within :data:`_OPEN_DECADES` of its median
    over the shears (a smooth or texture-poor surface: every shear fits about as well;
    a region, not a pixel between two surfaces) or of the best cost of the shears
    :data:`_RIVAL_STEPS` or more steps from it (positions in ``lo``: a far shear the data
    do not tell apart from the best).

    A coarse estimate counts only as deep inside the open region as its data reach
    (the image's edge counting as outside: it does not mix in the textured surfaces
    around it), of those the coarsest level's, and a finer level's only where it agrees
    within half a shear with the raw (supported) estimate of the coarsest level that has
    one there;
    each such estimate is replaced by the mean of those of its level around it (a
    Gaussian of half the level's reach); a level's estimate counts only where its
    estimates hold at least half of that Gaussian's weight around it (one it confirms
    alone is a chance agreement), and every open pixel of a region with such estimates
    takes the nearest of them.  There the cost grows by
    :data:`_PRIOR_DECADES` per px per view between the shear and that estimate: a shear
    a step or more further from it than another cannot win where their costs lie within
    a decade (an open pixel's best lies within 0.3 decade of its median over the shears
    or of a far shear); between the two shears around it, the nearer wins unless the
    estimate lies near their middle.  ``prior()`` gives the coarse levels
    (:func:`_coarse_prior`); it is called only where some open region is as deep as the
    finest level's reach.

    Returns ``(C, used)``: the cost, shape (S, H, W), and the pixels where the coarse
    disparity entered it (bool, (H, W)).
    """
    from scipy.ndimage import distance_transform_edt, label, uniform_filter

    low = C.min(0)
    spread = np.median(C, 0) - low
    # the best shear's cost against its best rival's (_RIVAL_STEPS): two minima apart by
    # less than the open margin leave the shear open too
    far = np.abs(np.arange(len(lo))[:, None, None] - C.argmin(0)[None]) >= _RIVAL_STEPS
    rival = np.where(far, C, np.inf).min(0) - low
    own = data & ((spread < _OPEN_DECADES) | (rival < _OPEN_DECADES))
    box = 2 * int(aggregate) + 1
    flat = data & (uniform_filter(own.astype(float), box, mode="constant") >= 0.5)
    # distance to the nearest pixel outside the open region, the image's edge outside
    depth = distance_transform_edt(np.pad(flat, 1))[1:-1, 1:-1]
    none = np.zeros_like(flat)
    if not (depth >= _COARSE_SUPPORT * 2).any():
        # no open region as deep as the finest coarse level's reach: nothing to take
        return C, none
    # per pixel the coarsest level whose data lie inside the open region: the one that
    # pools the most data (a finer level confirms a few wrong estimates by chance there)
    p = np.full(flat.shape, np.nan)
    coarser = np.full(flat.shape, np.nan)
    for d, reach in prior():
        # a finer level's value that the coarser level's (where it has one) puts on
        # another shear (more than half a shear off) is noise
        off = np.abs(d - coarser) > 0.5
        # A value counts only where the level's estimates (those not turned away)
        # hold at least half of the weight of a Gaussian of half its reach around it:
        # a value the level confirms alone, among pixels it leaves unconfirmed, is a
        # chance agreement (a 1/4 level's 0.32 px per view on the 512^2 wall at 1.0,
        # where no coarser level had an estimate to check it against, put a disk of
        # pixels on the shear of 0: most of the wall's 980 off by more than 1 px)
        est = np.isfinite(d) & ~off
        supported = est & (_gauss(est.astype(float), reach / 2) >= 0.5)
        take = np.isnan(p) & supported & (depth >= reach)
        if take.any():
            # each kept value the mean of the kept values around it, weighted by the
            # same Gaussian: its 2 sigma stay inside the region (they lie at least the
            # reach deep), and the coarse estimates' own noise (a few tenths of a px
            # per view, enough to tip the nearest shear) averages
            mean = (_gauss(np.where(take, d, 0.0), reach / 2)
                    / np.maximum(_gauss(take.astype(float), reach / 2), 1e-12))
            p[take] = mean[take]
        # the finer levels are checked against this level's own (not averaged)
        # values, its chance agreements left out
        coarser = np.where(np.isfinite(coarser), coarser, np.where(supported, d, np.nan))
    keep = np.isfinite(p)
    if not keep.any():
        return C, none
    # each open region takes the nearest kept estimate of its own (none, where it has
    # none): one distance transform per region that has one
    regions, _ = label(flat)
    prior_map = np.full(flat.shape, np.nan)
    for r in np.unique(regions[keep]):
        inside = regions == r
        near = tuple(distance_transform_edt(~(keep & inside), return_distances=False,
                                            return_indices=True))
        prior_map[inside] = p[near][inside]
    used = np.isfinite(prior_map)
    pen = _PRIOR_DECADES * np.abs(lo[:, None, None] - np.nan_to_num(prior_map))
    return C + np.where(used, pen, 0.0), used


def _gauss(a: np.ndarray, sigma: float, mode: str = "constant") -> np.ndarray:
    """``a`` (H, W) smoothed by a Gaussian of ``sigma`` px in x and y, truncated at 4
    sigma, edges by scipy's ``mode`` (default zeros beyond the image): scipy's
    ``gaussian_filter`` with the kernel made here, since scipy builds it with numpy's
    SIMD exp, whose bits depend on the CPU."""
    from scipy.ndimage import correlate1d

    g = gaussian_taps(float(sigma), int(4.0 * sigma + 0.5))
    return correlate1d(correlate1d(a, g, axis=0, mode=mode), g, axis=1, mode=mode)


def _confirmed(vk: np.ndarray, filters: str) -> tuple[np.ndarray, np.ndarray]:
    """The coarse pass at one level, views ``vk`` of shape (m, m, h, w): the grid's
    disparity (h, w) and where it is confirmed (bool, (h, w)): within twice the filters'
    reach (beyond, the estimator has failed: an occlusion edge, aliasing), and the
    centre row's and centre column's own estimates agree with it and with each other
    within :data:`_AGREE` at the pixel and as an RMS over a Gaussian of the window's
    sigma (a lucky agreement at one pixel of a noisy region does not count)."""
    from scipy.ndimage import correlate1d

    m = vk.shape[0]
    cc = m // 2
    kw = dict(sigma=1.0, window=5, filters=filters)
    e = _bcc(vk[None], **kw)
    d = e["disparity"]
    d_row = _bcc(np.ascontiguousarray(vk[cc:cc + 1])[None], **kw)["disparity"]
    # a column as a row of the transposed images (the HCI sign carries over)
    d_col = _bcc(np.ascontiguousarray(vk[:, cc:cc + 1].transpose(1, 0, 3, 2))[None],
                 **kw)["disparity"].T
    ok = e.interior & np.isfinite(d) & np.isfinite(d_row) & np.isfinite(d_col)
    g = gaussian_taps(1.0, 3)

    def smooth(a):
        return correlate1d(correlate1d(a, g, axis=0, mode="nearest"), g, axis=1,
                           mode="nearest")
    with np.errstate(invalid="ignore"):
        sq = np.where(ok, (d_row - d_col) ** 2, 0.0)
        rms = np.sqrt(smooth(sq) / np.maximum(smooth(ok.astype(float)), 1e-12))
        confirmed = (ok & (np.abs(d) <= 2 * _REACH) & (rms <= _AGREE)
                     & (np.abs(d - d_row) <= _AGREE) & (np.abs(d - d_col) <= _AGREE))
    return d, confirmed


# the disparity (px per view) the coarse pass's camera filters follow
_REACH = 1.0
# how closely (px per view, at the level's scale) the row's, the column's and the grid's
# coarse estimates must agree for a pixel to count towards the range: a quarter of the
# filters' reach, well above the scatter of textured pixels (0.1 or less on the smooth-wall
# scenes of tests/test_lightfield.py) and well below that of texture-poor ones (~1)
_AGREE = 0.25 * _REACH

# The refocused estimates read the data rows without the zoom-blur correction
# (docs/model.md): with the light fields' 1-px windows it made BadPix(0.07) worse on the
# synthetic two-layer scene (0.92 -> 1.47 %) and the cube (13.4 -> 14.9 %) and left it
# on the thin stripes (0.15 -> 0.16 %; there MSE x 100 fell 0.338 -> 0.181), measured with
# python -m gridflow.bench.lightfield_study (the HCI development scene agreed: 7.89 ->
# 9.13 %).  Its gains are in motion and brightness, which a light field does not have.
def _bcc(volume: np.ndarray, focal_length: float | None = None, **settings):
    """The estimator on views of a light field, shape (1, n, m, H, W): model bcc, focal
    length the image width unless given, unit camera spacing, the rows without the
    zoom-blur correction."""
    f = float(volume.shape[-1]) if focal_length is None else focal_length
    return estimate(volume, f, (1.0, 1.0), model="bcc", zoom_correction=False, **settings)


def shear(views: np.ndarray, s: int) -> np.ndarray:
    """Views refocused to disparity ``s``: view (r, c) shifted by ``s (c - cc)`` px in x and
    ``s (r - cc)`` px in y, edges repeated.

    Parameters
    ----------
    views : ndarray, shape (n, n, H, W)
    s : int

    Returns
    -------
    ndarray, shape (n, n, H, W)
    """
    n = views.shape[0]
    cc = n // 2
    out = np.empty_like(views)
    H, W = views.shape[-2:]
    for r in range(n):
        for c in range(n):
            dy, dx = s * (r - cc), s * (c - cc)
            # out(y, x) = view(y - dy, x - dx)
            ys = np.clip(np.arange(H) - dy, 0, H - 1)
            xs = np.clip(np.arange(W) - dx, 0, W - 1)
            out[r, c] = views[r, c][np.ix_(ys, xs)]
    return out


def _lowpass(views: np.ndarray, sigma: float) -> np.ndarray:
    """Each view blurred in x and y by a Gaussian of ``sigma`` px (edges repeated)."""
    r = max(1, int(np.ceil(3 * sigma)))
    g = gaussian_taps(sigma, r)
    H, W = views.shape[-2:]
    out = np.zeros_like(views)
    for o, w in zip(range(-r, r + 1), g):
        out += w * views[..., :, np.clip(np.arange(W) + o, 0, W - 1)]
    res = np.zeros_like(views)
    for o, w in zip(range(-r, r + 1), g):
        res += w * out[..., np.clip(np.arange(H) + o, 0, H - 1), :]
    return res


def _subgrid_centres(n: int, m: int) -> list[tuple[int, int]]:
    """Centres of the ``m x m`` sub-grids at the centre, edges and corners of an n x n grid."""
    h = (n - m) // 2
    offs = sorted({-h, 0, h})
    cc = n // 2
    return [(cc + a, cc + b) for a in offs for b in offs]


def _shift_in(a: np.ndarray, oy: int, ox: int, fill) -> np.ndarray:
    """``out[y, x] = a[y + oy, x + ox]`` over the last two axes, ``fill`` outside."""
    out = np.full_like(a, fill)
    H, W = a.shape[-2:]
    ys, yd = slice(max(oy, 0), H + min(oy, 0)), slice(max(-oy, 0), H + min(-oy, 0))
    xs, xd = slice(max(ox, 0), W + min(ox, 0)), slice(max(-ox, 0), W + min(-ox, 0))
    out[..., yd, xd] = a[..., ys, xs]
    return out


def _box(a: np.ndarray, r: int) -> np.ndarray:
    """Mean over a (2r+1)^2 box, edges repeated (cumulative sums; no scipy needed)."""
    p = np.pad(a, r, mode="edge")
    c = np.cumsum(np.cumsum(p, 0), 1)
    c = np.pad(c, ((1, 0), (1, 0)))
    k = 2 * r + 1
    return (c[k:, k:] - c[:-k, k:] - c[k:, :-k] + c[:-k, :-k]) / (k * k)


def _guided(p: np.ndarray, guide: np.ndarray, r: int, eps: float) -> np.ndarray:
    """The guided filter of He, Sun and Tang (ECCV 2010): ``p`` smoothed over (2r+1)^2
    boxes, its edges following those of ``guide`` (both shape (H, W))."""
    mI, mp = _box(guide, r), _box(p, r)
    a = (_box(guide * p, r) - mI * mp) / (_box(guide * guide, r) - mI * mI + eps)
    b = mp - a * mI
    return _box(a, r) * guide + _box(b, r)


def _admissible(disp, err, interior, s: int, m):
    """The estimate at shear ``s`` where admissible (finite, within half a pixel of the
    shear, its window clear of the repeated edge the shear moved in: ``m`` px, or ``(my,
    mx)`` px in y and in x); maps of shape (H, W): the estimator's ``disparity``,
    ``model_error`` and ``interior``."""
    H, W = interior.shape
    my, mx = (m, m) if np.isscalar(m) else m
    clear = np.zeros((H, W), dtype=bool)
    clear[my:H - my, mx:W - mx] = True
    clear &= (np.roll(np.roll(interior, my, 0), mx, 1)
              & np.roll(np.roll(interior, -my, 0), -mx, 1))
    d = s + disp
    ok = clear & np.isfinite(d) & np.isfinite(err) & (np.abs(d - s) <= 0.5)
    return np.where(ok, d, np.nan), np.where(ok, err, np.inf)


# The smallest row/column disagreement the confidence of "lines" resolves (px per view):
# far below the estimator's precision (its fast path agrees with the reference to 1e-6 of
# a quantity's scale)
AGREE_FLOOR = 1e-6

# the choices' own tuning, keywords of estimate_refocused (its docstring), with defaults
REFOCUS_TUNING = {"subgrid": None, "aggregate": 3, "smooth": True, "coarse_sigma": 2.0}


def estimate_refocused(views: np.ndarray, shifts=(-3, -2, -1, 0, 1, 2, 3), *,
                       sigma: float | None = None, window: int | None = None,
                       filters: str = DEFAULTS["filters"], select: str = "lines",
                       fill: bool = True, median: int = 3, progress=None,
                       **tuning) -> Estimate:
    """Disparity of the centre view over a range of integer shears.

    Parameters
    ----------
    views : ndarray, shape (n, n, H, W)
        A static light field, n odd (e.g. the 9 x 9 views of an HCI scene); camera steps
        are the unit of disparity (HCI sign: a centre pixel with disparity d appears in
        view (r, c) at (x - d (c - cc), y - d (r - cc))).
    shifts : sequence of int
        The shears tried; they should cover the scene's disparity range.
    sigma, window, filters
        Estimator settings (:class:`estimator.EstimatorSettings`); defaults
        ``SELECT_DEFAULTS[select]``: 1 px and 5 taps for ``"lines"`` and
        ``"occlusion"``, 2 px and 9 taps for ``"coarse"``; for ``"epi"`` the window
        along the line, 3.5 px and 21 taps (its data rows are not filtered across it).
    select : {"lines", "occlusion", "coarse", "epi"}
        How each pixel's estimate is chosen among the shears (module docstring):
        ``"lines"`` (1-D camera sub-grids along the centre row and column, shifted
        windows and a guided cost aggregation; for scenes with occlusions and thin
        structures), ``"occlusion"`` (the same with square sub-grids) or ``"coarse"``
        (the shear nearest to a coarse disparity; meant for fine periodic texture,
        where a wrong shear can alias: ``bench/README.md`` measures it worse than
        ``"lines"`` on a periodic grid with little else) or ``"epi"`` (as ``"lines"``,
        each segment fitted on its epipolar-plane images: structures a few px thin;
        ``bench/README.md`` measures it beside ``"lines"``).
    subgrid : int, optional
        ``"lines"`` and ``"occlusion"``: odd number of views across a camera sub-grid
        (square ones at the centre, edges and corners of the grid: nine of them on a
        9 x 9 grid, one on a 5 x 5; lines of that many views at the centre and both
        ends of the centre row and column); default 5, or the grid's size if smaller.
        ``"epi"`` takes as many views as its camera filters have taps and refuses it.
        (The whole row and column, ``subgrid = n``, is faster and measured better on
        two of three scenes, worse between thin stripes: ``bench/README.md``, *Light
        fields*.)
    aggregate : int
        ``"lines"``, ``"epi"`` and ``"occlusion"``: radius (px) of the guided filter that
        aggregates the costs.
    smooth : bool
        ``"lines"``, ``"epi"`` and ``"occlusion"``: where the data leave a region's
        shear open (smooth or texture-poor: the best shear's aggregated cost within a
        factor of two of its median over the shears, or of the best of the shears two or
        more steps from it), choose by the confirmed coarse disparity of the decimated
        light field (the range's coarse pass at 1/32 ... 1/2 resolution: the
        coarsest level whose data lie inside the region, a finer one only where it
        agrees within half a shear with a coarser one's estimate; each averaged over
        half its reach, each counting only where the level confirms at least half
        of the pixels around it), the rest of the region taking the nearest such value
        (default True; ``bench/README.md``, *Light fields*, measures it;
        :func:`_prior_cost`).
    coarse_sigma : float
        ``"coarse"``: low-pass of the coarse pass, px; its window is twice ``sigma``.
    fill : bool
        Give every pixel without an admissible estimate one from its neighbours (the
        normalised convolution of theirs, a Gaussian of ``2 sigma``; beyond its reach and
        at the image border the nearest such value): a dense map, ``filled`` marks them
        and their ``confidence`` is the lowest of the image's.
    median : int
        Size of a median filter over the disparity after the choice (and the fill), 0 or
        1 for none: a pixel whose estimate disagrees with most of its neighbours (a
        wrong shear, a fattened edge pixel) takes theirs; ``model_error`` and
        ``confidence`` stay those of the pixel's own estimate.
    progress : callable, optional
        Called as ``progress(done, total)`` after each shear.
    **tuning
        The choices' own tuning, ``subgrid``, ``aggregate``, ``smooth``,
        ``coarse_sigma`` (above; defaults :data:`REFOCUS_TUNING`); any other keyword is
        refused.

    Returns
    -------
    Estimate
        Model ``bcc``; maps, each shape (H, W): ``disparity``; ``shear``: the shear used;
        ``model_error``: the model error of the estimate kept; ``confidence`` (larger is
        better; threshold it to mask): with ``"lines"`` and ``"epi"`` ``-log10`` of the
        product of the disagreement (px per view) between the best estimates of the row's and of
        the column's sub-grids at the chosen shear and the model error relative to its
        median of its positive values (floors: 1e-6 px, ``AGREE_FLOOR``, and nine
        decades below that median; where one of the two has no estimate, the
        disagreement is the median of the others', 1 px where no pixel has both),
        else ``-log10`` of the model error relative to its median (``bench/README.md``,
        *Light fields*, ranks both against the errors);
        ``filled``: 1 where the value was filled from the neighbours (see ``fill``),
        else 0; with ``select="coarse"`` also ``coarse``: the coarse disparity.
        ``interior``: the pixels with a value, an admissible estimate of their own
        (finite, within half a pixel of its shear: ``interior & (filled == 0)``) or a
        filled one.  ``settings``: the shears and the settings used.
    """
    unknown = sorted(set(tuning) - set(REFOCUS_TUNING))
    if unknown:
        raise InputError(f"estimate_refocused: unknown keyword(s) {unknown}; the tuning "
                         f"keywords are {sorted(REFOCUS_TUNING)}")
    t = {**REFOCUS_TUNING, **tuning}
    v, shifts = _checked_views(views, shifts, select)
    n = v.shape[0]
    sigma = SELECT_DEFAULTS[select][0] if sigma is None else sigma
    window = SELECT_DEFAULTS[select][1] if window is None else window
    if select == "epi":
        # the EPI fits do not go through the estimator: its checks of the settings here
        EstimatorSettings(sigma=sigma, window=window, filters=filters)
        if t["subgrid"] is not None:
            raise InputError("subgrid: select='epi' takes segments of as many views as "
                             "its camera filters have taps (matched5 and fs5: 5, matched3 "
                             "or a 3 x 3 grid: 3)")
        t["subgrid"] = _epi_pair(filters, n).taps
    subgrid = min(5, n) if t["subgrid"] is None else t["subgrid"]
    if select != "coarse" and (subgrid % 2 == 0 or not 3 <= subgrid <= n):
        raise InputError(f"subgrid must be odd, at least 3 and at most the grid's {n}, "
                         f"got {subgrid}")
    lo = np.array(sorted(shifts))
    if select == "coarse":
        out = _select_coarse(v, lo, sigma, window, filters, t["coarse_sigma"], progress)
    else:
        # called only where a region leaves the shear open: the coarse pass measured 8 s
        # beside the refocusing's 20 s on a 9 x 9 scene of 512^2
        prior = (lambda: _coarse_prior(v, filters)) if t["smooth"] else None
        out = _select_occlusion(v, lo, sigma, window, filters, subgrid, t["aggregate"],
                                lines=select in ("lines", "epi"), progress=progress,
                                prior=prior, epi=select == "epi")
    maps, valid, filled = _finish(out, sigma, fill, median)
    settings = {"shears": list(shifts), "select": select, "sigma": sigma, "window": window,
                "filters": filters, "fill": fill, "median": median,
                "views": [n, n]}
    return Estimate(maps, "bcc", valid | filled, settings)


def _checked_views(views, shifts, select) -> tuple[np.ndarray, list[int]]:
    """The views as float64 ``(n, n, H, W)`` and the shears as distinct integers, or an
    :class:`InputError` naming what is wrong."""
    v = np.asarray(views, dtype=np.float64)
    if v.ndim != 4 or v.shape[0] != v.shape[1] or v.shape[0] % 2 == 0:
        raise InputError(f"views must have shape (n, n, H, W) with n odd, got {v.shape}")
    if not isinstance(shifts, range):
        shifts = list(shifts)
    if len(shifts):                     # before a range is spelt out
        check_shears(shifts, v.shape[0], *v.shape[-2:], what="shifts")
    shifts = [int(s) for s in shifts]
    if not shifts or len(set(shifts)) != len(shifts):
        raise InputError(f"shifts must be distinct integers, got {shifts}")
    if select not in SELECT_DEFAULTS:
        raise InputError(f"select must be one of {sorted(SELECT_DEFAULTS)}, got {select!r}")
    return v, shifts


def _finish(out: dict, sigma: float, fill: bool, median: int):
    """The chosen estimates' confidence, the fill and the median: ``(maps, valid,
    filled)``."""
    disp, err = out["disparity"], out["model_error"]
    H, W = disp.shape
    valid = np.isfinite(disp)
    with np.errstate(divide="ignore", invalid="ignore"):
        if "disagreement" in out:
            # two signs of a wrong estimate, multiplied: the row's and the column's
            # estimates apart (in a texture-poor region, where the model error can be
            # small, they disagree) and the model error relative to its median (at an
            # occluding edge, where they can agree on a mixture).  The model error is an
            # eigenvalue, 0 or slightly negative by round-off on noise-free data: its
            # median and floor (nine decades below) come from its positive values, as
            # in the cost of the choice; the disagreement is floored at AGREE_FLOOR.
            # So the confidence is at most 15.  Where one direction has no estimate
            # (near the image's edges, where its views moved the repeated edge in, or
            # an occlusion) the disagreement is unknown: it counts as the image's
            # median of the others, neither for nor against, and the model error ranks
            # (as the lowest confidence there is, the border strip's accurate estimates
            # of a textured surface ranked below a smooth wall's guesses: Spearman's
            # rho 0.40 -> 0.14 on the 128^2 wall of the test)
            pos = err[valid & (err > 0)]
            med = float(np.median(pos)) if pos.size else 1.0
            rel = np.maximum(err, 1e-9 * med) / med
            dis = np.maximum(out["disagreement"], AGREE_FLOOR)
            known = valid & np.isfinite(dis)
            dis = np.where(np.isfinite(dis), dis,
                           float(np.median(dis[known])) if known.any() else 1.0)
            conf = np.where(valid, -log10(dis * rel), np.nan)
        else:
            med = np.nanmedian(err[valid]) if valid.any() else np.nan
            conf = np.where(valid, -log10(err / med), np.nan)
    filled = np.zeros((H, W), dtype=bool)
    if fill and valid.any() and not valid.all():
        disp, filled = _fill(disp, valid, out["inside"], sigma)
        # a filled pixel has no estimate of its own: the lowest confidence there is
        conf = np.where(filled, np.nanmin(conf), conf)
    if median > 1 and np.isfinite(disp).any():
        disp = _median(disp, int(median))
    # the shear of a pixel without an estimate would read as a disparity: NaN there
    shear_map = np.where(np.isfinite(disp), out["shear"], np.nan)
    maps = {"disparity": disp, "shear": shear_map, "model_error": err, "confidence": conf,
            "filled": filled.astype(float)}
    if "coarse" in out:
        maps["coarse"] = out["coarse"]
    return maps, valid, filled


def _median(disp, size):
    """A ``size`` x ``size`` median of the disparity (scipy's, edges repeated); pixels
    without a value keep none and lend their nearest neighbour's to the filter."""
    from scipy.ndimage import distance_transform_edt, median_filter

    none = ~np.isfinite(disp)
    d = disp
    if none.any():
        d = disp[tuple(distance_transform_edt(none, return_distances=False,
                                              return_indices=True))]
    return np.where(none, np.nan, median_filter(d, size, mode="nearest"))


def _fill(disp, valid, inside, sigma):
    """Every pixel without an admissible estimate given one from its neighbours.

    Inside the region the estimator covers, the normalised convolution of the valid
    estimates (a Gaussian of ``2 sigma``, clipped to the image's size: beyond it the
    average is the whole image's); where that has too little weight (a hole wider than
    the Gaussian) and outside (the image border), the nearest filled value.

    Returns ``(disparity, filled)``, both shape (H, W).
    """
    from scipy.ndimage import distance_transform_edt

    H, W = disp.shape
    s = min(2 * float(sigma), float(max(H, W)))
    num = _gauss(np.where(valid, disp, 0.0), s, mode="nearest")
    den = _gauss(valid.astype(float), s, mode="nearest")
    conv = ~valid & inside & (den > 1e-3)
    out = np.where(conv, num / np.where(den > 0, den, 1.0), disp)
    rest = ~(valid | conv)
    if rest.any():
        near = distance_transform_edt(rest, return_distances=False, return_indices=True)
        out = out[tuple(near)]
    return out, ~valid


def _subgrid_estimates(sv, subgrid, sigma, window, filters, lines):
    """The estimator on each camera sub-grid of the sheared views ``sv`` (n, n, H, W).

    ``lines=False``: the ``subgrid`` x ``subgrid`` sub-grids at the centre, edges and
    corners of the grid.  ``lines=True``: 1-D sub-grids of ``subgrid`` views along the
    centre row and the centre column (at the centre and both ends of each); a column is
    estimated as a row of the transposed images (the HCI sign carries over: a point
    appears in view ``r`` of the column at ``y - d (r - cc)``).

    Yields ``(disparity, model_error, interior, (ry, rx))``: maps of shape (H, W) at the
    shear, and how many camera steps the sub-grid's views lie from the centre at most in
    y and in x (times the shear: the px of repeated edge its views have moved in; a row
    of views is not shifted in y, a column not in x).
    """
    n = sv.shape[0]
    W = sv.shape[-1]
    kw = dict(focal_length=float(W), sigma=sigma, window=window, filters=filters)
    cg = n // 2
    h = subgrid // 2
    if not lines:
        for rc, cc in _subgrid_centres(n, subgrid):
            sub = np.ascontiguousarray(sv[rc - h:rc + h + 1, cc - h:cc + h + 1])[None]
            e = _bcc(sub, **kw)
            yield (e["disparity"], e["model_error"], e.interior,
                   (abs(rc - cg) + h, abs(cc - cg) + h))
        return
    for c in sorted({h, cg, n - 1 - h}):
        reach = abs(c - cg) + h
        row = np.ascontiguousarray(sv[cg:cg + 1, c - h:c + h + 1])[None]
        e = _bcc(row, **kw)
        yield e["disparity"], e["model_error"], e.interior, (0, reach)
        col = np.ascontiguousarray(sv[c - h:c + h + 1, cg].transpose(0, 2, 1))[None, None]
        e = _bcc(col, **kw)
        yield e["disparity"].T, e["model_error"].T, e.interior.T, (reach, 0)


def _epi_pair(filters: str, n: int):
    """The camera filter pair of an EPI segment: ``filters`` where the grid has as many
    views as its taps, else ``"matched3"`` (as the estimator does on a short axis)."""
    from .filters import get_filter_pair

    pair = get_filter_pair(filters)
    return pair if pair.taps <= n else get_filter_pair("matched3")


def _epi_line(seg: np.ndarray, pair, sigma: float, window: int):
    """Disparity of a segment of views along x from its epipolar-plane images.

    A point of disparity ``d`` appears in view ``c`` of the segment at ``x - d (c -
    cc)``, so ``I_s = d I_x`` (``s`` the camera index; brightness constancy, as the
    ``bcc`` model).  ``I_x`` is the x-derivative of the camera-prefiltered views,
    ``I_s`` the camera derivative prefiltered in x (the same pair on both axes: the
    derivatives of one prefiltered signal, ``estimator.filters``), neither filtered in
    y; the structure tensor ``[[Jxx, Jxs], [Jxs, Jss]]`` is their products summed over a
    Gaussian window along x alone (an EPI, one image row), and ``d`` its total least
    squares solution (the eigenvector of the smaller eigenvalue ``lam``, which is the
    model error).

    Parameters
    ----------
    seg : ndarray, shape (m, H, W)
        ``m = pair.taps`` views along x (camera index increasing with x's shift sign as
        in the HCI convention).
    pair : FilterPair
    sigma, window : float, int
        The window along x: a Gaussian of ``sigma`` px, ``window`` taps.

    Returns
    -------
    disparity, model_error, interior : ndarray, shape (H, W)
        ``interior``: the pixels whose filters and window lie inside the image (in x).
    """
    from scipy.ndimage import correlate1d

    p, dk = pair.prefilter, pair.derivative
    # the weighted sums over the views in a fixed order (a BLAS call, np.tensordot, sums
    # in an order that depends on the CPU's kernels: tests/test_reproducible.py)
    cp = p[0] * seg[0]
    cd = dk[0] * seg[0]
    for j in range(1, seg.shape[0]):
        cp = cp + p[j] * seg[j]
        cd = cd + dk[j] * seg[j]
    ix = correlate1d(cp, dk, axis=1, mode="nearest")
    i_s = correlate1d(cd, p, axis=1, mode="nearest")
    rw = int(window) // 2
    g = gaussian_taps(float(sigma), rw)

    def win(a):
        return correlate1d(a, g, axis=1, mode="nearest")
    jxx, jxs, jss = win(ix * ix), win(ix * i_s), win(i_s * i_s)
    half = 0.5 * (jxx + jss)
    root = np.sqrt(0.25 * (jxx - jss) ** 2 + jxs * jxs)
    lam = half - root
    with np.errstate(divide="ignore", invalid="ignore"):
        # the eigenvector of lam is (jxs, lam - jxx) ~ (d, -1); jxx - lam = root +
        # (jxx - jss) / 2 >= 0, zero where jxs = 0 and jxx <= jss (no x-texture that
        # moves with the views): NaN there, which _admissible refuses
        d = jxs / (jxx - lam)
    H, W = seg.shape[-2:]
    m = pair.radius + rw
    interior = np.zeros((H, W), dtype=bool)
    interior[:, m:W - m] = True
    return d, np.maximum(lam, 0.0), interior & np.isfinite(d)


def _epi_estimates(sv, subgrid, sigma, window, filters, lines):
    """As :func:`_subgrid_estimates` with ``lines=True``, each segment of ``subgrid``
    views estimated on its EPIs (:func:`_epi_line`); a column as a row of the
    transposed images."""
    n = sv.shape[0]
    cg = n // 2
    h = subgrid // 2
    pair = _epi_pair(filters, n)
    for c in sorted({h, cg, n - 1 - h}):
        reach = abs(c - cg) + h
        d, err, inner = _epi_line(sv[cg, c - h:c + h + 1], pair, sigma, window)
        yield d, err, inner, (0, reach)
        d, err, inner = _epi_line(sv[c - h:c + h + 1, cg].transpose(0, 2, 1), pair,
                                  sigma, window)
        yield d.T, err.T, inner.T, (reach, 0)


def _select_occlusion(v, lo, sigma, window, filters, subgrid, aggregate, lines,
                      progress=None, prior=None, epi=False) -> dict:
    """Per shear, the best of the sub-grids and shifted windows; across shears, the
    smallest aggregated cost.  ``epi``: the line sub-grids estimated on their EPIs
    (:func:`_epi_estimates`; ``lines`` must be True)."""
    estimates = _epi_estimates if epi else _subgrid_estimates
    n = v.shape[0]
    H, W = v.shape[-2:]
    R = window // 2
    rows, cols = np.indices((H, W))
    D = np.full((lo.size, H, W), np.nan)
    E = np.full((lo.size, H, W), np.inf)
    # with line sub-grids, the best estimate of the row's sub-grids and of the column's
    # apart (group 0: rows, 1: columns), and which sub-grid gave it; square sub-grids
    # are one group.  The best of all is the better group's (the first sub-grid on a tie,
    # as when they are taken in turn), so D and E are those of one running minimum
    groups = 2 if lines else 1
    if lines:
        DG = np.full((groups, lo.size, H, W), np.nan)
    for k, s in enumerate(lo):
        sv = shear(v, int(s))
        Eg = np.full((groups, H, W), np.inf)
        Dg = np.full((groups, H, W), np.nan)
        Jg = np.full((groups, H, W), -1, dtype=np.int64)
        # a sub-grid off the centre sees the centre's point within |d - s| * (its offset)
        # <= 1 px of the same pixel after the shear: the views on one side of an
        # occluding edge, where the full grid mixes two surfaces.  A 1-D sub-grid along
        # an edge's direction sees no occlusion at all (thin structures)
        for j, (disp, err_s, interior, (ry, rx)) in enumerate(
                estimates(sv, subgrid, sigma, window, filters, lines)):
            # refused only where the sub-grid's own views moved the repeated edge in: a
            # row of views near the left and right edges, a column near the top and
            # bottom (the whole grid's margin would refuse a border strip every
            # sub-grid could have estimated)
            d, err = _admissible(disp, err_s, interior, int(s),
                                 (abs(int(s)) * ry, abs(int(s)) * rx))
            g = j % groups                 # lines: rows and columns come in turn
            # shifted windows: a pixel may take the estimate of a window that still
            # covers it (offset up to the window's radius), the one that fits best;
            # near an edge that is a window on the pixel's own side of it
            if not epi:
                offsets = [(oy, ox) for oy in range(-R, R + 1) for ox in range(-R, R + 1)]
            elif ry == 0:       # an EPI row's window lies along x: shifted along it alone
                offsets = [(0, o) for o in range(-R, R + 1)]
            else:               # a column's along y
                offsets = [(o, 0) for o in range(-R, R + 1)]
            for oy, ox in offsets:
                es = _shift_in(err, oy, ox, np.inf)
                better = es < Eg[g]
                Eg[g] = np.where(better, es, Eg[g])
                Dg[g] = np.where(better, _shift_in(d, oy, ox, np.nan), Dg[g])
                Jg[g] = np.where(better, j, Jg[g])
        if lines:
            first = (Eg[0] < Eg[1]) | ((Eg[0] == Eg[1]) & (Jg[0] < Jg[1]))
            E[k] = np.where(first, Eg[0], Eg[1])
            D[k] = np.where(first, Dg[0], Dg[1])
            DG[:, k] = Dg
        else:
            E[k], D[k] = Eg[0], Dg[0]
        if progress is not None:
            progress(k + 1, lo.size)
    # cost per shear: log model error (inadmissible: worse than any admissible one),
    # aggregated by a guided filter on the centre view so that a pixel pools the costs
    # of neighbours of its own brightness (its own surface), not those across an edge
    fin = np.isfinite(E)
    # the model error is an eigenvalue: >= 0, but round-off can make it 0 or slightly
    # negative on noise-free data; floor it nine decades below the median
    pos = E[fin & (E > 0)]
    floor = 1e-9 * float(np.median(pos)) if pos.size else 1e-300
    L = log10(np.maximum(np.where(fin, E, 1.0), floor))
    worst = L[fin].max() + 1.0 if fin.any() else 0.0
    C = np.where(fin, L, worst)
    guide = v[n // 2, n // 2]
    span = float(np.ptp(guide))
    guide = (guide - guide.min()) / (span if span > 0 else 1.0)
    if aggregate > 0:
        C = np.stack([_guided(c, guide, int(aggregate), 1e-3) for c in C])
    if prior is not None:
        C, _ = _prior_cost(C, lo, prior, aggregate, fin.any(0))
    idx = C.argmin(0)
    disp = D[idx, rows, cols]
    err = np.where(np.isfinite(disp), E[idx, rows, cols], np.nan)
    out = {"disparity": disp, "model_error": err, "shear": lo[idx].astype(float),
           "inside": fin.any(0)}
    if lines:
        # how far the row's and the column's best estimates at the chosen shear lie
        # apart (px per view; NaN where either has none): where the data fix the
        # disparity the two agree, in a smooth or texture-poor region they do not
        # (noise, the aperture problem), whatever their model errors say
        out["disagreement"] = np.abs(DG[0, idx, rows, cols] - DG[1, idx, rows, cols])
    return out


def _select_coarse(v, lo, sigma, window, filters, coarse_sigma, progress=None) -> dict:
    """The shear nearest to a coarse disparity from the low-passed light field."""
    n = v.shape[0]
    H, W = v.shape[-2:]
    win2 = 2 * (window // 2) * 2 + 1
    coarse = _bcc(_lowpass(v, coarse_sigma)[None], sigma=2 * sigma, window=win2,
                  filters=filters)["disparity"]
    # the coarse window reaches further: near the border take the nearest coarse value
    bad = ~np.isfinite(coarse)
    if bad.any() and not bad.all():
        from scipy.ndimage import distance_transform_edt

        near = distance_transform_edt(bad, return_distances=False, return_indices=True)
        coarse = coarse[tuple(near)]
    # the shear nearest to the coarse disparity (the nearest end of the range beyond it)
    pick = np.where(np.isfinite(coarse),
                    lo[np.abs(np.nan_to_num(coarse)[..., None] - lo).argmin(-1)], np.nan)
    D = np.full((lo.size, H, W), np.nan)
    E = np.full((lo.size, H, W), np.inf)
    for k, s in enumerate(lo):
        e = _bcc(shear(v, int(s))[None], sigma=sigma, window=window, filters=filters)
        D[k], E[k] = _admissible(e["disparity"], e["model_error"], e.interior, int(s),
                                 abs(int(s)) * (n // 2))
        if progress is not None:
            progress(k + 1, lo.size)
    # the shear nearest to the coarse disparity where it is admissible; elsewhere the
    # admissible neighbouring shear (one step either side) with the smaller model error;
    # shears further away are not considered: with fine texture an aliased shear can fit
    # as well as the right one
    idx_near = np.where(np.isfinite(pick), np.abs(np.nan_to_num(pick)[None] - lo[:, None, None])
                        .argmin(0), 0)
    rows, cols = np.indices((H, W))
    near_ok = np.isfinite(D[idx_near, rows, cols])
    far = np.abs(np.arange(lo.size)[:, None, None] - idx_near[None]) > 1
    idx_best = np.where(far, np.inf, E).argmin(0)
    idx = np.where(near_ok, idx_near, idx_best)
    disp = D[idx, rows, cols]
    err = np.where(np.isfinite(disp), E[idx, rows, cols], np.nan)
    return {"disparity": disp, "model_error": err, "shear": lo[idx].astype(float),
            "coarse": coarse, "inside": np.isfinite(D).any(0) | np.isfinite(coarse)}
