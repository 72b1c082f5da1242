"""Families of depth made apart from the simulator's sensors: the default, its two estimators and the peers.

    PYTHONPATH=src python benchmarks/families.py
    PYTHONPATH=src python benchmarks/families.py --families upsampled_linear:8,median_mm --frames 4

`surfnorm.bench.simulate` models sensors from their physics. The families here are what processing does to depth
after the sensor, each from a few lines of OpenCV and NumPy, on the 3F2N frames (tests/data/3f2n-sample, 12 frames;
depth put at 2.5 m median, as the simulator's Kinect v1 does; seed = the frame's index):

- ``upsampled_linear:K``: a sensor of 1/K the resolution (every K-th pixel), 0.4 % depth noise there, resized back
  to the frame bilinearly (a low-resolution time-of-flight or phone LiDAR registered to a colour camera, or a depth
  completion's output); K a whole number or one halfway between two (7.5: a phone's 256x192 depth brought to its
  1920x1440 colour; the pixel nearest each sample's centre, (i + 0.5) K - 0.5);
- ``upsampled_nearest:K``: the same, resized back to the nearest pixel;
- ``upsampled_cubic:K``: the same, resized back bicubically (OpenCV's ``INTER_CUBIC``);
- ``median_mm``: 0.2 % noise, whole millimetres, then a 5x5 median filter (a common clean-up);
- ``tof_mm``: 2 mm + 0.1 % of depth of noise, whole millimetres;
- ``smooth_warp``: a relative error of 0.2 % RMS smooth over about 15 pixels (a learned depth's, say);
- ``white:P``: independent Gaussian noise of P % of the depth, nothing else (P from 0 to 5: 0.01 is 0.25 mm at
  2.5 m, a tenth of the distance between neighbouring pixels' points there);
- ``correlated:P``: Gaussian noise of P % of the depth RMS, smoothed over about a pixel (a Gaussian of 1 pixel) before
  it is scaled: error that neighbours share, small, in float depth (a phone's LiDAR depth, a learned stereo matcher's
  output);
- ``mm``: the exact depth stored in whole millimetres, no noise (a renderer's or a dataset's 16-bit PNG); ``mm:Q``,
  in steps of Q millimetres (Q above 0 and at most 20: 2 at 2.5 m is what whole millimetres are at 1.25 m, in point
  spacings);
- ``outliers``: 0.2 % noise, and 1 % of the pixels anywhere in 0.8-1.2 times their depth (multipath, specks);
- ``bilateral``: 0.4 % noise, then OpenCV's bilateral filter (7 pixels, 3 cm, 3 pixels): an edge-keeping clean-up;
- ``flying``: 0.2 % noise, and every pixel at a depth edge (its 3x3 mean off its depth by over 2 %) at that mean
  (mixed pixels: a time-of-flight camera's, or a filter's, between the two sides);
- ``blurred``: the exact depth smoothed by a Gaussian of 1.5 pixels over the valid pixels (a resampling's blur);
  ``blurred:S``, of S pixels (S above 0 and at most 10);
- ``dropped:H``: white noise of 0.005 % of depth, and H percent of the pixels (above 0, at most 90) dropped at random
  (no depth): holes that the noise measurement's stencils must bridge, on small white noise.

Seven more, written later as a check of the default on families it was not tuned on (none is in the default list):

- ``float16``: the exact depth stored as half floats (metres; a render's or a network's compact output);
- ``disparity16_mm``: a stereo camera's depth: disparity f B / z (baseline 5 cm) with 0.05 px of noise, in steps of
  1/16 px, then the depth in whole millimetres (a RealSense-like subpixel matcher's 16-bit output);
- ``structured_light``: raw structured light: disparity (baseline 7.5 cm) with an error averaged over a 9x9 window
  (the matcher's correlation window; 0.05 px RMS), in steps of 1/8 px, the depth in float;
- ``blocks``: a relative error of 0.3 % RMS, constant over each 7x7 block (a codec's block offsets): the shape is
  exact inside each block, and steps where blocks meet;
- ``dropped_noisy``: 0.2 % noise and 5 % of the pixels dropped at random;
- ``bilateral_mm``: 0.2 % noise, whole millimetres, then OpenCV's bilateral filter (5 pixels, 2 cm, 2 pixels): a
  camera SDK's edge-keeping spatial filter after its millimetre output;
- ``tof_flying_mm``: 1.5 mm + 0.1 % of depth of noise, mixed pixels at depth edges (as ``flying``), whole millimetres.

Two more, written later still (checks, in no list): depth completed from a LiDAR's samples
(:func:`surfnorm.bench.processing.scanlines`: every 4th row, half of its pixels, 0.02 % noise):

- ``scan_inpaint``: completed by OpenCV's inpainting (:func:`surfnorm.bench.processing.inpainted`);
- ``scan_ipbasic``: completed by the classical recipe of Ku et al. (:func:`surfnorm.bench.processing.ipbasic_completed`:
  dilations, a median and a Gaussian).

The scene's background is no depth (0), as the simulator's sensors see it; every family keeps invalid pixels invalid.

Per family and method: e_A in degrees (mean over the frames of the mean angle to the exact normals over the object's
pixels with depth and a normal). For the upsampled families also the default run at the sensor's own resolution
(on the 1/K depth, with the intrinsics scaled), its normals resized back to the nearest pixel: ``auto (native)``.
Every library runs on one thread.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
FAMILIES = (
    "upsampled_linear",
    "upsampled_nearest",
    "upsampled_cubic",
    "median_mm",
    "tof_mm",
    "smooth_warp",
    "white",
    "correlated",
    "mm",
    "outliers",
    "bilateral",
    "flying",
    "blurred",
    "dropped",
    "float16",
    "disparity16_mm",
    "structured_light",
    "blocks",
    "dropped_noisy",
    "bilateral_mm",
    "tof_flying_mm",
    "scan_inpaint",
    "scan_ipbasic",
)
DEFAULT = (
    "upsampled_linear:4,upsampled_linear:5,upsampled_linear:6,upsampled_linear:8,upsampled_linear:12,"
    "upsampled_linear:7.5,upsampled_nearest:8,upsampled_cubic:5,upsampled_cubic:6,upsampled_cubic:8,upsampled_cubic:12,"
    "upsampled_cubic:7.5,median_mm,tof_mm,"
    "smooth_warp,"
    "white:0.01,white:0.02,white:0.05,white:0.2,correlated:0.01,correlated:0.02,mm,mm:1.5,mm:2,mm:4,outliers,"
    "bilateral,flying,blurred"
)


def _number(text: str) -> float:
    """``text`` as a float; NaN where it is not a number (so that every range test refuses it)."""
    try:
        return float(text)
    except ValueError:
        return float("nan")


def parse_family(text: str) -> tuple[str, float]:
    """``"upsampled_linear:8"`` -> ("upsampled_linear", 8); ``"white:0.05"`` -> ("white", 0.05) (percent), and so
    ``correlated``; ``"blurred:1"`` -> ("blurred", 1.0) (the Gaussian's pixels; ``"blurred"``: 0, that is 1.5);
    ``"mm:2"`` -> ("mm", 2.0) (the step in millimetres; ``"mm"``: 0, that is 1); other families take no factor
    (0)."""
    from surfnorm.errors import InputError

    name, _, factor = text.partition(":")
    if name not in FAMILIES:
        raise InputError(f"--families: expected some of {', '.join(FAMILIES)}, got {text!r}")
    if name == "dropped":
        percent = _number(factor)
        if not 0.0 < percent <= 90.0:
            raise InputError(f"--families: expected dropped:H with H a percent above 0 and at most 90, got {text!r}")
        return name, percent
    if name in ("white", "correlated"):
        percent = _number(factor)
        if not 0.0 < percent <= 5.0:
            raise InputError(f"--families: expected {name}:P with P a percent above 0 and at most 5, got {text!r}")
        return name, percent
    if name == "mm" and factor:
        q = _number(factor)
        if not 0.0 < q <= 20.0:
            raise InputError(f"--families: expected mm:Q with Q millimetres above 0 and at most 20, got {text!r}")
        return name, q
    if name == "blurred" and factor:
        sigma = _number(factor)
        if not 0.0 < sigma <= 10.0:
            raise InputError(f"--families: expected blurred:S with S pixels above 0 and at most 10, got {text!r}")
        return name, sigma
    if not name.startswith("upsampled"):
        if factor:
            raise InputError(f"--families: {name} takes no factor, got {text!r}")
        return name, 0
    k = _number(factor)
    if not (2 <= k <= 16 and (2 * k).is_integer()):
        raise InputError(f"--families: expected {name}:K with K from 2 to 16, whole or halfway (7.5), got {text!r}")
    return name, int(k) if k.is_integer() else k


def sampled(n: int, k: float) -> np.ndarray:
    """The pixels of a side of n that a sensor of 1/k the resolution samples: floor((i + 0.5) k), the nearest to its
    pixel i's centre (i + 0.5) k - 0.5 (i k + k // 2 for a whole k)."""
    centres = (np.arange(math.ceil(n / k) + 1) + 0.5) * k
    return np.floor(centres[centres < n]).astype(np.int64)


def low_resolution(z: np.ndarray, k: float, rng) -> np.ndarray:
    """Every k-th pixel of ``z`` (0 where invalid; :func:`sampled`), with 0.4 % multiplicative noise: the sensor of 1/k
    resolution."""
    low = z[np.ix_(sampled(z.shape[0], k), sampled(z.shape[1], k))].astype(np.float32)
    return np.where(low > 0, low * (1.0 + 0.004 * rng.standard_normal(low.shape)), 0.0).astype(np.float32)


def resized(family: str, low: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The low sensor's depth ``low`` resized to the frame (``valid``'s shape) as ``family`` does it, 0 where the
    frame had no depth."""
    import cv2

    H, W = valid.shape
    interpolation = {
        "upsampled_linear": cv2.INTER_LINEAR,
        "upsampled_nearest": cv2.INTER_NEAREST,
        "upsampled_cubic": cv2.INTER_CUBIC,
    }[family]
    # the low pixel i sits at i k + k // 2; bilinear resizing puts it at (i + 0.5) k - 0.5: the same for odd k
    out = cv2.resize(low, (W, H), interpolation=interpolation)
    return np.where(valid & (out > 0), out, 0.0).astype(np.float32)


def _valid_mean(z: np.ndarray, valid: np.ndarray, blur) -> np.ndarray:
    """``blur`` (a linear filter) of the valid pixels' depth over the valid pixels only (normalised convolution:
    invalid pixels neither pull a mean towards 0 nor count)."""
    weight = blur(valid.astype(np.float32))
    return blur(np.where(valid, z, 0.0).astype(np.float32)) / np.maximum(weight, 1e-6)


def _disparity(z: np.ndarray, valid: np.ndarray, fb: float, error: np.ndarray, steps: int) -> np.ndarray:
    """The depth of a disparity matcher: fb / z plus ``error`` (pixels), rounded to 1 / ``steps`` of a pixel, back to
    depth (fb: focal length times baseline; 0 where invalid or where the disparity is not positive)."""
    d = np.round((fb / np.where(valid, z, 1.0) + error) * steps) / steps
    return np.where(valid & (d > 0), fb / np.where(d > 0, d, 1.0), 0.0)


def _mixed(z: np.ndarray, valid: np.ndarray, noisy: np.ndarray) -> np.ndarray:
    """``noisy`` with every pixel at a depth edge (its 3x3 mean off its depth by over 2 %) at that mean."""
    import cv2

    mean = _valid_mean(z, valid, lambda a: cv2.blur(a, (3, 3)))
    return np.where(np.abs(mean - z) > 0.02 * z, mean, noisy)


def _later(family: str, z: np.ndarray, valid: np.ndarray, rng, f: float) -> np.ndarray:
    """The families written later (see the module docstring), unmasked."""
    import cv2

    if family.startswith("scan_"):
        from surfnorm.bench.processing import inpainted, ipbasic_completed, scanlines

        samples = scanlines(z, valid, rng)
        return inpainted(samples) if family == "scan_inpaint" else ipbasic_completed(samples)
    if family == "float16":
        return z.astype(np.float16)
    if family == "disparity16_mm":
        depth = _disparity(z, valid, f * 0.05, 0.05 * rng.standard_normal(z.shape), 16)
        return np.round(depth * 1000.0) / 1000.0
    if family == "structured_light":
        window = cv2.blur(rng.standard_normal(z.shape).astype(np.float32), (9, 9))  # RMS 1/9
        return _disparity(z, valid, f * 0.075, 0.45 * window, 8)
    if family == "blocks":
        H, W = z.shape
        field = np.kron(rng.standard_normal(((H + 6) // 7, (W + 6) // 7)), np.ones((7, 7)))[:H, :W]
        return z * (1.0 + 0.003 * field)
    if family == "dropped_noisy":
        out = z * (1.0 + 0.002 * rng.standard_normal(z.shape))
        return np.where(rng.random(z.shape) < 0.05, 0.0, out)
    if family == "bilateral_mm":
        noisy = np.round(z * (1.0 + 0.002 * rng.standard_normal(z.shape)) * 1000.0) / 1000.0
        return cv2.bilateralFilter(np.where(valid, noisy, 0.0).astype(np.float32), 5, 0.02, 2.0)
    # tof_flying_mm
    noisy = z + (0.0015 + 0.001 * z) * rng.standard_normal(z.shape)
    return np.round(_mixed(z, valid, noisy) * 1000.0) / 1000.0


def degrade(family: str, k: float, z: np.ndarray, valid: np.ndarray, rng, f: float = 500.0) -> np.ndarray:
    """Depth ``z`` (metres, float32; ``valid``) as ``family`` delivers it (``k``: its factor, see
    :func:`parse_family`; ``f``: the focal length in pixels, for the disparity families): float32, 0 where it has
    none."""
    import cv2

    if family in FAMILIES[FAMILIES.index("float16") :]:
        out = _later(family, z, valid, rng, f)
    elif family.startswith("upsampled"):
        return resized(family, low_resolution(np.where(valid, z, 0.0), k, rng), valid)
    elif family == "median_mm":
        noisy = np.round(z * (1.0 + 0.002 * rng.standard_normal(z.shape)) * 1000.0) / 1000.0
        out = cv2.medianBlur(np.where(valid, noisy, 0.0).astype(np.float32), 5)
    elif family == "tof_mm":
        out = np.round((z + (0.002 + 0.001 * z) * rng.standard_normal(z.shape)) * 1000.0) / 1000.0
    elif family == "smooth_warp":
        field = cv2.GaussianBlur(rng.standard_normal(z.shape).astype(np.float32), (0, 0), 15.0)
        out = z * (1.0 + 0.002 * field / field.std())
    elif family == "white":
        out = z * (1.0 + 0.01 * k * rng.standard_normal(z.shape))
    elif family == "dropped":  # (k: the percent of pixels dropped)
        dropped = rng.random(z.shape) < 0.01 * k
        out = np.where(dropped, 0.0, z * (1.0 + 0.00005 * rng.standard_normal(z.shape)))
    elif family == "correlated":
        field = cv2.GaussianBlur(rng.standard_normal(z.shape).astype(np.float32), (0, 0), 1.0)
        out = z * (1.0 + 0.01 * k * field / field.std())
    elif family == "mm":  # (k: the step in millimetres; 0: 1)
        step = (k or 1.0) / 1000.0
        out = np.round(z / step) * step
    elif family == "outliers":
        out = z * (1.0 + 0.002 * rng.standard_normal(z.shape))
        out = np.where(rng.random(z.shape) < 0.01, z * rng.uniform(0.8, 1.2, z.shape), out)
    elif family == "bilateral":
        noisy = np.where(valid, z * (1.0 + 0.004 * rng.standard_normal(z.shape)), 0.0).astype(np.float32)
        out = cv2.bilateralFilter(noisy, 7, 0.03, 3.0)
    elif family == "flying":
        out = _mixed(z, valid, z * (1.0 + 0.002 * rng.standard_normal(z.shape)))
    else:  # blurred (k: the Gaussian's pixels; 0: 1.5)
        out = _valid_mean(z, valid, lambda a: cv2.GaussianBlur(a, (0, 0), k or 1.5))
    return np.where(valid & (out > 0), out, 0.0).astype(np.float32)


def native_camera(K: np.ndarray, k: float) -> np.ndarray:
    """The intrinsics of the 1/k sensor of :func:`low_resolution` (its pixel i is the frame's pixel i k + k // 2 for a
    whole k, (i + 0.5) k - 0.5 for one halfway between two)."""
    shift = k // 2 if float(k).is_integer() else k / 2 - 0.5
    Kn = np.array(K, np.float64)
    Kn[0, 0] /= k
    Kn[1, 1] /= k
    Kn[0, 2] = (K[0, 2] - shift) / k
    Kn[1, 2] = (K[1, 2] - shift) / k
    return Kn


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # before any peer library is imported
    import cv2

    from surfnorm import estimate
    from surfnorm.bench.scripts import script_entries, threef2n_root
    from surfnorm.bench.simulate import SENSORS, metres_per_unit
    from surfnorm.io.threef2n import find_frames, read_frame
    from surfnorm.metrics import mean_angular_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("root", nargs="?", default=None, help="3F2N frames; default tests/data/3f2n-sample")
    ap.add_argument("--families", default=DEFAULT, help=f"comma-separated among {', '.join(FAMILIES)}")
    ap.add_argument("--methods", default="auto,adaptive_fit,d2nt_v3,opencv_linemod_w5,opencv_fals_w5,open3d_knn30")
    ap.add_argument("--frames", type=int, default=None, help="the first N frames only")
    args = ap.parse_args(argv)
    got = script_entries("families", args.methods, lambda: [parse_family(f) for f in args.families.split(",")])
    if got is None:
        return 2
    families, entries = got
    root = threef2n_root(args.root, REPO)
    names = find_frames(root)[: args.frames]
    frames = [read_frame(root, name) for name in names]
    print("| family | " + " | ".join(e.label for e in entries) + " | auto (native) |")
    print("|" + "---|" * (len(entries) + 2))
    for family, k in families:
        errors: dict[str, list[float]] = {e.label: [] for e in entries}
        native: list[float] = []
        for i, frame in enumerate(frames):
            z = (frame.depth * metres_per_unit(frame.depth, SENSORS["kinect_v1"], frame.mask)).astype(np.float32)
            valid = np.isfinite(z) & (z > 0) & frame.mask  # the background: no depth, as the simulator's sensors
            z = np.where(valid, z, 0.0).astype(np.float32)
            low = None
            if family.startswith("upsampled"):  # made once: the frame resized from it, and the default on it
                low = low_resolution(z, k, np.random.default_rng(i))
                got = resized(family, low, valid)
            else:
                got = degrade(family, k, z, valid, np.random.default_rng(i), float(frame.K.matrix[0, 0]))
            scored = frame.mask & (got > 0)
            for e in entries:
                errors[e.label].append(mean_angular_error(e.normals(got, frame.K, got > 0), frame.normals, scored))
            if low is not None:
                n = estimate(low, native_camera(frame.K.matrix, k), threads=1)
                n = cv2.resize(n, z.shape[::-1], interpolation=cv2.INTER_NEAREST)
                native.append(mean_angular_error(n, frame.normals, scored))
        label = family + (f":{k:g}" if k else "")
        cells = [f"{np.mean(v):.2f}" for v in errors.values()] + [f"{np.mean(native):.2f}" if native else "-"]
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
