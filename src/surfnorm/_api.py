"""The front door: :func:`estimate`, :func:`refine`, and batches of frames."""

from __future__ import annotations

import numbers
from typing import cast

import numpy as np

from ._bands import CORES, map_threads, on_threads, whole
from ._choices import DLF_NAMES
from ._results import new_result
from ._validate import (
    as_depth,
    as_mask,
    as_normals,
    as_output,
    check_bool,
    check_choice,
    check_fill,
    split_masked,
    valid_map,
    valid_pixels,
)
from .camera import Intrinsics
from .errors import InputError
from .methods import DEFAULT_METHOD, resolve

__all__ = ["estimate", "refine", "auto_decision"]


def _intrinsics_list(K, n: int | None) -> list[Intrinsics] | Intrinsics:
    if n is None:
        return Intrinsics.from_matrix(K)
    if isinstance(K, Intrinsics):
        return [K] * n
    if isinstance(K, (list, tuple)) and any(isinstance(k, Intrinsics) for k in K):
        # one per frame, each an Intrinsics or a 3x3 matrix, checked here (not in a worker thread)
        if len(K) != n:
            raise InputError(f"K: expected one intrinsics for all {n} frames or one per frame, got {len(K)}")
        return [Intrinsics.from_matrix(k, name=f"K[{i}]") for i, k in enumerate(K)]
    try:
        arr = np.asarray(K)
    except (TypeError, ValueError) as exc:  # a ragged list
        raise InputError(
            f"K: expected a 3x3 matrix, ({n}, 3, 3) matrices or one Intrinsics per frame, got a ragged {type(K).__name__}"
        ) from exc
    if arr.ndim == 3:
        if arr.shape[0] != n:
            raise InputError(f"K: expected shape (3, 3) or ({n}, 3, 3) for {n} frames, got shape {arr.shape}")
        return [Intrinsics.from_matrix(k, name=f"K[{i}]") for i, k in enumerate(arr)]
    return [Intrinsics.from_matrix(arr)] * n


def _run(method, refined, options, z, valid, cam, out=None, tie_tol=0.0, relative=0.0, bands=whole):
    if out is None:
        out = new_result(z.shape + (3,))
    if tie_tol and method.ties:
        options = dict(options, tie_tol=tie_tol)
    if relative and method.relative:
        options = dict(options, relative=relative)
    if method.bands and bands is not whole:
        options = dict(options, bands=bands)
    if not refined:
        # A recipe ending with MNR (d2nt_v3) refines inside its own run, fused: no full-size temporary.
        return method.run(z, valid, cam, out, **options)
    from .kernels.mnr import mnr

    mnr_dlf = options["mnr_dlf"]
    run_options = options if method.mnr else {k: v for k, v in options.items() if k != "mnr_dlf"}
    raw = method.run(z, valid, cam, new_result(out.shape), **run_options)
    return mnr(z, valid, raw, out, dlf=mnr_dlf, fill=options["fill"], tie_tol=tie_tol, bands=bands)


#: The methods whose normals ``estimate(..., uncertainty=True)`` gives a sigma (see surfnorm.kernels.uncertainty).
UNCERTAIN = ("auto", "adaptive_fit", "d2nt_v3")


def _run_uncertain(method, options, z, valid, cam, out, sigma_out, tie_tol=0.0, relative=0.0, bands=whole):
    """:func:`_run` of a method of ``UNCERTAIN``, and each normal's sigma into ``sigma_out``."""
    from .kernels.uncertainty import sigma_map

    record: dict = {}
    if method.name != "d2nt_v3":
        options = dict(options, record=record)
    normals = _run(method, False, options, z, valid, cam, out, tie_tol, relative, bands)
    sigma_map(method.name, record, z, valid, cam, normals, options.get("fill", 0.0), sigma_out, bands)
    return normals


