"""The registry of estimators: name -> recipe, category, paper reference, options.

A method name is a recipe. ``d2nt_v3`` is DAG gradients -> D2NT translation
-> MNR; any registered name followed by ``+mnr`` runs MNR after it (Table IV:
``3f2n_median+mnr``, ``cp2tv+mnr``). The CLI and the benchmark read their
choices from here, so a new estimator appears everywhere once registered.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from ._validate import check_bool, check_choice, check_fill, check_positive
from .errors import InputError
from ._choices import BORDERS, DLF_NAMES

__all__ = ["Option", "Method", "MethodInfo", "register", "resolve", "methods", "CATEGORIES", "MNR_SUFFIX", "DEFAULT_METHOD"]

CATEGORIES = ("energy minimisation", "averaging", "depth-to-normal", "automatic")
MNR_SUFFIX = "+mnr"
#: The method of :func:`surfnorm.estimate`, the CLI and :func:`surfnorm.convert` when none is named.
DEFAULT_METHOD = "auto"


@dataclass(frozen=True)
class Option:
    """A keyword option of a method: its default, a checker that returns the clean value, and a description."""

    default: Any
    check: Callable[[str, Any], Any]
    doc: str


def _dlf(name, value):
    return check_choice(name, value, DLF_NAMES)


FILL = Option(0.0, lambda name, value: check_fill(value),
              "value written into all three components where no valid normal exists")
DAG_OPTIONS = {
    "dlf": Option("1d", _dlf, "discrete Laplace filter of the DAG smoothness (Table II): 1d, alpha, beta, gamma"),
    "tau": Option(1.0, check_positive, "softness tau of the softmin (eq. 13)"),
    "truncate": Option(True, check_bool, "use the truncated softmin (eq. 14)"),
}
BORDER_OPTIONS = {
    "border": Option("one-sided", lambda name, value: check_choice(name, value, BORDERS),
                     "finite differences at the image border: one-sided, or reflect (OpenCV BORDER_REFLECT_101, "
                     "as the authors' code, which zeroes the gradient there)"),
}
MNR_OPTIONS = {
    "mnr_dlf": Option("alpha", _dlf, "discrete Laplace filter of the MNR smoothness (authors' code: alpha; Sec. IV-A text: beta)"),
}


@dataclass(frozen=True)
class Method:
    """A registered estimator.

    ``run(z, valid, cam, out, **options)`` fills ``out`` (H, W, 3) float32 from
    validated depth ``z`` (H, W) float32, ``valid`` (H, W) bool and
    :class:`~surfnorm.camera.Intrinsics` ``cam``.
    """

    name: str
    category: str
    reference: str
    summary: str
    run: Callable
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


@dataclass(frozen=True)
class MethodInfo:
    """What :func:`surfnorm.methods` reports about a method."""

    name: str
    category: str
    reference: str
    summary: str
    options: dict


_REGISTRY: dict[str, Method] = {}


def register(method: Method) -> Method:
    if method.category not in CATEGORIES:
        raise ValueError(f"category of {method.name!r}: expected one of {CATEGORIES}, got {method.category!r}")
    if MNR_SUFFIX in method.name:
        raise ValueError(f"method name {method.name!r} may not contain {MNR_SUFFIX!r}")
    _REGISTRY[method.name] = method
    return method


def _ensure_loaded():
    # Importing the estimator modules registers them; done lazily so that
    # ``import surfnorm`` stays cheap.
    from . import estimators  # noqa: F401


def methods() -> dict[str, MethodInfo]:
    """The registered estimators by name, in registration order.

    Any name may also be followed by ``+mnr`` to refine its output with MNR.
    """
    _ensure_loaded()
    return {
        m.name: MethodInfo(m.name, m.category, m.reference, m.summary,
                           {k: o.default for k, o in option_specs(m, False).items()})
        for m in _REGISTRY.values()
    }


def option_specs(method: Method, refined: bool) -> dict[str, Option]:
    specs = {"fill": FILL, **method.options}
    if method.mnr or refined:
        specs.update(MNR_OPTIONS)
    return specs


def resolve(name, options: dict) -> tuple[Method, bool, dict]:
    """Look a method name up and check its options. Returns (method, refine_after, clean options)."""
    _ensure_loaded()
    if not isinstance(name, str):
        raise InputError(f"method: expected a method name (str), got {type(name).__name__} {name!r}")
    base, refined = (name[: -len(MNR_SUFFIX)], True) if name.endswith(MNR_SUFFIX) else (name, False)
    if base not in _REGISTRY:
        raise InputError(f"method: expected one of {', '.join(_REGISTRY)} (optionally followed by {MNR_SUFFIX!r}), got {name!r}")
    method = _REGISTRY[base]
    specs = option_specs(method, refined)
    unknown = sorted(set(options) - set(specs))
    if unknown:
        raise InputError(f"options of method {name!r}: expected some of {', '.join(sorted(specs))}, got unknown option(s) {', '.join(unknown)}")
    clean = {k: spec.check(k, options[k]) if k in options else spec.default for k, spec in specs.items()}
    return method, refined, clean
