"""The registry of estimators: name -> kernel, recipe, category, paper reference, options.

A method name is a recipe. ``d2nt_v3`` is DAG gradients -> D2NT translation
-> MNR; any registered name followed by ``+mnr`` runs MNR after it (Table IV:
``3f2n_median+mnr``, ``cp2tv+mnr``). The CLI and the benchmark read their
choices from here, so a new estimator appears everywhere once registered.

Every entry names the function that computes it, ``kernel="surfnorm.kernels.<module>.<function>"``,
written out once: the entry's ``run`` imports that module on the method's first run and calls the
function with the checked options (and the entry's ``kernel_args``, e.g. ``gradient="fd"``), so that
``import surfnorm`` loads no Numba, and a first ``estimate(..., method="d2nt_v3")`` loads only the D2NT
kernels (tests/test_methods.py checks that each path imports and that each run calls it). ``torch``
says whether :mod:`surfnorm.torch` has a twin of the kernel; the documentation's method listing and
kernel page are generated from these entries. How to add an estimator: docs/contributing.md.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Callable

from ._choices import BORDERS, DLF_NAMES, SDA_BASES, SDA_MAX_ITERATIONS
from ._constants import DLF_DEFAULT, MAX_WINDOW, MNR_DLF_DEFAULT, TRUNCATE_DEFAULT
from ._validate import check_bool, check_choice, check_fill, check_iterations, check_positive, check_window
from .errors import InputError

__all__ = [
    "Option",
    "Method",
    "MethodInfo",
    "register",
    "resolve",
    "methods",
    "OptionInfo",
    "options_of",
    "parse_method",
    "CATEGORIES",
    "MNR_SUFFIX",
    "DEFAULT_METHOD",
]

CATEGORIES = ("energy minimisation", "averaging", "depth-to-normal", "automatic")
MNR_SUFFIX = "+mnr"
#: The method of :func:`surfnorm.estimate`, the CLI and :func:`surfnorm.convert` when none is named.
DEFAULT_METHOD = "auto"


@dataclass(frozen=True)
class Option:
    """A keyword option of a method: its default, a checker that returns the clean value, its meaning, its values.

    ``doc`` (what it does) and ``allowed`` (the values its checker accepts) are what ``surfnorm methods NAME``
    prints and what the documentation's methods page shows: the one place where each option is explained.
    """

    default: Any
    check: Callable[[str, Any], Any]
    doc: str
    allowed: str = ""


@dataclass(frozen=True)
class OptionInfo:
    """What :func:`options_of` reports about one option of a method."""

    name: str
    default: Any
    allowed: str
    doc: str


def _dlf(name, value):
    return check_choice(name, value, DLF_NAMES)


_DLF_ALLOWED = ", ".join(DLF_NAMES)

FILL = Option(
    0.0,
    lambda name, value: check_fill(value),
    "value written into all three components where no valid normal exists",
    "a number float32 can hold: 0.0, nan, +-inf, or a magnitude between 1.4e-45 and 3.4e38",
)
DAG_OPTIONS = {
    "dlf": Option(
        DLF_DEFAULT,
        _dlf,
        "discrete Laplace filter of the DAG smoothness (Table II): which neighbours measure how smooth each side "
        "of a pixel is",
        _DLF_ALLOWED,
    ),
    "tau": Option(
        1.0,
        check_positive,
        "softness tau of the softmin (eq. 13), in depth units (relative to each pixel's depth with "
        "scale_invariant=True): smaller trusts the smoother side more",
        "a positive finite number",
    ),
    "truncate": Option(
        TRUNCATE_DEFAULT,
        check_bool,
        "use the truncated softmin (eq. 14): the smoother side alone where one is clearly smoother",
        "True, False",
    ),
}
BORDER_OPTIONS = {
    "border": Option(
        "one-sided",
        lambda name, value: check_choice(name, value, BORDERS),
        "finite differences at the image border: one-sided, or reflect (OpenCV BORDER_REFLECT_101, "
        "as the authors' code, which zeroes the gradient there)",
        ", ".join(BORDERS),
    ),
}
MNR_OPTIONS = {
    "mnr_dlf": Option(
        MNR_DLF_DEFAULT,
        _dlf,
        "discrete Laplace filter of the MNR smoothness (authors' code: alpha; Sec. IV-A text: beta)",
        _DLF_ALLOWED,
    ),
}


def _call_kernel(kernel: str, kernel_args: dict, z, valid, cam, out, **options):
    """Import the module of ``kernel`` (``"package.module.function"``) and call the function: the run of an entry."""
    module, _, function = kernel.rpartition(".")
    return getattr(importlib.import_module(module), function)(z, valid, cam, out, **kernel_args, **options)


@dataclass(frozen=True)
class Method:
    """A registered estimator.

    ``run(z, valid, cam, out, **options)`` fills ``out`` (H, W, 3) float32 from
    validated depth ``z`` (H, W) float32, ``valid`` (H, W) bool and
    :class:`~surfnorm.camera.Intrinsics` ``cam``. Left out (the usual case), it
    is derived from the entry: it calls the function that ``kernel`` names
    (``"surfnorm.kernels.<module>.<function>"``, imported on the first run) with
    ``kernel_args`` and the method's checked options.
    """

    name: str
    category: str
    reference: str
    summary: str
    run: Callable = None  # type: ignore[assignment]  # None: derived from kernel and kernel_args (__post_init__)
    options: dict = field(default_factory=dict)
    mnr: bool = False  # the recipe ends with MNR, which run does itself (fused), taking mnr_dlf
    ties: bool = False  # run takes ``tie_tol`` (near-ties as ties), which the scale-invariant mode passes
    relative: bool = False  # run takes ``relative`` (tau relative to each pixel's depth), which that mode passes
    # Normals unchanged when depth (and tau) are multiplied by a power of two: the paper-faithful mode may then
    # rescale a frame whose depth would leave float32's range (surfnorm.units, "Range"). False for fits whose
    # result depends on the unit of depth (PlaneSVD's offset, SDA-SNE's penalty), which compute in float64.
    equivariant: bool = True
    # How one frame is split over threads. True: run takes ``bands`` and runs each of its stages through it
    # in row bands, every band reading the rows around it that it needs (its halo) from the whole frame, so
    # the result is the same to the bit (see surfnorm._bands). False: one frame runs on one thread.
    bands: bool = False
    kernel: str = ""  # where the kernel lives: "surfnorm.kernels.<module>.<function>"
    # Checks between options (each option's own checker sees only its value): raises InputError. Called by
    # resolve, so both backends share it.
    check_options: Callable[[dict], None] | None = None
    # Keyword arguments the derived run passes to the kernel besides the options (d2nt_basic: gradient="fd").
    kernel_args: dict = field(default_factory=dict)
    # Whether surfnorm.torch has a twin of the kernel (registered there under the same name). False: the method
    # runs in surfnorm.estimate only, and surfnorm.torch.estimate says so (InputError).
    torch: bool = True

    def __post_init__(self):
        """Derive ``run`` from ``kernel`` and ``kernel_args`` where the entry gives none."""
        if self.run is None:
            if not self.kernel:
                raise ValueError(
                    f"method {self.name!r}: expected kernel='surfnorm.kernels.<module>.<function>' or a run"
                )
            object.__setattr__(self, "run", partial(_call_kernel, self.kernel, dict(self.kernel_args)))


@dataclass(frozen=True)
class MethodInfo:
    """What :func:`surfnorm.methods` reports about a method.

    ``kernel`` is where its kernel lives (``"surfnorm.kernels.<module>.<function>"``), ``kernel_args`` what
    the method passes to it besides its options, ``torch`` whether :mod:`surfnorm.torch` runs it too.
    """

    name: str
    category: str
    reference: str
    summary: str
    options: dict
    kernel: str = ""
    kernel_args: dict = field(default_factory=dict)
    torch: bool = True


_REGISTRY: dict[str, Method] = {}


def register(method: Method) -> Method:
    """Add ``method`` to the registry under its name (its category checked) and return it."""
    if method.category not in CATEGORIES:
        raise ValueError(f"category of {method.name!r}: expected one of {CATEGORIES}, got {method.category!r}")
    if MNR_SUFFIX in method.name:
        raise ValueError(f"method name {method.name!r} may not contain {MNR_SUFFIX!r}")
    _REGISTRY[method.name] = method
    return method


def methods() -> dict[str, MethodInfo]:
    """The registered estimators by name, in registration order.

    Any name may also be followed by ``+mnr`` to refine its output with MNR.

    Examples
    --------
    >>> import surfnorm
    >>> info = surfnorm.methods()["d2nt_v3"]
    >>> info.category, info.options["dlf"], info.options["mnr_dlf"]
    ('depth-to-normal', '1d', 'alpha')
    """
    return {
        m.name: MethodInfo(
            m.name,
            m.category,
            m.reference,
            m.summary,
            {k: o.default for k, o in option_specs(m, False).items()},
            m.kernel,
            dict(m.kernel_args),
            m.torch,
        )
        for m in _REGISTRY.values()
    }


def options_of(name: str) -> list[OptionInfo]:
    """Every option of a method (a name from :func:`methods`, optionally ending in ``+mnr``): meaning, default, values.

    The same text that ``surfnorm methods NAME`` prints and the documentation's methods page shows.

    Examples
    --------
    >>> from surfnorm.methods import options_of
    >>> [(o.name, o.default) for o in options_of("plane_pca")]
    [('fill', 0.0), ('window', 3)]
    >>> options_of("plane_pca")[1].allowed
    'an odd integer >= 3'
    """
    method, refined, _ = resolve(name, {})
    return [OptionInfo(k, o.default, o.allowed, o.doc) for k, o in option_specs(method, refined).items()]


def _option_value(text: str):
    """An option's value as typed on a command line: an int, a float, True/False, None, else the text itself."""
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return {"true": True, "false": False, "none": None}.get(text.lower(), text)