def _in_range(method, options: dict, src: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, dict]:
    """The paper-faithful mode's range rescale of one frame (surfnorm.units, "Range").

    Depth and tau are multiplied by a power of two where the frame's depth would leave float32's range in the
    kernels (judged on ``src``, the caller's values, where they reach beyond float32); else unchanged. Methods
    whose normals depend on the unit (``equivariant`` False) only where float32 would lose the depth.
    """
    from .units import SAFE_EXPONENT, UNIT_EXPONENT, range_exponent, scaled_frame

    k = range_exponent(z, src, SAFE_EXPONENT if method.equivariant else UNIT_EXPONENT)
    if k == 0:
        return z, options
    if "tau" in options:
        options = dict(options, tau=options["tau"] * 2.0**k)
    return scaled_frame(src, k), options


#: Pixels below which the validity map is made on the calling thread: it takes about 20 us per 640x480 frame, less
#: than handing a band to another thread (0.075 ms on two threads against 0.019 ms on one, measured).
_VALID_ON_THREADS = 1 << 21


def _valid(z, mask, bands=whole):
    # One Numba pass (compiled on first use, so that ``import surfnorm`` compiles nothing).
    if bands is whole or z.size < _VALID_ON_THREADS:
        return valid_map(z, mask)
    out = np.empty(z.shape, dtype=np.bool_)
    bands(lambda a, b: valid_map(z[a:b], None if mask is None else mask[a:b], out=out[a:b]), z.shape[0])
    return out


def _workers(threads) -> int:
    workers = threads if threads is not None else CORES
    if not isinstance(workers, numbers.Integral) or isinstance(workers, (bool, np.bool_)) or workers < 1:
        raise InputError(f"threads: expected a positive integer, got {threads!r}")
    return int(workers)  # (np.int64(2) as window= takes it)


def _inputs(depth, mask, out, scale_invariant, disparity):
    """:func:`estimate`'s arrays, validated.

    Returns (z: float32 depth, rescaled to relative depth in the scale-invariant and disparity modes; src: the
    caller's values; the mask; out; tie_tol and relative of those modes, else 0).
    """
    depth, unmasked = split_masked(depth)
    z = as_depth(depth)
    user_mask = as_mask(mask, z.shape)
    if unmasked is not None:  # np.ma: masked pixels are invalid
        user_mask = unmasked if user_mask is None else user_mask & unmasked
    if out is not None:
        out = as_output(out, z.shape + (3,), [("depth", z), ("mask", user_mask)])
    src = np.asarray(depth)  # the caller's values before float32 (float64 keeps its digits when rescaled)
    tie_tol = relative = 0.0
    if check_bool("scale_invariant", scale_invariant) | check_bool("disparity", disparity):
        from .units import REFERENCE_DEPTH, TIE_TOLERANCE, relative_depth

        # Validity from the caller's values (float64 depth of 1e-60 is 0 in float32). Invalid pixels become 0 in
        # the rescaled depth, and a value that over/underflows float32 when rescaled is not finite and positive,
        # so the validity computed below from z covers both.
        z = relative_depth(src, valid_pixels(src, user_mask), disparity=disparity)
        tie_tol, relative = TIE_TOLERANCE, REFERENCE_DEPTH
    return z, src, user_mask, out, tie_tol, relative


