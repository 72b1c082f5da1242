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

# --- 3F2N and SNE-RoadSeg (three_filters.py) -------------------------------------------------

from .three_filters import sne_roadseg as _sne_roadseg, three_filters as _three_filters  # noqa: E402

THREE_F2N_PAPER = "Fan et al., Three-Filters-to-Normal: An Accurate and Ultrafast Surface Normal Estimator, RA-L 2021"

register(Method("3f2n_mean", "depth-to-normal", THREE_F2N_PAPER + ", eq. 7-11",
                "3F2N: gradients of inverse depth, n_z as the mean over the 8 neighbours",
                lambda z, valid, cam, out, *, border, fill: _three_filters(z, valid, cam, out, third="mean", border=border, fill=fill),
                BORDER_OPTIONS))
register(Method("3f2n_median", "depth-to-normal", THREE_F2N_PAPER + ", eq. 7-11",
                "3F2N: gradients of inverse depth, n_z as the median over the 8 neighbours",
                lambda z, valid, cam, out, *, border, fill: _three_filters(z, valid, cam, out, third="median", border=border, fill=fill),
                BORDER_OPTIONS))
register(Method("sne_roadseg", "depth-to-normal",
                "Fan et al., SNE-RoadSeg: Incorporating Surface Normal Information into Semantic Segmentation "
                "for Accurate Freespace Detection, ECCV 2020, Sec. 3.1",
                "SNE of SNE-RoadSeg: 3F2N gradients, unit neighbour normals fused through the polar angle",
                lambda z, valid, cam, out, *, border, fill: _sne_roadseg(z, valid, cam, out, border=border, fill=fill),
                BORDER_OPTIONS))
