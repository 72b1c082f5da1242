"""The PyTorch backend: batched, differentiable normals from depth, on any device.

::

    import surfnorm.torch
    normals = surfnorm.torch.estimate(depth, K, method="d2nt_v3")   # depth (B, 1, H, W) -> (B, 3, H, W)
    layer = surfnorm.torch.DepthToNormal(method="d2nt_v2", dlf="alpha")

Same method names, options and conventions as :func:`surfnorm.estimate`
(camera frame x right, y down, z forward; unit normals facing the camera;
``fill`` where no valid normal exists; 0-based pixel centres), computed with
tensor operations instead of Numba kernels. Needs the ``torch`` extra
(``pip install surfnorm[torch]``); ``import surfnorm`` never imports torch.

Every method of :func:`surfnorm.methods` runs here (each also with
``+mnr``) except those whose registry entry says ``torch=False``
(:data:`NUMPY_ONLY`; :func:`estimate` names them in its InputError), and on the CPU gives the NumPy backend's normals to 1e-4 per
component (the tests compare them on the 12 frames of the 3F2N sample, with
and without holes; ``adaptive_fit`` and ``auto`` also on the real frames of
the sensor sample, where ``adaptive_fit`` gives the same bits).

* Device and dtype follow ``depth``: float32 and float64 are computed as
  they are; float16 and bfloat16 are computed in float32 and returned in
  their own dtype; integer depth gives float32. Where the NumPy kernels work
  in float64 (3F2N, SNE-RoadSeg, SDA-SNE, the plane fits, the averaging
  methods and the adaptive fit), so does this backend inside, whatever the
  input dtype. ``adaptive_fit`` and ``auto`` also take ``K`` in float64, so
  that their data-dependent choices (noise profile, radius, widening,
  quadrant, ``auto``'s weight) are those of the NumPy kernels: see
  :mod:`surfnorm.torch._adaptive`.
* No host synchronisation in the forward pass: every per-pixel choice is a
  ``torch.where`` on masks, so it runs asynchronously on a GPU and traces
  under ``torch.compile``. Two exceptions: ``sda_sne`` with
  ``iterations=None`` (until stable) reads once per pass whether every frame
  has stopped, and ``auto`` once per batch whether any frame was resized from
  a lower resolution. (On the CPU the plane fits also gather the pixels whose
  Newton iteration still moves, and ``adaptive_fit`` and ``auto`` the pixels
  and frames each step concerns, which is free there.)
* SDA-SNE's dynamic programming is a Jacobi iteration: each pass is
  element-wise over all pixels, scanlines and both axes at once (see
  :mod:`surfnorm.torch._sda`), and each frame of a batch stops on its own,
  as the NumPy kernel's loop does.

Gradients. Every method is differentiable with respect to ``depth`` almost
everywhere (``torch.autograd.gradcheck`` passes in float64 for each, with a
hole). None is non-differentiable as a whole; what carries no gradient, and
why:

* the discrete choices are piecewise constant: the truncated softmin and
  MNR (which neighbour), 3F2N's median (which candidate), SDA-SNE's dynamic
  programming (which of the nine candidates; its energies are computed on
  detached depth), the plane fits' null vector (which pair of rows),
  ``adaptive_fit``'s noise profile and windows (each pixel's radius,
  widening and quadrant: the fit of the chosen window is differentiable in
  the depths inside it, and the gradient flows there only), ``auto``'s
  choice and blend weight (from the noise floor; the blend itself passes
  the gradient to both normals). The
  gradient flows through the value that was chosen; exactly at a tie it is
  that of the side the forward pass took;
* constant outputs have zero gradient: the fill value (invalid pixels get
  zero gradient), and the fronto-parallel fallback (0, 0, -1) of 3F2N,
  SNE-RoadSeg and SDA-SNE's 3F2N base where no candidate is left;
* the plane fits' gradient is that of the smallest eigenvalue, undefined
  where it is repeated (a window whose points spread equally in two
  directions about their centroid): it is taken through one Newton step at
  the root, finite but meaningless there.
"""