def parse_method(text: str) -> tuple[str, dict]:
    """A method with its options as one string, as ``surfnorm estimate -m`` takes it: ``NAME:opt=val,opt=val``.

    Options follow the name after ``:`` and are separated by ``,`` or ``:`` (the sensor benchmark's
    ``plane_pca:window=11:fill=nan`` works too). Values: integers, floats (``nan``), ``true``/``false``,
    ``none``, else text. The options are not checked here; :func:`surfnorm.estimate` checks them.

    Examples
    --------
    >>> from surfnorm.methods import parse_method
    >>> parse_method("adaptive_fit:window=5,max_window=11")
    ('adaptive_fit', {'window': 5, 'max_window': 11})
    >>> parse_method("sda_sne:iterations=none,base=3f2n")
    ('sda_sne', {'iterations': None, 'base': '3f2n'})
    """
    if not isinstance(text, str):
        raise InputError(f"method: expected a method name (str), got {type(text).__name__} {text!r}")
    name, sep, rest = text.strip().partition(":")
    options: dict = {}
    for item in rest.replace(":", ",").split(",") if sep else []:
        key, eq, value = item.partition("=")
        if not eq or not key.strip() or not value.strip():
            raise InputError(f"method: expected NAME or NAME:option=value[,option=value...], got {text!r}")
        options[key.strip()] = _option_value(value.strip())
    return name.strip(), options


