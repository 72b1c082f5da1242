"""The report's figures as PNG (Matplotlib, Agg backend): Fig. 1 trade-off, Fig. 3 noise curves, Fig. 4 panel."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io._atomic import atomic_write
from . import paper

__all__ = ["tradeoff", "noise", "panel", "PANEL_METHODS", "PANEL_VMAX"]

#: The error maps of the Fig. 4-style panel (surfnorm names, paper names).
PANEL_METHODS = (("3f2n_median", "3F2N"), ("cp2tv", "CP2TV"), ("d2nt_v3", "D2NT V3"))
#: Top of the panel's shared error colour scale, in degrees (larger errors are drawn at this colour).
PANEL_VMAX = 30.0
LEVEL_MARKERS = {"Easy": "o", "Medium": "s", "Hard": "^"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    plt = _plt()

    def write(tmp: Path):
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")

    try:
        return atomic_write(path, write)
    finally:
        plt.close(fig)


def tradeoff(path, rows: list[dict], levels: list[str]) -> Path:
    """Fig. 1: e_A against t (log axis), one point per method and level; marker = level, colour = method."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 6))
    cmap = plt.get_cmap("tab20")
    plotted = [r for r in rows if r["t_ms"] is not None and any(r["e_a"].get(lv) is not None for lv in levels)]
    for i, r in enumerate(plotted):
        colour = cmap(i % 20)
        for lv in levels:
            if r["e_a"].get(lv) is not None:
                ax.scatter(
                    r["t_ms"],
                    r["e_a"][lv],
                    marker=LEVEL_MARKERS[lv],
                    color=colour,
                    s=46,
                    edgecolors="black" if not r["peer"] else colour,
                    linewidths=0.6,
                    facecolors=colour if not r["peer"] else "none",
                )
        ax.scatter(
            [],
            [],
            marker="o",
            color=colour,
            facecolors=colour if not r["peer"] else "none",
            label=r["method"] + (" (peer)" if r["peer"] else ""),
        )
    for lv in levels:
        ax.scatter([], [], marker=LEVEL_MARKERS[lv], color="grey", label=f"level: {lv}")
    ax.axvline(paper.REAL_TIME_MS, color="grey", linestyle="--", linewidth=1)
    ax.text(paper.REAL_TIME_MS, ax.get_ylim()[1] if plotted else 1, " 30 fps", color="grey", va="top", fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("t: median ms per 480x640 frame, one thread (log scale)")
    ax.set_ylabel("e_A (degrees)")
    ax.set_title(
        "Fig. 1 (regenerated): accuracy against time, one point per method and level\n"
        "lower left is better; hollow markers: peers"
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    return _save(fig, Path(path))


def noise(path, result, summary: dict, levels: list[str]) -> Path:
    """Fig. 3: e_A of d2nt_basic / v2 / v3 against the noise's standard deviation, one panel per level."""
    plt = _plt()
    table = result.experiments["noise"]
    fig, axes = plt.subplots(1, max(len(levels), 1), figsize=(4.2 * max(len(levels), 1), 3.6), squeeze=False)
    for ax, lv in zip(axes[0], levels):
        for method, style in (("d2nt_basic", "o-"), ("d2nt_v2", "s-"), ("d2nt_v3", "^-")):
            pts = [
                (float(label.split("/", 1)[1]), summary.get(key, {}).get("e_a", {}).get(lv))
                for label, key in table.items()
                if label.split("/", 1)[0] == method
            ]
            pts = [(s, e) for s, e in pts if e is not None]
            if pts:
                xs, ys = zip(*sorted(pts))
                ax.plot(xs, ys, style, label=method, markersize=5)
        ax.set_title(f"{lv}")
        ax.set_xlabel("noise standard deviation (depth units)")
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("e_A (degrees)")
    axes[0][0].legend(fontsize=8)
    fig.suptitle(
        f"Fig. 3 (regenerated): D2NT versions under zero-mean Gaussian depth noise (seed {result.config['seed']})"
    )
    fig.tight_layout()
    return _save(fig, Path(path))


def _panel_frame(result) -> str | None:
    ok = [f for f in result.frames if f not in result.unreadable]
    if result.config.get("panel_frame") in ok:
        return result.config["panel_frame"]
    from ..io.threef2n import read_frame

    for lv in reversed(paper.LEVELS):  # the hardest level present
        firsts: dict = {}
        for f in ok:
            if f.startswith(lv + "/"):
                firsts.setdefault(f.rsplit("/", 1)[0], f)  # the first frame of each object
        if firsts:
            # the object that fills most of its frame, so that the panel shows detail rather than white space
            def area(name):
                rows, cols = _bbox(read_frame(result.config["root"], name).mask)
                return (rows.stop or 0) - (rows.start or 0), (cols.stop or 0) - (cols.start or 0)

            return max(firsts.values(), key=lambda f: min(area(f)))
    return None


def _bbox(mask: np.ndarray, margin: int = 8):
    """Slices of the mask's bounding box with a margin (the whole image when the mask is empty)."""
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return (slice(None), slice(None))
    H, W = mask.shape
    return (
        slice(max(rows.min() - margin, 0), min(rows.max() + margin + 1, H)),
        slice(max(cols.min() - margin, 0), min(cols.max() + margin + 1, W)),
    )


def panel(path, result) -> tuple[Path, str | None]:
    """Fig. 4-style panel on one frame: depth, ground truth, error maps of 3F2N, CP2TV, D2NT V3 (one colour scale)."""
    from .. import metrics
    from .._api import estimate
    from ..io.pictures import normal_to_rgb8
    from ..io.threef2n import read_frame
    from ..methods import methods

    plt = _plt()
    name = _panel_frame(result)
    fig, axes = plt.subplots(
        1, 2 + len(PANEL_METHODS), figsize=(3.6 * (2 + len(PANEL_METHODS)), 3.8), layout="constrained"
    )
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    if name is None:
        axes[0].text(0.5, 0.5, "no readable frame", ha="center", transform=axes[0].transAxes)
        return _save(fig, Path(path)), None
    frame = read_frame(result.config["root"], name)
    crop = _bbox(frame.mask)
    depth = np.where(frame.mask, frame.depth, np.nan)[crop]
    im = axes[0].imshow(depth, cmap="viridis")
    axes[0].set_title("depth (object)")
    fig.colorbar(im, ax=axes[0], fraction=0.046, pad=0.02)
    axes[1].imshow(normal_to_rgb8(np.where(frame.mask[..., None], frame.normals, 0))[crop])
    axes[1].set_title("ground truth normals")
    registered = methods()
    err_im = None
    for ax, (method, label) in zip(axes[2:], PANEL_METHODS):
        if method not in registered:
            ax.imshow(np.full(depth.shape, np.nan), cmap="inferno", vmin=0.0, vmax=PANEL_VMAX)
            ax.text(0.5, 0.5, f"{method}\nnot registered", ha="center", va="center", transform=ax.transAxes)
            ax.set_title(label)
            continue
        n = estimate(frame.depth, frame.K, method=method)
        err = metrics.angular_error(n, frame.normals)
        err[~frame.mask] = np.nan
        err_im = ax.imshow(err[crop], cmap="inferno", vmin=0.0, vmax=PANEL_VMAX)
        ax.set_title(
            f"{label} error\ne_A {metrics.mean_angular_error(n, frame.normals, frame.mask):.2f} deg", fontsize=10
        )
    if err_im is not None:
        fig.colorbar(
            err_im,
            ax=list(axes[2:]),
            fraction=0.02,
            pad=0.01,
            label=f"angular error (degrees, clipped at {PANEL_VMAX:g})",
        )
    fig.suptitle(
        f"Fig. 4 (regenerated): {name}, cropped to the object; black = small error, yellow = 30 degrees or more"
    )
    return _save(fig, Path(path)), name