from __future__ import annotations

import math
from typing import Callable

try:
    import torch
except ImportError as exc:  # pragma: no cover - exercised only without torch
    from ..errors import MissingDependencyError

    raise MissingDependencyError(
        "surfnorm.torch needs PyTorch: install the extra with `pip install surfnorm[torch]`"
    ) from exc

from ..errors import InputError
from ..methods import MNR_SUFFIX
from ..methods import methods as numpy_methods
from ..methods import resolve as numpy_resolve
from . import _adaptive, _averaging, _ops, _plane_fit, _sda, _sne
from ._validate import as_depth, as_intrinsics, as_mask, compute_dtype

__all__ = ["estimate", "DepthToNormal", "methods"]


# The torch kernels by method name: ``run(grid, cam, **options) -> (B, 3, H, W)``, where the options are
# those of the NumPy backend's method (surfnorm.methods: same names, defaults and checks; ``mnr_dlf`` is
# taken off and applied here, as MNR runs after the kernel). Whether a recipe ends with MNR (d2nt_v3) is
# read from the NumPy registry too, so the two backends cannot disagree on a method's options.
# A method registered with ``torch=False`` (surfnorm.methods) has no kernel here: it is left out of
# :func:`methods`, and :func:`estimate` names it in an InputError (:data:`NUMPY_ONLY`). Giving one a torch
# twin: write its kernel as ``run(g: _ops.Grid, cam, *, <its options>, fill) -> (B, 3, H, W)`` in a module
# of this package (g.z is depth with invalid pixels set to 1, g.valid the validity, cam = (fx, fy, cx, cy)
# each (B, 1, 1)), add ``_register("name", module.run)`` below and drop ``torch=False`` from its entry;
# tests/test_torch.py then compares it with the NumPy backend (and fails while the two disagree).
_KERNELS: dict[str, Callable] = {}


def _register(name: str, run: Callable) -> None:
    _KERNELS[name] = run


def _d2nt_dag(g, cam, *, dlf, tau, truncate, fill):
    return _ops.d2nt_dag(g, cam, dlf=dlf, tau=tau, truncate=truncate, fill=fill)


_register("d2nt_basic", _ops.d2nt_basic)
_register("d2nt_v2", _d2nt_dag)
_register("d2nt_v3", _d2nt_dag)  # + MNR (the NumPy registry marks the recipe)
_register("cp2tv", _ops.cp2tv)
_register("3f2n_mean", lambda g, cam, *, border, fill: _ops.three_f2n(g, cam, third="mean", border=border, fill=fill))
_register(
    "3f2n_median", lambda g, cam, *, border, fill: _ops.three_f2n(g, cam, third="median", border=border, fill=fill)
)
_register("sne_roadseg", _sne.sne_roadseg)
_register("sda_sne", _sda.sda_sne)
_register("plane_svd", _plane_fit.plane_svd)
_register("plane_pca", _plane_fit.plane_pca)
_register("vector_svd", _plane_fit.vector_svd)
_register("area_weighted", _averaging.area_weighted)
_register("angle_weighted", _averaging.angle_weighted)
_register("adaptive_fit", _adaptive.adaptive_fit)
_register("auto", _adaptive.auto)

#: Kernels that take the intrinsics in float64 whatever the depth's dtype, as the NumPy kernels do: their
#: data-dependent choices (noise test, radius) must see the same numbers.
_FLOAT64_CAMERA = (_adaptive.adaptive_fit, _adaptive.auto)

#: Kernels whose products of depth leave the floating-point range at extreme magnitudes (1e-60, 1e60): their
#: depth is brought into range first (:func:`_unit_range`), as PlaneSVD's and SDA-SNE's always is.
_PLANE_FITS = (_plane_fit.plane_svd, _plane_fit.plane_pca, _plane_fit.vector_svd)