def option_specs(method: Method, refined: bool) -> dict[str, Option]:
    specs = {"fill": FILL, **method.options}
    if method.mnr or refined:
        specs.update(MNR_OPTIONS)
    return specs


def resolve(name, options: dict) -> tuple[Method, bool, dict]:
    """Look a method name up and check its options. Returns (method, refine_after, clean options)."""
    if not isinstance(name, str):
        raise InputError(f"method: expected a method name (str), got {type(name).__name__} {name!r}")
    base, refined = (name[: -len(MNR_SUFFIX)], True) if name.endswith(MNR_SUFFIX) else (name, False)
    if base not in _REGISTRY:
        raise InputError(
            f"method: expected one of {', '.join(_REGISTRY)} (optionally followed by {MNR_SUFFIX!r}), got {name!r}"
        )
    method = _REGISTRY[base]
    specs = option_specs(method, refined)
    unknown = sorted(set(options) - set(specs))
    if unknown:
        raise InputError(
            f"options of method {name!r}: expected some of {', '.join(sorted(specs))}, got unknown option(s) {', '.join(unknown)}"
        )
    clean = {k: spec.check(k, options[k]) if k in options else spec.default for k, spec in specs.items()}
    if method.check_options is not None:
        method.check_options(clean)
    return method, refined, clean


