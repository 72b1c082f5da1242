"""Names of the choices the kernels take, kept free of Numba so that ``import surfnorm`` stays cheap."""

from __future__ import annotations

#: How a finite difference treats the image border (see :func:`surfnorm.kernels.gradients.stencil`).
BORDERS = ("one-sided", "reflect")

#: The four discrete Laplace filters of Table II, by name.
DLF_NAMES = ("1d", "alpha", "beta", "gamma")

#: SDA-SNE: how the gradients become normals: CP2TV on depth, or 3F2N's median on inverse depth.
SDA_BASES = ("cp2tv", "3f2n")

#: SDA-SNE: safety cap on the passes of ``iterations=None`` (run until stable). On the
#: 3F2N sample the authors' stop test fires after 6 to 228 passes (planar
#: scenes take longest, because extending a run wins ties against keeping).
SDA_MAX_ITERATIONS = 1000

#: Orientation of a normal (see :func:`surfnorm.kernels._rows.facing_sign`): a normal within this relative margin of being
#: perpendicular to the viewing ray (|n . P| <= ORIENTATION_TIE |n| |P|) is edge-on, and its sign is decided by
#: a fixed rule instead of by rounding. (The kernels that use it are compiled with its value and cached: after
#: changing it, delete the Numba cache files in src/surfnorm/__pycache__.)
ORIENTATION_TIE = 1e-3
