"""How well ``estimate(..., uncertainty=True)``'s sigma predicts the error: calibration and sparsification.

* :func:`calibration`: on the simulated sensors (:mod:`surfnorm.bench.simulate`, exact ground truth), pixels
  pooled over the 3F2N frames are sorted by their predicted sigma and split into deciles; each decile's RMS
  actual error over its mean sigma is 1 for a calibrated sigma. ``overall`` is the RMS error over the RMS sigma
  of all pixels.
* :func:`sparsification`: on real frames (the sensor sample's layout, angle to the reference planes), the mean
  error of the x % most confident pixels, beside the oracle that keeps the x % with the smallest true error,
  and the rank (Spearman) correlation between sigma and the error.

Two 3F2N frames are left out of the calibration by default (``SKIP``): their ground-truth normals disagree
with their own depth by 4-5 degrees on every plane, by a focal length that is not the one their intrinsics
give (on exact depth, ``d2nt_v3``'s median error is 5.1 degrees on ``Hard/room`` and 4.5 on ``Medium/chair``;
with fx and fy times 0.8 and 1.25 respectively it is 0.4 and 1.2). No depth-based sigma can see that.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..metrics import angular_error

#: 3F2N frames whose ground truth does not match their depth (see the module docstring).
SKIP = ("Hard/room", "Medium/chair")
#: Shares of the most confident pixels on the sparsification curve.
SHARES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


def deciles(error: np.ndarray, sigma: np.ndarray, bins: int = 10) -> list[dict]:
    """Pixels sorted by sigma, in ``bins`` groups of equal count: each group's mean sigma, RMS error, their ratio."""
    order = np.argsort(sigma, kind="stable")
    out = []
    for b in np.array_split(order, bins):
        mean_sigma = float(np.mean(sigma[b]))
        rms = float(math.sqrt(np.mean(np.square(error[b]))))
        out.append({"sigma": mean_sigma, "rms_error": rms, "ratio": rms / mean_sigma, "pixels": int(b.size)})
    return out


def calibration_frames(root=None, skip=SKIP) -> list[str]:
    """The 3F2N frames under ``root`` (default: the sample shipped in the package) that :func:`calibration` uses:
    all but ``skip``; InputError (naming ``dataset``, the command line's argument) where there are none."""
    from ..io.threef2n import find_frames, sample_root

    root = sample_root() if root is None else root
    names = [n for n in find_frames(root) if not any(n.startswith(s + "/") for s in skip)]
    if not names:
        raise InputError(
            f"dataset: expected 3F2N frames (Easy|Medium|Hard/<object>/depth/*.bin) for the calibration of sigma, "
            f"found none under {root}" + (f" but {', '.join(skip)}" if skip else "")
        )
    return names


def calibration(root=None, sensors=None, *, method: str = "auto", skip=SKIP, seed: int = 0) -> dict:
    """Calibration of sigma on every simulated sensor (``sensors``: default all) over the 3F2N frames under
    ``root`` (default: the sample shipped in the package) but ``skip``. Returns {sensor: {"deciles", "overall",
    "within": deciles with a ratio in 0.67-1.5, "pixels"}}."""
    from .._api import estimate
    from ..io.threef2n import read_frame, sample_root
    from .simulate import SENSORS, frame_seed, simulate

    root = sample_root() if root is None else root
    names = calibration_frames(root, skip)
    result = {}
    for s in sensors or list(SENSORS):
        errors, sigmas = [], []
        for name in names:
            fr = read_frame(root, name)
            z = simulate(fr.depth, fr.K, s, seed=frame_seed(seed, name, s), mask=fr.mask, normals=fr.normals)
            n, sigma = estimate(z, fr.K, method=method, uncertainty=True, threads=1)
            m = fr.mask & (z > 0) & np.isfinite(sigma)
            errors.append(angular_error(n, fr.normals)[m])
            sigmas.append(sigma[m].astype(np.float64))
        e, g = np.concatenate(errors), np.concatenate(sigmas)
        d = deciles(e, g)
        result[s] = {
            "deciles": d,
            "overall": float(math.sqrt(np.mean(e * e)) / math.sqrt(np.mean(g * g))),
            "within": sum(0.67 <= x["ratio"] <= 1.5 for x in d),
            "pixels": int(e.size),
        }
    return {"method": method, "frames": names, "skipped": list(skip), "sensors": result}


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 0 .. n-1, ties given their mean rank."""
    order = np.argsort(x, kind="stable")
    r = np.empty(x.size)
    r[order] = np.arange(x.size)
    values, inverse = np.unique(x, return_inverse=True)
    if values.size < x.size:
        sums = np.bincount(inverse, weights=r)
        counts = np.bincount(inverse)
        r = (sums / counts)[inverse]
    return r


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation (Pearson's of the ranks, ties at their mean rank)."""
    ra, rb = _ranks(np.asarray(a, np.float64)), _ranks(np.asarray(b, np.float64))
    ra -= ra.mean()
    rb -= rb.mean()
    return float(np.sum(ra * rb) / math.sqrt(np.sum(ra * ra) * np.sum(rb * rb)))