def estimate(
    depth,
    K,
    *,
    method: str = DEFAULT_METHOD,
    mask=None,
    threads: int | None = None,
    scale_invariant: bool = False,
    disparity: bool = False,
    out: np.ndarray | None = None,
    uncertainty: bool = False,
    **options,
):
    """Estimate surface normals from a depth image (or a stack of them).

    Parameters
    ----------
    depth : ndarray of shape (H, W) or (N, H, W)
        Depth along the optical axis (any unit; float or integer). Pixels with
        depth 0, negative, NaN or inf are invalid and never used.
    K : array_like of shape (3, 3) or (N, 3, 3), or Intrinsics
        Intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], 0-based pixel centres.
    method : str
        A name from :func:`surfnorm.methods`, optionally followed by ``+mnr``.
        The default, ``"auto"``, runs ``d2nt_v3`` on clean depth (rendered) and
        ``adaptive_fit`` on sensor depth (quantised, noisy, sparse), chosen
        from the depth's own noise floor; see :mod:`surfnorm.kernels.auto`.
    mask : ndarray of bool, shape of ``depth``, optional
        False where depth must not be used (in addition to invalid values).
        A NumPy masked array's masked pixels (in ``depth`` or in ``mask``)
        are not used either, whatever values lie under the mask.
    threads : int, optional
        Threads (default: all cores). A stack of frames runs frames side by
        side; one frame is split into bands of rows, computed side by side,
        with the same result to the bit as on one thread (a frame of fewer
        than 64 rows stays on one thread). Pass 1 where frames already run
        in parallel (several processes or threads calling ``estimate``).
    scale_invariant : bool
        False (default, paper-faithful): the DAG softmin threshold ``tau`` is in
        depth units. True: ``tau`` is relative to each pixel's own depth
        (tau z / ``surfnorm.units.REFERENCE_DEPTH``, 100) and near-ties are
        judged relative to depth, so normals do not depend on the unit of
        depth, and every decision is local; see :mod:`surfnorm.units`.
    disparity : bool
        ``depth`` holds disparity (or inverse depth up to scale); it is inverted
        and handled as in the scale-invariant mode. See :mod:`surfnorm.units`.
    out : ndarray of float32, shape of the result, optional
        Write the normals into this C-contiguous array (and return it) instead
        of a new one, so that a stream of frames or batches reuses one buffer.
        Without it, a result of 256 KiB or more takes the memory of an earlier
        result of its size that nothing uses any more, where there is one (see
        :mod:`surfnorm._results`); else it is memory that the system hands over
        and zeroes when it is first written, a cost per frame that more threads
        do not lower (``make bench`` measures it on a stack of frames).
    uncertainty : bool
        True: also return each normal's predicted RMS angular error in degrees
        (``sigma``), from the estimator's own fit: its residual, its support
        and the frame's noise (see :mod:`surfnorm.kernels.uncertainty`). For
        ``auto`` (whatever it runs on the frame), ``adaptive_fit`` and
        ``d2nt_v3``; other methods raise InputError. The normals are the
        same bits with and without it.
    **options
        The method's options (see ``surfnorm.methods()[name].options``), e.g.
        ``dlf``, ``tau``, ``truncate``, ``mnr_dlf``, ``fill``.

    Returns
    -------
    ndarray of float32, shape (H, W, 3) or (N, H, W, 3)
        Unit normals in the camera frame (x right, y down, z forward), facing
        the camera (n_z < 0 on a fronto-parallel wall). Pixels without a valid
        normal hold ``fill`` (default 0.0) in all three components. The array
        is ``out`` when one was given.
    sigma : ndarray of float32, shape (H, W) or (N, H, W)
        Only with ``uncertainty=True`` (the result is then ``(normals, sigma)``):
        each normal's predicted RMS angular error in degrees, NaN exactly where
        the normal is ``fill``.

    Raises
    ------
    InputError (a ValueError)
        Bad depth, K, mask, method name or option; the message names which.

    Warns
    -----
    IntrinsicsWarning
        ``K`` does not look like the intrinsics of this frame: a principal point outside it or far from its
        centre towards one corner, or an image size in ``K`` other than the frame's (see
        :meth:`surfnorm.Intrinsics.check_frame`).

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> K = [[500.0, 0, 31.5], [0, 500.0, 23.5], [0, 0, 1]]
    >>> n = surfnorm.estimate(np.full((48, 64), 2.0), K, method="d2nt_basic")
    >>> n.shape, n[24, 32].round(6).tolist()
    ((48, 64, 3), [0.0, 0.0, -1.0])
    """
    method_obj, refined, clean = resolve(method, options)
    if check_bool("uncertainty", uncertainty) and (refined or method_obj.name not in UNCERTAIN):
        raise InputError(
            f"uncertainty: True is available for the methods {', '.join(UNCERTAIN)}, got method={method!r}"
        )
    z, src, user_mask, out, tie_tol, relative = _inputs(depth, mask, out, scale_invariant, disparity)
    workers = _workers(threads)

    def frame(i, bands=whole):
        """Depth, validity and options of frame i (None: the only frame), rescaled into range if needed."""
        z_i, src_i, options = (z, src, clean) if i is None else (z[i], src[i], clean)
        m_i = user_mask if i is None or user_mask is None else user_mask[i]
        if not relative:
            z_i, options = _in_range(method_obj, options, src_i, z_i)
        return z_i, _valid(z_i, m_i, bands), dict(options)

    if z.ndim == 2:
        cam = Intrinsics.from_matrix(K)
        cam.check_frame(z.shape, stacklevel=2)
        bands = on_threads(workers)
        z_0, valid_0, options_0 = frame(None, bands)
        if uncertainty:
            sigma = new_result(z.shape)
            normals = _run_uncertain(method_obj, options_0, z_0, valid_0, cam, out, sigma, tie_tol, relative, bands)
            return normals, sigma
        return _run(method_obj, refined, options_0, z_0, valid_0, cam, out, tie_tol, relative, bands)
    cams = cast(list, _intrinsics_list(K, z.shape[0]))  # a list for a stack
    one_camera = all(c is cams[0] for c in cams)
    for i, cam_i in {id(c): (i, c) for i, c in enumerate(cams)}.values():  # each distinct camera once
        cam_i.check_frame(z.shape, name="K" if one_camera else f"K[{i}]", stacklevel=2)
    if out is None:
        out = new_result(z.shape + (3,))
    sigmas = new_result(z.shape) if uncertainty else None

    def one(i):
        # Everything per frame (validity, kernel) runs here, so frames proceed in parallel:
        # the kernels release the GIL (nogil=True).
        z_i, valid_i, options_i = frame(i)
        if sigmas is not None:
            _run_uncertain(method_obj, options_i, z_i, valid_i, cams[i], out[i], sigmas[i], tie_tol, relative)
        else:
            _run(method_obj, refined, options_i, z_i, valid_i, cams[i], out[i], tie_tol, relative)

    if workers == 1 or z.shape[0] == 1:
        for i in range(z.shape[0]):
            one(i)
    else:
        map_threads(one, z.shape[0], min(workers, z.shape[0]))
    return out if sigmas is None else (out, sigmas)