#: Registered methods that run only in :func:`surfnorm.estimate`: those whose entry in
#: :mod:`surfnorm.methods` says ``torch=False``.
NUMPY_ONLY = tuple(name for name, info in numpy_methods().items() if not info.torch)


def methods() -> dict[str, dict]:
    """The methods this backend offers, by name, with their options' defaults (any may take ``+mnr``).

    The same names, options and defaults as :func:`surfnorm.methods`.
    """
    registered = numpy_methods()
    return {name: dict(info.options) for name, info in registered.items() if info.torch and name in _KERNELS}


def _resolve(name, options: dict):
    """(kernel, ends with MNR, refine after, clean options), checked as :func:`surfnorm.estimate` checks them."""
    if not isinstance(name, str):
        raise InputError(f"method: expected a method name (str), got {type(name).__name__} {name!r}")
    base = name[: -len(MNR_SUFFIX)] if name.endswith(MNR_SUFFIX) else name
    if base in NUMPY_ONLY:
        raise InputError(
            f"method: expected one of {', '.join(methods())} in the torch backend, got {name!r}, which has no "
            f"torch kernel (torch=False in surfnorm.methods) and runs only in surfnorm.estimate (NumPy)"
        )
    if base not in _KERNELS:
        raise InputError(
            f"method: expected one of {', '.join(methods())} (optionally followed by {MNR_SUFFIX!r}) "
            f"in the torch backend, got {name!r}"
        )
    method, refined, clean = numpy_resolve(name, options)
    return _KERNELS[base], method.mnr, refined, clean, method.equivariant


