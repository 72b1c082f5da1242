"""A seeded depth-sensor noise model for tests and benchmarks.

Three effects of structured-light and stereo depth cameras, applied in this order:

1. axial noise: Gaussian along the ray with a standard deviation that grows
   with depth, sigma(z) = a + b z^2 (structured light: the disparity error is
   about constant, and dz = z^2 / (f B) dd). The defaults a = 1.2 mm and
   b = 1.9 mm/m^2 are close to the Kinect v1 fit of Nguyen, Izadi and Lovell
   (3DIMPVT 2012, sigma = 0.0012 + 0.0019 (z - 0.4)^2 m), without its offset;
2. quantisation to multiples of ``quantum`` (1 mm, as a 16-bit millimetre PNG
   stores it);
3. dropouts: pixels within ``edge_width`` pixels of a depth discontinuity (a
   jump between 4-neighbours of more than ``edge_jump`` times the depth, where
   the projector's pattern is occluded or smeared) become invalid (depth 0)
   with probability ``edge_dropout``; any pixel with probability ``dropout``.

All lengths are in the unit of the depth (metres for the defaults; use
:meth:`SensorNoise.in_unit` for millimetres). Invalid input pixels (0, NaN,
inf, negative) stay as they are. The same seed gives the same output.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ._validate import as_depth
from .errors import InputError

__all__ = ["SensorNoise", "add_noise"]


def _check(name, value, *, upper=None):
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not np.isfinite(value)
        or value < 0
    ):
        raise InputError(f"{name}: expected a finite number >= 0, got {value!r}")
    if upper is not None and value > upper:
        raise InputError(f"{name}: expected a number <= {upper}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class SensorNoise:
    """Parameters of the noise model (lengths in the depth unit; defaults: metres, Kinect-v1-like)."""

    a: float = 0.0012  # axial noise at zero depth
    b: float = 0.0019  # growth of axial noise with depth squared (per unit of depth)
    quantum: float = 0.001  # depth step; 0 for none
    edge_jump: float = 0.05  # a relative jump |z_p - z_q| / z_p above this is a discontinuity
    edge_width: int = 1  # pixels on each side of a discontinuity that may drop out
    edge_dropout: float = 0.5  # probability that such a pixel drops out
    dropout: float = 0.0  # probability that any pixel drops out

    def __post_init__(self):
        for name in ("a", "b", "quantum", "edge_jump"):
            _check(name, getattr(self, name))
        for name in ("edge_dropout", "dropout"):
            _check(name, getattr(self, name), upper=1.0)
        if (
            isinstance(self.edge_width, bool)
            or not isinstance(self.edge_width, (int, np.integer))
            or self.edge_width < 0
        ):
            raise InputError(f"edge_width: expected an integer >= 0, got {self.edge_width!r}")

    def in_unit(self, per_metre: float) -> "SensorNoise":
        """The same sensor for depth stored in another unit: ``per_metre`` units per metre (1000 for mm)."""
        s = _check("per_metre", per_metre)
        if s == 0:
            raise InputError("per_metre: expected a positive number, got 0")
        return replace(self, a=self.a * s, b=self.b / s, quantum=self.quantum * s)

    def sigma(self, z):
        """Axial standard deviation sigma(z) = a + b z^2."""
        return self.a + self.b * np.asarray(z, dtype=np.float64) ** 2


def _edges(z: np.ndarray, valid: np.ndarray, jump: float, width: int) -> np.ndarray:
    """Valid pixels within ``width`` pixels of a 4-neighbour jump larger than ``jump`` times the depth (or of a hole)."""
    edge = np.zeros(z.shape, dtype=bool)
    for axis in (0, 1):
        a = np.swapaxes(z, 0, axis)
        va = np.swapaxes(valid, 0, axis)
        with np.errstate(invalid="ignore"):
            step = np.abs(a[1:] - a[:-1]) > jump * np.minimum(a[1:], a[:-1])
        step |= va[1:] != va[:-1]  # the rim of a hole is an edge too
        e = np.swapaxes(edge, 0, axis)
        e[1:] |= step
        e[:-1] |= step
    if width > 1:
        k = np.ones((2 * width - 1, 2 * width - 1), np.uint8)
        edge = cv2.dilate(edge.astype(np.uint8), k).astype(bool)
    return edge & valid


def add_noise(depth, model: SensorNoise | None = None, *, seed) -> np.ndarray:
    """Depth with sensor noise, float32 of the same shape (H, W); see the module docstring.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Clean depth; invalid pixels stay invalid.
    model : SensorNoise, optional
        Default: ``SensorNoise()`` (metres, Kinect-v1-like).
    seed : int or numpy.random.Generator
        Required, so that every use is reproducible.

    Examples
    --------
    >>> import numpy as np
    >>> from surfnorm.noise import add_noise, SensorNoise
    >>> z = add_noise(np.full((4, 4), 2.0), SensorNoise(quantum=0.001), seed=0)
    >>> bool(np.all(np.abs(z - 2.0) < 0.05)), bool(np.allclose(z * 1000, np.rint(z * 1000), atol=1e-3))
    (True, True)
    """
    model = SensorNoise() if model is None else model
    if not isinstance(model, SensorNoise):
        raise InputError(f"model: expected a SensorNoise, got {type(model).__name__}")
    if seed is None or isinstance(seed, bool):
        raise InputError(f"seed: expected an integer or a numpy Generator, got {seed!r}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    z = as_depth(depth, batch=False).astype(np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(z) & (z > 0)
    out = z.copy()
    noisy = z + rng.standard_normal(z.shape) * model.sigma(np.where(valid, z, 0.0))
    if model.quantum > 0:
        noisy = np.rint(noisy / model.quantum) * model.quantum
    noisy = np.where(noisy > 0, noisy, 0.0)  # noise never makes a negative depth; it makes a hole
    out[valid] = noisy[valid]
    drop = np.zeros(z.shape, dtype=bool)
    if model.edge_dropout > 0 and model.edge_width > 0:
        drop |= _edges(z, valid, model.edge_jump, model.edge_width) & (rng.random(z.shape) < model.edge_dropout)
    if model.dropout > 0:
        drop |= valid & (rng.random(z.shape) < model.dropout)
    out[drop] = 0.0
    return out.astype(np.float32)