# --- The estimators ------------------------------------------------------------------------------
# Each entry's ``kernel=`` names the function that computes it; its run imports it on the first call and
# passes the method's checked options (and ``kernel_args``) on to it (see the module docstring).

D2NT_PAPER = "Feng et al., D2NT: A High-Performing Depth-to-Normal Translator, ICRA 2023"


register(
    Method(
        "d2nt_basic",
        "depth-to-normal",
        D2NT_PAPER + ", eq. 9",
        "D2NT translation with finite-difference gradients",
        kernel="surfnorm.kernels.translate.d2nt",
        kernel_args=dict(gradient="fd"),
        options=BORDER_OPTIONS,
        bands=True,
    )
)
register(
    Method(
        "d2nt_v2",
        "depth-to-normal",
        D2NT_PAPER + ", eq. 9-14",
        "D2NT with discontinuity-aware gradient (DAG) filter",
        kernel="surfnorm.kernels.translate.d2nt",
        kernel_args=dict(gradient="dag"),
        options=DAG_OPTIONS,
        relative=True,
        bands=True,
    )
)
register(
    Method(
        "d2nt_v3",
        "depth-to-normal",
        D2NT_PAPER + ", eq. 9-20, Sec. IV-A",
        "D2NT with DAG filter and MRF-based normal refinement (MNR)",
        kernel="surfnorm.kernels.d2nt_v3.d2nt_v3",
        options=DAG_OPTIONS,
        mnr=True,
        ties=True,
        relative=True,
        bands=True,
    )
)
register(
    Method(
        "cp2tv",
        "depth-to-normal",
        "Nakagawa et al., Estimating surface normals with depth image gradients for fast and accurate registration, 3DV 2015",
        "cross product of two finite-difference tangent vectors",
        kernel="surfnorm.kernels.translate.cp2tv",
        options=BORDER_OPTIONS,
        bands=True,
    )
)

# --- 3F2N and SNE-RoadSeg ------------------------------------------------------------------------

THREE_F2N_PAPER = "Fan et al., Three-Filters-to-Normal: An Accurate and Ultrafast Surface Normal Estimator, RA-L 2021"


register(
    Method(
        "3f2n_mean",
        "depth-to-normal",
        THREE_F2N_PAPER + ", eq. 7-11",
        "3F2N: gradients of inverse depth, n_z as the mean over the 8 neighbours",
        kernel="surfnorm.kernels.three_filters.three_filters",
        kernel_args=dict(third="mean"),
        options=BORDER_OPTIONS,
        bands=True,
    )
)
register(
    Method(
        "3f2n_median",
        "depth-to-normal",
        THREE_F2N_PAPER + ", eq. 7-11",
        "3F2N: gradients of inverse depth, n_z as the median over the 8 neighbours",
        kernel="surfnorm.kernels.three_filters.three_filters",
        kernel_args=dict(third="median"),
        options=BORDER_OPTIONS,
        bands=True,
    )
)
register(
    Method(
        "sne_roadseg",
        "depth-to-normal",
        "Fan et al., SNE-RoadSeg: Incorporating Surface Normal Information into Semantic Segmentation "
        "for Accurate Freespace Detection, ECCV 2020, Sec. 3.1",
        "SNE of SNE-RoadSeg: 3F2N gradients, unit neighbour normals fused through the polar angle",
        kernel="surfnorm.kernels.three_filters.sne_roadseg",
        options=BORDER_OPTIONS,
        bands=True,
    )
)