def _unit_range(z: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Depth, each frame multiplied by a power of two (``surfnorm.units``, "Range").

    1 unless the median of a strided sample (about 1024 values) of the frame's valid depth lies outside
    [2^-100, 2^100], where the plane fits' products leave the floating-point range; otherwise the power that
    brings it into [64, 128), as :func:`surfnorm.estimate` takes for PlaneSVD and SDA-SNE (whose normals depend
    on the unit). Exact, and on the device without a sync (``torch.compile`` traces it as one graph).
    """
    from ..units import UNIT_EXPONENT

    flat = torch.where(valid, z, torch.full_like(z, math.nan)).flatten(1)
    sample = flat[:, :: max(1, flat.shape[1] // 1024)].detach().double()
    med = torch.nanmedian(sample, dim=1).values  # NaN where a frame has no valid pixel
    outside = (med > 0) & ((med < 2.0**-UNIT_EXPONENT) | (med > 2.0**UNIT_EXPONENT))
    k = torch.where(outside, 7 - torch.frexp(med).exponent, torch.zeros_like(med, dtype=torch.int32))
    scale = torch.ldexp(torch.ones_like(med), k).view(-1, *([1] * (z.dim() - 1)))
    return z * scale if z.dtype == torch.float64 else (z.double() * scale).to(z.dtype)


def estimate(depth, K, *, method: str = "d2nt_v3", mask=None, uncertainty: bool = False, **options) -> torch.Tensor:
    """Estimate surface normals from a batch of depth images.

    Parameters
    ----------
    depth : Tensor of shape (B, 1, H, W) or (H, W)
        Depth along the optical axis, any floating or integer dtype, any
        device. Pixels with depth 0, negative, NaN or inf are invalid and never used.
    K : Tensor or array_like of shape (B, 3, 3) or (3, 3), or Intrinsics
        [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with 0-based pixel centres. A
        tensor may live on depth's device or on the CPU; its values are not
        checked (that would wait for the device); other forms are.
    method : str
        One of :func:`surfnorm.torch.methods` (the names of
        :func:`surfnorm.methods`), optionally followed by ``+mnr``.
    mask : Tensor of bool, shape (B, 1, H, W) or (H, W), optional
        False where depth must not be used; an (H, W) mask applies to every frame.
    uncertainty : bool
        Not available on this backend: True raises InputError (each normal's
        sigma comes from :func:`surfnorm.estimate` with ``uncertainty=True``).
    **options
        The method's options, as in :func:`surfnorm.estimate` (``dlf``,
        ``tau``, ``truncate``, ``border``, ``window``, ``iterations``,
        ``base``, ``mnr_dlf``, ``fill``).

    Returns
    -------
    Tensor of shape (B, 3, H, W)
        Unit normals (x right, y down, z forward) facing the camera, with
        ``fill`` (default 0.0) in all three components where there is no
        valid normal. An (H, W) depth gives B = 1. Same device as depth;
        dtype that of depth (float32 for integer depth).

    Raises
    ------
    InputError (a ValueError)
        Bad depth, K, mask, method name or option; the message names which.

    Examples
    --------
    >>> import torch, surfnorm.torch
    >>> K = torch.tensor([[500.0, 0, 31.5], [0, 500.0, 23.5], [0, 0, 1]])
    >>> n = surfnorm.torch.estimate(torch.full((2, 1, 48, 64), 2.0), K, method="d2nt_basic")
    >>> n.shape, n[0, :, 24, 32].tolist()
    (torch.Size([2, 3, 48, 64]), [0.0, 0.0, -1.0])
    """
    if uncertainty is not False:
        raise InputError(
            "uncertainty: the torch backend gives no sigma; use surfnorm.estimate(depth, K, uncertainty=True) "
            f"(NumPy; methods auto, adaptive_fit, d2nt_v3), got uncertainty={uncertainty!r}"
        )
    run, ends_with_mnr, refined, clean, equivariant = _resolve(method, options)
    z, plain = as_depth(depth)
    user_mask = as_mask(mask, z, plain)
    work, out_dtype = compute_dtype(z)
    z = z.to(work)
    cam = as_intrinsics(
        K, z.shape[0], z.device, torch.float64 if run in _FLOAT64_CAMERA else work, frame_shape=tuple(z.shape[-2:])
    )
    valid = (z > 0) & (z < math.inf)  # finite and positive (NaN fails both)
    if user_mask is not None:
        valid = valid & user_mask
    if not equivariant or run in _PLANE_FITS:  # (the others compute at any magnitude)
        z = _unit_range(z, valid)
    # invalid depth -> 1: never read by the estimators, and no NaN even in discarded branches (B x H x W)
    g = _ops.Grid(torch.where(valid, z, torch.ones_like(z)), valid)
    mnr_dlf = clean.pop("mnr_dlf", None)
    normals = run(g, cam, **clean)
    if ends_with_mnr:
        normals = _ops.mnr(g, normals, dlf=mnr_dlf, fill=clean["fill"])
    if refined:  # e.g. d2nt_v3+mnr refines twice, as surfnorm.estimate
        normals = _ops.mnr(g, normals, dlf=mnr_dlf, fill=clean["fill"])
    return normals.to(out_dtype)


class DepthToNormal(torch.nn.Module):
    """:func:`estimate` as a module: stores the method and its options, nothing else.

    ``DepthToNormal(method="d2nt_v3", **options)(depth, K, mask=None)`` equals
    ``estimate(depth, K, method=method, mask=mask, **options)``. The options are
    checked when the module is built.
    """

    def __init__(self, method: str = "d2nt_v3", **options):
        super().__init__()
        _resolve(method, options)
        self.method = method
        self.options = dict(options)

    def forward(self, depth: torch.Tensor, K, mask=None) -> torch.Tensor:
        """:func:`estimate` with the stored method and options."""
        return estimate(depth, K, method=self.method, mask=mask, **self.options)

    def extra_repr(self) -> str:
        """The method and options, as shown by ``print(module)``."""
        return ", ".join([f"method={self.method!r}"] + [f"{k}={v!r}" for k, v in self.options.items()])
