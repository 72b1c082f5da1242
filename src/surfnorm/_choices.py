"""Names of the choices the kernels take, kept free of Numba so that ``import surfnorm`` stays cheap."""

from __future__ import annotations

#: How a finite difference treats the image border (see :func:`surfnorm.gradients.stencil`).
BORDERS = ("one-sided", "reflect")

#: The four discrete Laplace filters of Table II, by name.
DLF_NAMES = ("1d", "alpha", "beta", "gamma")