# --- SDA-SNE -------------------------------------------------------------------------------------

SDA_OPTIONS = {
    "iterations": Option(
        3,
        check_iterations,
        "passes of the dynamic programming (authors' demo: 3); None runs until no pixel changes, "
        f"at most {SDA_MAX_ITERATIONS} passes",
        "an integer >= 0, or None",
    ),
    "base": Option(
        "cp2tv",
        lambda name, value: check_choice(name, value, SDA_BASES),
        "how gradients become normals: cp2tv (on depth, the paper's SDA-SNE) or 3f2n "
        "(SDA on inverse depth, then 3F2N's median filter, as the authors' demo offers)",
        ", ".join(SDA_BASES),
    ),
    **BORDER_OPTIONS,
}


register(
    Method(
        "sda_sne",
        "energy minimisation",
        "Ming et al., SDA-SNE: Spatial Discontinuity-Aware Surface Normal Estimation via Multi-Directional "
        "Dynamic Programming, 3DV 2022",
        "depth gradients chosen by multi-directional dynamic programming, then CP2TV",
        kernel="surfnorm.kernels.sda.sda_sne",
        options=SDA_OPTIONS,
        ties=True,
        equivariant=False,
        bands=True,
    )
)

# --- Table I: energy minimisation (plane fitting) and averaging -----------------------------------

WINDOW_OPTIONS = {
    "window": Option(
        3,
        check_window,
        "side of the square pixel neighbourhood whose points are fitted: larger smooths noise and rounds edges; "
        "one wider than the frame is clipped to 2 max(H, W) - 1, which holds every pixel of the frame from any "
        "pixel (the same normals)",
        "an odd integer >= 3",
    ),
}


register(
    Method(
        "plane_svd",
        "energy minimisation",
        "Wang et al., Comparison of local plane fitting methods for range data, CVPR 2001 "
        "(as formulated by Klasing et al., ICRA 2009); D2NT Table I",
        "least-squares plane with offset: smallest right singular vector of [Q+, 1]",
        kernel="surfnorm.kernels.plane_fit.plane_svd",
        options=WINDOW_OPTIONS,
        relative=True,
        equivariant=False,
        bands=True,
    )
)
register(
    Method(
        "plane_pca",
        "energy minimisation",
        "Klasing et al., Realtime segmentation of range data using continuous nearest neighbors, ICRA 2009; "
        "D2NT Table I",
        "smallest eigenvector of the covariance of the window's points about their centroid",
        kernel="surfnorm.kernels.plane_fit.plane_pca",
        options=WINDOW_OPTIONS,
        bands=True,
    )
)
register(
    Method(
        "vector_svd",
        "energy minimisation",
        "Jordan and Mordohai, A quantitative evaluation of surface normal estimation in point clouds, "
        "IROS 2014; D2NT Table I",
        "smallest right singular vector of the matrix of the vectors q - p",
        kernel="surfnorm.kernels.plane_fit.vector_svd",
        options=WINDOW_OPTIONS,
        bands=True,
    )
)
register(
    Method(
        "area_weighted",
        "averaging",
        "Klasing et al., Comparison of surface normal estimation methods for range sensing applications, "
        "ICRA 2009; D2NT eq. 2 and Table I",
        "mean of the 8 triangle normals around the pixel, weighted by triangle area",
        kernel="surfnorm.kernels.averaging.area_weighted",
        bands=True,
    )
)
register(
    Method(
        "angle_weighted",
        "averaging",
        "Jin et al., A comparison of algorithms for vertex normal computation, The Visual Computer 2005; "
        "D2NT eq. 2 and Table I",
        "mean of the 8 triangle normals around the pixel, weighted by their angle at the pixel",
        kernel="surfnorm.kernels.averaging.angle_weighted",
        bands=True,
    )
)

