"""Registers every estimator (imported lazily by :mod:`surfnorm.methods`).

A method's kernels are imported when it first runs, not here: the first
``estimate(..., method="d2nt_v3")`` in a fresh process then loads only the
D2NT kernels (measured: about 0.15 s less than loading every estimator's).
"""

from __future__ import annotations

import importlib
from functools import partial

from ._choices import SDA_BASES as _SDA_BASES, SDA_MAX_ITERATIONS as _SDA_MAX_ITERATIONS
from ._validate import check_choice as _check_choice, check_iterations as _check_iterations, check_window
from .methods import BORDER_OPTIONS, DAG_OPTIONS, Method, Option, register


def _kernel(module: str, name: str):
    """``surfnorm.<module>.<name>``, imported on its first call."""
    def run(*args, **kwargs):
        return getattr(importlib.import_module(f"surfnorm.kernels.{module}"), name)(*args, **kwargs)

    run.__name__ = run.__qualname__ = name
    return run


d2nt, d2nt_v3, cp2tv = _kernel("translate", "d2nt"), _kernel("translate", "d2nt_v3"), _kernel("translate", "cp2tv")
_three_filters, _sne_roadseg = _kernel("three_filters", "three_filters"), _kernel("three_filters", "sne_roadseg")
_sda_sne = _kernel("sda", "sda_sne")
plane_svd, plane_pca, vector_svd = (_kernel("plane_fit", n) for n in ("plane_svd", "plane_pca", "vector_svd"))
area_weighted, angle_weighted = _kernel("averaging", "area_weighted"), _kernel("averaging", "angle_weighted")

D2NT_PAPER = "Feng et al., D2NT: A High-Performing Depth-to-Normal Translator, ICRA 2023"


def _d2nt_basic(z, valid, cam, out, *, border, fill, **bands):
    return d2nt(z, valid, cam, out, gradient="fd", border=border, fill=fill, **bands)


def _d2nt_dag(z, valid, cam, out, *, dlf, tau, truncate, fill, relative=0.0, **bands):
    return d2nt(z, valid, cam, out, gradient="dag", dlf=dlf, tau=tau, truncate=truncate, fill=fill, relative=relative,
                **bands)


def _d2nt_v3(z, valid, cam, out, *, dlf, tau, truncate, mnr_dlf, fill, tie_tol=0.0, relative=0.0, **bands):
    return d2nt_v3(z, valid, cam, out, dlf=dlf, tau=tau, truncate=truncate, mnr_dlf=mnr_dlf, fill=fill, tie_tol=tie_tol,
                   relative=relative, **bands)


register(Method("d2nt_basic", "depth-to-normal", D2NT_PAPER + ", eq. 9",
                "D2NT translation with finite-difference gradients", _d2nt_basic, BORDER_OPTIONS, bands=True))
register(Method("d2nt_v2", "depth-to-normal", D2NT_PAPER + ", eq. 9-14",
                "D2NT with discontinuity-aware gradient (DAG) filter", _d2nt_dag, DAG_OPTIONS, relative=True, bands=True))
register(Method("d2nt_v3", "depth-to-normal", D2NT_PAPER + ", eq. 9-20, Sec. IV-A",
                "D2NT with DAG filter and MRF-based normal refinement (MNR)", _d2nt_v3, DAG_OPTIONS, mnr=True,
                ties=True, relative=True, bands=True))
register(Method("cp2tv", "depth-to-normal",
                "Nakagawa et al., Estimating surface normals with depth image gradients for fast and accurate registration, 3DV 2015",
                "cross product of two finite-difference tangent vectors",
                lambda z, valid, cam, out, *, border, fill, **bands: cp2tv(z, valid, cam, out, border=border, fill=fill,
                                                                           **bands),
                BORDER_OPTIONS, bands=True))

# --- 3F2N and SNE-RoadSeg (three_filters.py) -------------------------------------------------


THREE_F2N_PAPER = "Fan et al., Three-Filters-to-Normal: An Accurate and Ultrafast Surface Normal Estimator, RA-L 2021"

register(Method("3f2n_mean", "depth-to-normal", THREE_F2N_PAPER + ", eq. 7-11",
                "3F2N: gradients of inverse depth, n_z as the mean over the 8 neighbours",
                partial(_three_filters, third="mean"),
                BORDER_OPTIONS, bands=True))
register(Method("3f2n_median", "depth-to-normal", THREE_F2N_PAPER + ", eq. 7-11",
                "3F2N: gradients of inverse depth, n_z as the median over the 8 neighbours",
                partial(_three_filters, third="median"),
                BORDER_OPTIONS, bands=True))
register(Method("sne_roadseg", "depth-to-normal",
                "Fan et al., SNE-RoadSeg: Incorporating Surface Normal Information into Semantic Segmentation "
                "for Accurate Freespace Detection, ECCV 2020, Sec. 3.1",
                "SNE of SNE-RoadSeg: 3F2N gradients, unit neighbour normals fused through the polar angle",
                _sne_roadseg,
                BORDER_OPTIONS, bands=True))

