"""Which way a normal points: one rule, used wherever an estimator has to choose the sign.

3F2N (and SNE-RoadSeg and SDA-SNE's 3F2N base, which share its last step) and
the plane fits find a normal up to its sign and turn it to face the camera,
n . P < 0 with P the pixel's 3D point. Where the normal is (nearly)
perpendicular to the viewing ray, n . P is a difference of nearly equal
terms and its sign is decided by rounding: integer depth gives exact ties
(n . P = 0 in exact arithmetic), and the NumPy and PyTorch backends, or the
same depth in metres and in millimetres, rounded them to opposite signs
(a 180-degree difference on 0.1-0.3 % of the pixels of sensor frames).

The rule, :func:`facing_sign` here and ``surfnorm.torch._ops.facing_sign``:

1. if |n . P| > t |n| |P| (t = :data:`ORIENTATION_TIE` = 1e-3, i.e. the normal is
   more than 0.06 degrees away from edge-on): the sign that makes n . P < 0;
2. else (edge-on, both signs face the camera equally little) the first of
   n_z, n_y, n_x (in that order) whose magnitude exceeds t |n| is made
   negative: towards the camera along the optical axis, else "up", else "left".

Scale-free (both tests are relative), so the same in every unit of depth. t
is far above the rounding of n . P (float32 candidates in 3F2N: about 1e-7
relative; float64 elsewhere), and above what the float32 rounding of depth
in another unit does to an exact tie of integer depth: 3F2N's mean of
candidates, which divide by 1 mm steps, moves such a normal up to 1e-4 away
from edge-on (measured on the 3F2N sample read as centimetres, mm against
float32 metres; with t = 1e-5 that flipped 15 pixels). So exact and rounded
ties fall in the band the same way; a normal at the band's edge itself can
still go either way, as at any rule's boundary (a sign cannot be chosen
continuously for all directions). The folded angular error of the
benchmarks is unchanged by the sign: on the 12 frames of the 3F2N sample the
rule turns only edge-on normals around (measured with
``benchmarks/orientation_ties.py``).
"""

from __future__ import annotations

from .._choices import ORIENTATION_TIE
from .._config import pixel

__all__ = ["ORIENTATION_TIE", "facing_sign"]


@pixel
def facing_sign(n_x, n_y, n_z, p_x, p_y, p_z):
    """+1.0 or -1.0: the factor that turns (n_x, n_y, n_z) to face the camera from the point (p_x, p_y, p_z).

    Any positive multiple of n or of P gives the same answer. Float64, no branches (selects only).
    """
    d = n_x * p_x + n_y * p_y + n_z * p_z
    t2 = ORIENTATION_TIE * ORIENTATION_TIE * (n_x * n_x + n_y * n_y + n_z * n_z)
    edge_on = d * d <= t2 * (p_x * p_x + p_y * p_y + p_z * p_z)
    key = n_z if n_z * n_z > t2 else (n_y if n_y * n_y > t2 else n_x)
    key = key if edge_on else d
    return -1.0 if key > 0.0 else 1.0