register(
    Method(
        "cross_product",
        "depth-to-normal",
        "kornia (Riba et al., Kornia: an Open Source Differentiable Computer Vision Library for PyTorch, "
        "WACV 2020), kornia.geometry.depth.depth_to_normals",
        "cross product of the horizontal and vertical central differences of the back-projected points",
        kernel="surfnorm.kernels.cross_product.cross_product",
        bands=True,
        torch=False,
    )
)

# --- Sensor depth (ours) -------------------------------------------------------------------------

SURFNORM = "surfnorm (ours, not in the D2NT paper)"


def _check_window_or_none(name, value):
    return None if value is None else check_window(name, value)


def _check_stride(name, value):
    if value is None:
        return None
    if isinstance(value, int) and not isinstance(value, bool) and value in (1, 2, 4):
        return value
    raise InputError(f"{name}: expected 1, 2, 4 or None, got {value!r}")


ADAPTIVE_OPTIONS = {
    "window": Option(
        None,
        _check_window_or_none,
        "side of the fitted window; None: chosen per pixel from the frame's noise and the pixel's depth, "
        "smaller near depth edges (edge-aware quadrant windows)",
        "None, or an odd integer >= 3 and at most max_window",
    ),
    "max_window": Option(
        MAX_WINDOW,
        check_window,
        "largest window side the per-pixel choice may take, also where sparse depth (LiDAR) needs wide windows",
        "an odd integer >= 3",
    ),
    "stride": Option(
        None,
        _check_stride,
        "1: every pixel's own window; 2: windows on every other row and column, the pixels between taking the "
        "planes of the fitted pixels next to them (their mean, or the closest at an edge; a quarter of the fits); "
        "4: windows on every fourth row and column, each pixel taking the planes of its 4x4 cell's corners (their "
        "bilinear mean, or the closest at an edge; a sixteenth of the fits); None: 4 where every pixel but a few has a "
        "valid fitted pixel at a corner of its cell, else 2 unless the depth is sparse (LiDAR: 1); with "
        "uncertainty=True at most 2, the stride its sigma is calibrated at",
        "1, 2, 4, or None",
    ),
}


def _window_within_max(options: dict) -> None:
    window, max_window = options["window"], options["max_window"]
    if window is not None and window > max_window:  # the kernel's radius tables stop at max_window
        raise InputError(f"window: expected at most max_window ({max_window}), got {window}")


register(
    Method(
        "adaptive_fit",
        "energy minimisation",
        SURFNORM + ": least-squares plane of inverse depth over a window sized from the frame's noise, "
        "integral images, edge-aware quadrant windows",
        "plane fit of inverse depth, support sized from the depth's own noise; for sensor depth",
        kernel="surfnorm.kernels.adaptive_fit.adaptive_fit",
        options=ADAPTIVE_OPTIONS,
        bands=True,
        check_options=_window_within_max,
    )
)
register(
    Method(
        "auto",
        "automatic",
        SURFNORM + ": d2nt_v3 on clean depth, adaptive_fit on sensor depth, chosen from the depth's noise floor",
        "the default: d2nt_v3 or adaptive_fit, chosen from the depth itself",
        kernel="surfnorm.kernels.auto.auto",
        options={
            "tau": Option(
                1.0,
                DAG_OPTIONS["tau"].check,
                "softness tau of d2nt_v3's softmin (eq. 13), where auto picks d2nt_v3",
                DAG_OPTIONS["tau"].allowed,
            ),
            "stride": Option(
                None,
                _check_stride,
                "adaptive_fit's stride where auto runs it (see adaptive_fit); None: adaptive_fit's default",
                "1, 2, 4, or None",
            ),
        },
        ties=True,
        relative=True,
        bands=True,
    )
)