# --- SDA-SNE (sda.py) ----------------------------------------------------------------------------


SDA_OPTIONS = {
    "iterations": Option(3, _check_iterations,
                         "passes of the dynamic programming (authors' demo: 3); None runs until no pixel changes, "
                         f"at most {_SDA_MAX_ITERATIONS} passes"),
    "base": Option("cp2tv", lambda name, value: _check_choice(name, value, _SDA_BASES),
                   "how gradients become normals: cp2tv (on depth, the paper's SDA-SNE) or 3f2n "
                   "(SDA on inverse depth, then 3F2N's median filter, as the authors' demo offers)"),
    **BORDER_OPTIONS,
}

register(Method("sda_sne", "energy minimisation",
                "Ming et al., SDA-SNE: Spatial Discontinuity-Aware Surface Normal Estimation via Multi-Directional "
                "Dynamic Programming, 3DV 2022",
                "depth gradients chosen by multi-directional dynamic programming, then CP2TV",
                lambda z, valid, cam, out, *, iterations, base, border, fill, tie_tol=0.0, **bands:
                    _sda_sne(z, valid, cam, out, iterations=iterations, base=base, border=border, fill=fill,
                             tie_tol=tie_tol, **bands),
                SDA_OPTIONS, ties=True, equivariant=False, bands=True))

# --- Table I: energy minimisation (plane fitting) and averaging -----------------------------------

WINDOW_OPTIONS = {
    "window": Option(3, check_window, "side of the square pixel neighbourhood whose points are fitted (odd, >= 3)"),
}

register(Method("plane_svd", "energy minimisation",
                "Wang et al., Comparison of local plane fitting methods for range data, CVPR 2001 "
                "(as formulated by Klasing et al., ICRA 2009); D2NT Table I",
                "least-squares plane with offset: smallest right singular vector of [Q+, 1]",
                plane_svd, WINDOW_OPTIONS, relative=True, equivariant=False, bands=True))
register(Method("plane_pca", "energy minimisation",
                "Klasing et al., Realtime segmentation of range data using continuous nearest neighbors, ICRA 2009; "
                "D2NT Table I",
                "smallest eigenvector of the covariance of the window's points about their centroid",
                plane_pca, WINDOW_OPTIONS, bands=True))
register(Method("vector_svd", "energy minimisation",
                "Jordan and Mordohai, A quantitative evaluation of surface normal estimation in point clouds, "
                "IROS 2014; D2NT Table I",
                "smallest right singular vector of the matrix of the vectors q - p",
                vector_svd, WINDOW_OPTIONS, bands=True))
register(Method("area_weighted", "averaging",
                "Klasing et al., Comparison of surface normal estimation methods for range sensing applications, "
                "ICRA 2009; D2NT eq. 2 and Table I",
                "mean of the 8 triangle normals around the pixel, weighted by triangle area",
                area_weighted, bands=True))
register(Method("angle_weighted", "averaging",
                "Jin et al., A comparison of algorithms for vertex normal computation, The Visual Computer 2005; "
                "D2NT eq. 2 and Table I",
                "mean of the 8 triangle normals around the pixel, weighted by their angle at the pixel",
                angle_weighted, bands=True))

# --- Sensor depth (ours): adaptive_fit.py, auto.py -------------------------------------------------

_adaptive_fit, _auto = _kernel("adaptive_fit", "adaptive_fit"), _kernel("auto", "auto")
SURFNORM = "surfnorm (ours, not in the D2NT paper)"


def _check_window_or_none(name, value):
    return None if value is None else check_window(name, value)


ADAPTIVE_OPTIONS = {
    "window": Option(None, _check_window_or_none,
                     "side of the fitted window (odd, >= 3); None: chosen per pixel from the frame's noise and "
                     "the pixel's depth"),
    "max_window": Option(31, check_window, "largest window side (odd, >= 3), also for sparse depth"),
}

register(Method("adaptive_fit", "energy minimisation",
                SURFNORM + ": least-squares plane of inverse depth over a window sized from the frame's noise, "
                "integral images, edge-aware quadrant windows",
                "plane fit of inverse depth, support sized from the depth's own noise; for sensor depth",
                _adaptive_fit, ADAPTIVE_OPTIONS))
register(Method("auto", "automatic",
                SURFNORM + ": d2nt_v3 on clean depth, adaptive_fit on sensor depth, chosen from the depth's "
                "noise floor",
                "the default: d2nt_v3 or adaptive_fit, chosen from the depth itself",
                _auto, {"tau": Option(1.0, DAG_OPTIONS["tau"].check, "softness tau of d2nt_v3's softmin (eq. 13), "
                                      "where auto picks d2nt_v3")},
                ties=True, relative=True, bands=True))