def plane_pixel_errors(normals: np.ndarray, frame) -> tuple[np.ndarray, np.ndarray]:
    """(error in degrees, flat index) of every reference-plane pixel of a sensor frame with a normal (gt.npy's
    pixels for a rendered frame)."""
    if frame.planes is None:
        err = angular_error(normals, frame.gt)
        m = np.isfinite(err)
        return err[m], np.flatnonzero(m)
    errs, idx = [], []
    for pn, pm in zip(*frame.planes):
        err = angular_error(normals, np.broadcast_to(pn, normals.shape))
        m = pm & np.isfinite(err)
        errs.append(err[m])
        idx.append(np.flatnonzero(m))
    return np.concatenate(errs), np.concatenate(idx)


def sparsification(frames, *, method: str = "auto") -> dict:
    """Per real frame of ``frames`` (:class:`surfnorm.bench.sensor.SensorFrame`): the sparsification curve (mean error of the most confident ``SHARES``),
    the oracle's, their ratio to the mean over all at 50 %, and Spearman's rank correlation of sigma and error."""
    from .._api import estimate

    result = {}
    for fr in frames:
        n, sigma = estimate(fr.depth, fr.K, method=method, uncertainty=True)
        e, idx = plane_pixel_errors(n, fr)
        g = sigma.reshape(-1)[idx].astype(np.float64)
        by_sigma = e[np.argsort(g, kind="stable")]
        by_error = np.sort(e)
        curve = [float(by_sigma[: max(1, round(s * e.size))].mean()) for s in SHARES]
        oracle = [float(by_error[: max(1, round(s * e.size))].mean()) for s in SHARES]
        half = SHARES.index(0.5)
        result[fr.name] = {
            "curve": curve,
            "oracle": oracle,
            "half": curve[half] / curve[-1],
            "oracle_half": oracle[half] / oracle[-1],
            "spearman": spearman(g, e),
            "pixels": int(e.size),
        }
    return {"method": method, "shares": list(SHARES), "frames": result}


def markdown(cal: dict | None, spars: dict | None) -> str:
    """The report's section on sigma."""
    lines = ["## Uncertainty (`estimate(..., uncertainty=True)`)", ""]
    if cal is not None:
        lines += [
            f"Calibration on the simulated sensors ({len(cal['frames'])} 3F2N frames; left out: "
            f"{', '.join(cal['skipped']) or 'none'}, whose ground truth does not match their depth). Per decile of "
            "predicted sigma: RMS actual error / mean sigma (1 is calibrated; the target band is 0.67-1.5). "
            "Overall: RMS error / RMS sigma.",
            "",
            "| sensor | " + " | ".join(f"d{i + 1}" for i in range(10)) + " | within | overall |",
            "|---" * 13 + "|",
        ]
        for s, r in cal["sensors"].items():
            cells = " | ".join(f"{d['ratio']:.2f}" for d in r["deciles"])
            lines.append(f"| {s} | {cells} | {r['within']}/10 | {r['overall']:.2f} |")
        lines.append("")
    if spars is not None:
        lines += [
            "Sparsification on the real frames: mean error of the 50 % most confident pixels over the mean of all "
            "(the oracle keeps the 50 % with the smallest true error), and Spearman's rank correlation of sigma "
            "and the error.",
            "",
            "| frame | pixels | mean error, all | 50 % most confident | ratio | oracle ratio | rank correlation |",
            "|---|---|---|---|---|---|---|",
        ]
        half = spars["shares"].index(0.5)
        for name, r in spars["frames"].items():
            lines.append(
                f"| {name} | {r['pixels']} | {r['curve'][-1]:.2f} | {r['curve'][half]:.2f} | {r['half']:.2f} | "
                f"{r['oracle_half']:.2f} | {r['spearman']:.2f} |"
            )
        lines.append("")
    return "\n".join(lines)


def figure(path, cal: dict | None, spars: dict | None) -> Path:
    """Calibration (RMS error against mean sigma per decile, per sensor) and sparsification curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    ax = axes[0]
    if cal is not None:
        top = 1.0
        for s, r in cal["sensors"].items():
            x = [d["sigma"] for d in r["deciles"]]
            y = [d["rms_error"] for d in r["deciles"]]
            top = max(top, max(x), max(y))
            ax.plot(x, y, "o-", ms=3, lw=1, label=s)
        t = np.array([0.1, top * 1.2])
        ax.plot(t, t, "k-", lw=0.8)
        ax.fill_between(t, 0.67 * t, 1.5 * t, color="0.85", zorder=0)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("mean predicted sigma of the decile (degrees)")
        ax.set_ylabel("RMS actual error (degrees)")
        ax.set_title("Calibration on the simulated sensors", fontsize=9)
        ax.legend(fontsize=6)
    ax = axes[1]
    if spars is not None:
        shares = [100 * s for s in spars["shares"]]
        for name, r in spars["frames"].items():
            (line,) = ax.plot(shares, r["curve"], "-", lw=1.2, label=name)
            ax.plot(shares, r["oracle"], ":", lw=1, color=line.get_color())
        ax.set_xlabel("share of the pixels kept, most confident first (%)")
        ax.set_ylabel("mean error of those kept (degrees)")
        ax.set_title("Sparsification on the real frames (dotted: oracle)", fontsize=9)
        ax.legend(fontsize=6)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
