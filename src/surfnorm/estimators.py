"""Registers every estimator (imported lazily by :mod:`surfnorm.methods`)."""

from __future__ import annotations

from .methods import BORDER_OPTIONS, DAG_OPTIONS, Method, register
from .translate import cp2tv, d2nt, d2nt_v3

D2NT_PAPER = "Feng et al., D2NT: A High-Performing Depth-to-Normal Translator, ICRA 2023"


def _d2nt_basic(z, valid, cam, out, *, border, fill):
    return d2nt(z, valid, cam, out, gradient="fd", border=border, fill=fill)


def _d2nt_dag(z, valid, cam, out, *, dlf, tau, truncate, fill):
    return d2nt(z, valid, cam, out, gradient="dag", dlf=dlf, tau=tau, truncate=truncate, fill=fill)


def _d2nt_v3(z, valid, cam, out, *, dlf, tau, truncate, mnr_dlf, fill):
    return d2nt_v3(z, valid, cam, out, dlf=dlf, tau=tau, truncate=truncate, mnr_dlf=mnr_dlf, fill=fill)


register(Method("d2nt_basic", "depth-to-normal", D2NT_PAPER + ", eq. 9",
                "D2NT translation with finite-difference gradients", _d2nt_basic, BORDER_OPTIONS))
register(Method("d2nt_v2", "depth-to-normal", D2NT_PAPER + ", eq. 9-14",
                "D2NT with discontinuity-aware gradient (DAG) filter", _d2nt_dag, DAG_OPTIONS))
register(Method("d2nt_v3", "depth-to-normal", D2NT_PAPER + ", eq. 9-20, Sec. IV-A",
                "D2NT with DAG filter and MRF-based normal refinement (MNR)", _d2nt_v3, DAG_OPTIONS, mnr=True))
register(Method("cp2tv", "depth-to-normal",
                "Nakagawa et al., Estimating surface normals with depth image gradients for fast and accurate registration, 3DV 2015",
                "cross product of two finite-difference tangent vectors",
                lambda z, valid, cam, out, *, border, fill: cp2tv(z, valid, cam, out, border=border, fill=fill),
                BORDER_OPTIONS))
