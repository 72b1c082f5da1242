"""The estimators' kernels: Numba loops that trust validated input.

Nothing here validates or imports the registry; :mod:`surfnorm.methods` names,
for every method, the module and function below that computes it. The data
flow, bottom to top::

    _rows           helpers shared by the kernels (private): clamped reads, runs of
                    fully valid pixels, exp, normalise-and-store, orientation, points
    gradients       FD and DAG depth gradients (D2NT eq. 10-14)
    translate       D2NT eq. 9 (d2nt_basic, d2nt_v2) and CP2TV
    mnr             MNR (D2NT Sec. III-C, IV-A), on any normal map
    d2nt_v3         DAG gradients -> eq. 9 -> MNR, fused into one sweep
    three_filters   3F2N and SNE-RoadSeg
    sda             SDA-SNE
    plane_fit       PlaneSVD, PlanePCA, VectorSVD
    averaging       AreaWeighted, AngleWeighted
    adaptive_fit    plane fit of inverse depth for sensor depth (ours)
    auto            d2nt_v3 or adaptive_fit, chosen from the depth (ours)
"""
