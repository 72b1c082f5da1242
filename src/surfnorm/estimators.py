"""Registers every estimator (imported lazily by :mod:`surfnorm.methods`)."""

from __future__ import annotations

from .methods import BORDER_OPTIONS, DAG_OPTIONS, Method, register
from .translate import cp2tv, d2nt

D2NT_PAPER = "Feng et al., D2NT: A High-Performing Depth-to-Normal Translator, ICRA 2023"


def _d2nt_basic(z, valid, cam, out, *, border, fill):
    return d2nt(z, valid, cam, out, gradient="fd", border=border, fill=fill)


def _d2nt_dag(z, valid, cam, out, *, dlf, tau, truncate, fill):
    return d2nt(z, valid, cam, out, gradient="dag", dlf=dlf, tau=tau, truncate=truncate, fill=fill)


register(Method("d2nt_basic", "depth-to-normal", D2NT_PAPER + ", eq. 9",
                "D2NT translation with finite-difference gradients", _d2nt_basic, BORDER_OPTIONS))
register(Method("d2nt_v2", "depth-to-normal", D2NT_PAPER + ", eq. 9-14",
                "D2NT with discontinuity-aware gradient (DAG) filter", _d2nt_dag, DAG_OPTIONS))
register(Method("d2nt_v3", "depth-to-normal", D2NT_PAPER + ", eq. 9-20, Sec. IV-A",
                "D2NT with DAG filter and MRF-based normal refinement (MNR)", _d2nt_dag, DAG_OPTIONS, mnr=True))
register(Method("cp2tv", "depth-to-normal",
                "Nakagawa et al., Estimating surface normals with depth image gradients for fast and accurate registration, 3DV 2015",
                "cross product of two finite-difference tangent vectors",
                lambda z, valid, cam, out, *, border, fill: cp2tv(z, valid, cam, out, border=border, fill=fill),
                BORDER_OPTIONS))


# --- Table I: energy minimisation (plane fitting) and averaging -----------------------------------
from ._validate import check_window  # noqa: E402
from .averaging import angle_weighted, area_weighted  # noqa: E402
from .methods import Option  # noqa: E402
from .plane_fit import plane_pca, plane_svd, vector_svd  # noqa: E402

WINDOW_OPTIONS = {
    "window": Option(3, check_window, "side of the square pixel neighbourhood whose points are fitted (odd, >= 3)"),
}

register(Method("plane_svd", "energy minimisation",
                "Wang et al., Comparison of local plane fitting methods for range data, CVPR 2001 "
                "(as formulated by Klasing et al., ICRA 2009); D2NT Table I",
                "least-squares plane with offset: smallest right singular vector of [Q+, 1]",
                plane_svd, WINDOW_OPTIONS))
register(Method("plane_pca", "energy minimisation",
                "Klasing et al., Realtime segmentation of range data using continuous nearest neighbors, ICRA 2009; "
                "D2NT Table I",
                "smallest eigenvector of the covariance of the window's points about their centroid",
                plane_pca, WINDOW_OPTIONS))
register(Method("vector_svd", "energy minimisation",
                "Jordan and Mordohai, A quantitative evaluation of surface normal estimation in point clouds, "
                "IROS 2014; D2NT Table I",
                "smallest right singular vector of the matrix of the vectors q - p",
                vector_svd, WINDOW_OPTIONS))
register(Method("area_weighted", "averaging",
                "Klasing et al., Comparison of surface normal estimation methods for range sensing applications, "
                "ICRA 2009; D2NT eq. 2 and Table I",
                "mean of the 8 triangle normals around the pixel, weighted by triangle area",
                area_weighted))
register(Method("angle_weighted", "averaging",
                "Jin et al., A comparison of algorithms for vertex normal computation, The Visual Computer 2005; "
                "D2NT eq. 2 and Table I",
                "mean of the 8 triangle normals around the pixel, weighted by their angle at the pixel",
                angle_weighted))