def refine(normals, depth, *, mask=None, dlf: str = "alpha", fill: float = 0.0) -> np.ndarray:
    """MNR (MRF-based normal refinement, Sec. III-C) on any normal map.

    Each pixel takes the normal of the smoothest pixel (smallest |Laplacian of
    depth| under ``dlf``) among its 4-neighbours and itself; see
    :mod:`surfnorm.kernels.mnr`.

    Parameters
    ----------
    normals : ndarray of shape (H, W, 3)
        Normals from any estimator; zero or non-finite vectors count as missing.
    depth : ndarray of shape (H, W)
        The depth they were estimated from.
    mask : ndarray of bool, optional
        False where depth must not be used. Masked entries of NumPy masked
        arrays (``depth``, ``normals`` or ``mask``) count as unusable too.
    dlf : {"1d", "alpha", "beta", "gamma"}
        Discrete Laplace filter for the smoothness (default alpha, as the authors' code).
    fill : float
        Value for pixels without a valid normal.

    Returns
    -------
    ndarray of float32, shape (H, W, 3)
        The refined unit normals; ``fill`` where no valid normal exists.

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> depth = np.full((8, 8), 2.0)
    >>> noisy = np.zeros((8, 8, 3)); noisy[..., 2] = -1.0; noisy[4, 4] = [0.6, 0.0, -0.8]
    >>> surfnorm.refine(noisy, depth)[4, 4].tolist()   # on a flat wall every neighbour is as smooth
    [0.0, 0.0, -1.0]
    """
    from .kernels.mnr import mnr

    depth, unmasked = split_masked(depth)
    z = as_depth(depth, batch=False)
    if isinstance(normals, np.ma.MaskedArray):  # a masked component: the pixel has no normal
        normals = np.ma.filled(np.ma.asarray(normals, dtype=np.float32), np.nan)
    n = as_normals(normals, z.shape)
    check_choice("dlf", dlf, DLF_NAMES)
    fill = check_fill(fill)
    user_mask = as_mask(mask, z.shape)
    if unmasked is not None:
        user_mask = unmasked if user_mask is None else user_mask & unmasked
    from .units import range_exponent, scaled_frame

    k = range_exponent(z, np.asarray(depth))  # depth of any magnitude (MNR compares smoothness: scale-free)
    if k:
        z = scaled_frame(depth, k)
    valid = _valid(z, user_mask)
    return mnr(z, valid, n, np.empty_like(n), dlf=dlf, fill=fill)


def auto_decision(depth, K, *, mask=None, disparity: bool = False):
    """What the default method, ``auto``, runs on a frame, and the measurements it decided on.

    ``auto`` measures the depth's noise once per frame (the noise floor at the pixel scale, the noise at
    twice that scale in the quietest tenth of the frame, and the quantisation noise of depth terraces) and
    runs ``d2nt_v3`` on clean depth, ``adaptive_fit`` on sensor depth, their blend between, and ``adaptive_fit``
    with wide windows on depth resized from a lower resolution; see :mod:`surfnorm.kernels.auto`. This function
    measures the same and returns the decision without estimating any normal.

    Parameters
    ----------
    depth : ndarray of shape (H, W) or (N, H, W)
        Depth as given to :func:`estimate`.
    K : array_like of shape (3, 3) or (N, 3, 3), or Intrinsics
        As for :func:`estimate`.
    mask : ndarray of bool, optional
        As for :func:`estimate`.
    disparity : bool
        As for :func:`estimate`: the input holds disparity.

    Returns
    -------
    Decision, or a list of them for a stack
        ``method`` ("d2nt_v3", "adaptive_fit" or "blend"), ``weight`` (adaptive_fit's share), ``reading``
        (the noise level decided on, in point spacings z / f), the measurements behind it, and ``upsampled``
        (the factor of a resize from a lower resolution, or 1); ``str()`` of it is one line for a person.

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> K = [[500.0, 0, 31.5], [0, 500.0, 23.5], [0, 0, 1]]
    >>> v, u = np.mgrid[0:48, 0:64]
    >>> slope = 2.0 + 0.01 * u                      # a plane seen at an angle, exact
    >>> surfnorm.auto_decision(slope, K).method
    'd2nt_v3'
    >>> terraces = np.round(slope * 40) / 40        # the same plane in 2.5 cm steps
    >>> surfnorm.auto_decision(terraces, K).method
    'adaptive_fit'
    """
    from .kernels.auto import decide

    depth, unmasked = split_masked(depth)
    z = as_depth(depth)
    user_mask = as_mask(mask, z.shape)
    if unmasked is not None:
        user_mask = unmasked if user_mask is None else user_mask & unmasked
    if check_bool("disparity", disparity):
        from .units import relative_depth

        z = relative_depth(np.asarray(depth), valid_pixels(z, user_mask), disparity=True)
    if z.ndim == 2:
        return decide(z, _valid(z, user_mask), _intrinsics_list(K, None))
    cams = _intrinsics_list(K, z.shape[0])
    assert isinstance(cams, list)  # for a stack (n given)
    return [decide(z[i], _valid(z[i], None if user_mask is None else user_mask[i]), cams[i]) for i in range(len(z))]
