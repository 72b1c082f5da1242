"""Turning a :class:`~surfnorm.bench.runner.BenchResult` into report.md, results.json and the figures."""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np

from ..io._atomic import atomic_write
from ..reference import official_figures
from . import paper
from .runner import DLFS, NOISE_METHODS, SLOW_MS, SLOW_REPEATS, BenchResult

__all__ = ["summarise", "write_report", "table3_rows"]


# ---------------------------------------------------------------------------- aggregates


def _levels(result: BenchResult) -> list[str]:
    present = {f.split("/")[0] for f in result.frames if f not in result.unreadable}
    return [lv for lv in paper.LEVELS if lv in present]


def summarise(result: BenchResult) -> dict:
    """Per spec key: e_A per level (mean of the frames' e_A), frame counts, and t (median of the frames' medians)."""
    out: dict[str, dict] = {}
    for rec in result.accuracy:
        if rec["frame"] in result.unreadable:
            continue
        entry = out.setdefault(rec["key"], {"e_a": {}, "frames": {}, "coverage": {}, "errors": 0})
        if "error" in rec or rec.get("e_a") is None or not math.isfinite(rec["e_a"]):
            entry["errors"] += 1
            continue
        entry["e_a"].setdefault(rec["level"], []).append(rec["e_a"])
        entry["coverage"].setdefault(rec["level"], []).append(rec["coverage"])
    for entry in out.values():
        entry["frames"] = {lv: len(v) for lv, v in entry["e_a"].items()}
        entry["coverage"] = {lv: float(np.mean(v)) for lv, v in entry["coverage"].items()}
        entry["e_a"] = {lv: float(np.mean(v)) for lv, v in entry["e_a"].items()}
    for rec in result.timing:
        if "ms" in rec:
            out.setdefault(rec["key"], {"e_a": {}, "frames": {}, "coverage": {}, "errors": 0}).setdefault(
                "ms_frames", []
            ).append(rec["ms"])
    for entry in out.values():
        frames_ms = entry.pop("ms_frames", [])
        entry["t_ms"] = float(np.median(frames_ms)) if frames_ms else None
    return out


def _official(result: BenchResult, method: str, levels) -> dict[str, float]:
    """The authors' code's e_A on the same frames (shipped JSON), per level, where every frame has a figure."""
    out = {}
    for lv in levels:
        frames = [f for f in result.frames if f.startswith(lv + "/") and f not in result.unreadable]
        vals = [official_figures(f).get(method) for f in frames]
        if frames and all(v is not None for v in vals):
            out[lv] = float(np.mean([v for v in vals if v is not None]))
    return out


def _reference(result: BenchResult, label: str, key: str, levels) -> dict[str, float]:
    if not key.startswith("peer:"):
        return _official(result, label, levels)
    if label in paper.PEER_OFFICIAL:
        return _official(result, paper.PEER_OFFICIAL[label], levels)
    ref = paper.PEERS_REFERENCE.get(label)
    # peers.md is per level over all 12 sample frames: comparable only when all of them are evaluated
    frames = [f for f in result.frames if f not in result.unreadable]
    if ref is None or len(frames) != 12 or not all(official_figures(f) for f in frames):
        return {}
    return {lv: v for lv, v in zip(paper.LEVELS, ref[0]) if lv in levels}


def table3_rows(result: BenchResult, summary: dict) -> list[dict]:
    levels = _levels(result)
    rows = []
    for label, key in result.experiments["table3"].items():
        s = summary.get(key, {})
        t = s.get("t_ms")
        e_a = {lv: s.get("e_a", {}).get(lv) for lv in levels}
        rows.append(
            {
                "method": label,
                "peer": key.startswith("peer:"),
                "real_time": None if t is None else t < paper.REAL_TIME_MS,
                "t_ms": t,
                "e_a": e_a,
                "pi": {lv: (None if t is None or e_a[lv] is None else e_a[lv] * t) for lv in levels},
                "coverage": s.get("coverage", {}),
                "paper": paper.TABLE_III.get(paper.PAPER_NAME.get(label, "")),
                "paper_name": paper.PAPER_NAME.get(label),
                "on_these_frames": _reference(result, label, key, levels),
                "reference_ms": paper.PEERS_REFERENCE.get(label, (None, None))[1],
            }
        )
    return rows


# ---------------------------------------------------------------------------- markdown


def _f(v, digits=2) -> str:
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{digits}f}"


def _t(v) -> str:
    return "–" if v is None else (f"{v:.2f}" if v < 10 else f"{v:.1f}" if v < 100 else f"{v:.0f}")


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _e(summary, key, lv):
    return summary.get(key, {}).get("e_a", {}).get(lv)


def _markdown(result: BenchResult, summary: dict, meta: dict) -> str:
    levels = _levels(result)
    lvi = [paper.LEVELS.index(lv) for lv in levels]
    n_frames = {
        lv: sum(1 for f in result.frames if f.startswith(lv + "/") and f not in result.unreadable) for lv in levels
    }
    out = ["# surfnorm bench report", ""]
    out.append(
        f"Dataset: `{result.config['root']}`, {sum(n_frames.values())} frames evaluated "
        f"({', '.join(f'{lv} {n}' for lv, n in n_frames.items())}). "
        f"e_A: mean folded angular error in degrees over the object's pixels (depth != 1), averaged over the "
        f"frames of a level. Figures in brackets are the paper's (full 3F2N dataset, its machine), "
        f"so on a sample they agree only roughly."
    )
    out.append("")
    out.append(
        f"surfnorm {meta['surfnorm']} (commit {meta['git_commit'] or 'unknown'}), Python {meta['python']}, "
        f"CPU: {meta['cpu']} ({meta['cpu_count']} logical cores), timing setup: {meta['threads']}."
    )
    out.append("")
    if result.unreadable:
        out += ["## Frames not evaluated", ""]
        out += [f"- `{name}`: {why}" for name, why in result.unreadable.items()]
        out.append("")
    if result.skipped:
        out += ["## Skipped", ""]
        out += [f"- {name}: {why}" for name, why in result.skipped.items()]
        out.append("")

    tables = result.config["tables"]
    # Table III
    if "table3" in tables:
        out += _table3_md(result, summary, levels, lvi)
    if result.experiments.get("faithfulness"):
        out += _faithfulness_md(result, levels)
    if "table2" in tables:
        out += _table2_md(result, summary, levels, lvi)
    if "table4" in tables:
        out += _table4_md(result, summary, levels, lvi)
    if "noise" in tables:
        out += _noise_md(result, summary, levels)
    figs = []
    if "table3" in tables:
        figs.append("- `fig1_tradeoff.png`: e_A against t (log time axis), one point per method and level (Fig. 1).")
    if "noise" in tables:
        figs.append(
            "- `fig3_noise.png`: e_A of the three D2NT versions against the noise's standard deviation, per level (Fig. 3)."
        )
    if "fig4" in tables:
        figs.append(
            f"- `fig4_panel.png`: depth, ground truth and error maps of 3F2N, CP2TV and D2NT V3 on "
            f"`{meta.get('panel_frame')}`, one colour scale (Fig. 4)."
        )
    if figs:
        out += ["## Figures", ""] + figs + [""]
    return "\n".join(out)


def _table3_md(result, summary, levels, lvi) -> list[str]:
    out = [
        "## Table III: speed, accuracy and trade-off",
        "",
        f"t: median over frames of the median of repeated warm calls on one frame, one thread, in ms "
        f"(methods interleaved; slow methods, over {SLOW_MS:g} ms, get {SLOW_REPEATS} calls). Real-time (RT): "
        f"t < 1000/30 ms (30 frames per second). pi = e_A x t (degrees/kHz). In brackets: the paper's figure "
        f"(full dataset, its machine), or for peers the one-thread time in peers.md. Last column: the same "
        f"estimator's e_A per level on these frames as measured with its authors' code (JSON shipped with "
        f"surfnorm), or for the other peers in peers.md (shown only when the 12 sample frames are evaluated; "
        f"peers.md used the 1-based principal point of params.txt as is, which moves e_A by up to 0.05). "
        f"The paper's pi are shown as printed, though two do not equal its e_A x t: D2NT Easy (3.05, not 2.80) "
        f"and D2NT V2 (computed with t = 7.1 ms, not the 7.80 printed).",
        "",
    ]
    header = (
        ["RT", "method", "t (ms)"]
        + [f"e_A {lv}" for lv in levels]
        + [f"pi {lv}" for lv in levels]
        + ["reference on these frames"]
    )
    rows = []
    for r in table3_rows(result, summary):
        p = r["paper"]
        rt = "–" if r["real_time"] is None else ("Y" if r["real_time"] else "N")
        if p:
            rt += f" [{'Y' if p[0] else 'N'}]"
        name = r["method"] + (f" ({r['paper_name']})" if r["paper_name"] else "") + (" — peer" if r["peer"] else "")
        t = (
            _t(r["t_ms"])
            + (f" [{p[1]:.2f}]" if p else "")
            + (f" [peers.md {r['reference_ms']:g}]" if r["reference_ms"] else "")
        )
        cells = [rt, name, t]
        cells += [_f(r["e_a"][lv]) + (f" [{p[2][i]:.2f}]" if p else "") for lv, i in zip(levels, lvi)]
        cells += [_f(r["pi"][lv]) + (f" [{p[3][i]:.2f}]" if p else "") for lv, i in zip(levels, lvi)]
        ref = r["on_these_frames"]
        cells.append(" / ".join(_f(ref.get(lv)) for lv in levels) if ref else "–")
        rows.append(cells)
    out += [_table(header, rows), ""]
    return out


def _faithfulness_md(result, levels) -> list[str]:
    """Our D2NT family against the authors' figures (shipped JSON) on the frames that have them."""
    rows = []
    for name, key in result.experiments["faithfulness"].items():
        ours = {
            r["frame"]: r.get("e_a") for r in result.accuracy if r["key"] == key and r["frame"] not in result.unreadable
        }
        pairs = [(f, e, official_figures(f).get(name)) for f, e in ours.items()]
        pairs = [(f, e, o) for f, e, o in pairs if e is not None and o is not None]
        if not pairs:
            continue
        cells = [name + (" (border=reflect, as the authors' FD)" if name == "d2nt_basic" else "")]
        for lv in levels:
            sel = [(e, o) for f, e, o in pairs if f.startswith(lv + "/")]
            cells.append(f"{np.mean([e for e, _ in sel]):.4f} / {np.mean([o for _, o in sel]):.4f}" if sel else "–")
        cells.append(f"{max(abs(e - o) for _, e, o in pairs):.4f}")
        peer = next((p for p, m in paper.PEER_OFFICIAL.items() if m == name), None)
        live = {
            r["frame"]: r.get("e_a")
            for r in result.accuracy
            if r["key"] == result.experiments["table3"].get(peer, "") and r.get("e_a") is not None
        }
        diffs = [abs(e - live[f]) for f, e in ours.items() if e is not None and f in live]
        cells.append(f"{max(diffs):.1e}" if diffs else "– (peer not run)")
        cells.append(str(len(pairs)))
        rows.append(cells)
    if not rows:
        return []
    return [
        "## The D2NT family against the authors' code on these frames",
        "",
        "e_A per level, ours / the authors' d2nt 0.1.3 (figures shipped with surfnorm, "
        "`surfnorm.reference.official_figures`), the largest difference on one frame, in degrees, and the "
        "largest difference on one frame from the same package run live in this bench (the d2nt peer).",
        "",
        _table(
            ["method"]
            + [f"{lv} ours / authors" for lv in levels]
            + ["max abs. diff. per frame", "max abs. diff. vs the d2nt peer", "frames"],
            rows,
        ),
        "",
    ]


def _table2_md(result, summary, levels, lvi) -> list[str]:
    out = []
    t2 = result.experiments["table2"]
    if t2:
        out += [
            "## Table II: the four discrete Laplace filters (DLF)",
            "",
            "D2NT+DAG: `d2nt_v2` with the DAG filter's DLF = X. D2NT+MNR: our reading is D2NT with finite-difference "
            "gradients followed by MNR whose smoothness uses DLF X (`d2nt_basic+mnr`, `mnr_dlf=X`): Table II is an "
            "ablation of each module on its own, and D2NT V3 (DAG 1D + MNR) in Table III (0.89/4.78/9.86) matches "
            "none of the D2NT+MNR rows, so that column is not DAG followed by MNR. For comparison, the last column "
            "group is DAG (1D) followed by MNR with DLF X (`d2nt_v3`, `mnr_dlf=X`). The paper's DLF-gamma row is the "
            "same in both of its columns, which looks like a copying slip in the paper.",
            "",
        ]
        groups = [g for g in ("D2NT+DAG", "D2NT+MNR", "D2NT+DAG+MNR") if any(k.startswith(g + "/") for k in t2)]
        header = ["DLF"] + [f"{g} {lv}" for g in groups for lv in levels]
        rows = []
        for d in DLFS:
            cells = [d]
            for g in groups:
                key = t2.get(f"{g}/{d}")
                pp = paper.TABLE_II.get(g, {}).get(d)
                cells += [_f(_e(summary, key, lv)) + (f" [{pp[i]:.2f}]" if pp else "") for lv, i in zip(levels, lvi)]
            rows.append(cells)
        out += [_table(header, rows), ""]
    else:
        out += ["## Table II", "", "(d2nt_basic, d2nt_v2, d2nt_v3 are not registered: nothing to measure.)", ""]
    return out


def _table4_md(result, summary, levels, lvi) -> list[str]:
    t4 = result.experiments["table4"]
    out = [
        "## Table IV: MNR after 3F2N and CP2TV",
        "",
        "3F2N is `3f2n_median` (the 3F2N paper's default aggregation); improvement = (w/o - w/) / w/o. "
        "The paper's CP2TV improvements (40.8 / 15.0 / 35.6 %) do not follow from its own e_A "
        "(which give 46.2 / 20.3 / 28.7 %); they are shown as printed.",
        "",
    ]
    header = ["config"] + [f"{m} {lv}" for m in paper.TABLE_IV for lv in levels]
    rows = []
    for cfg_name in ("w/o MNR", "w/ MNR", "improvement"):
        cells = [cfg_name]
        for m in paper.TABLE_IV:
            pp = paper.TABLE_IV[m][cfg_name]
            for lv, i in zip(levels, lvi):
                wo, w = _e(summary, t4.get(f"{m}/w/o MNR"), lv), _e(summary, t4.get(f"{m}/w/ MNR"), lv)
                if cfg_name == "improvement":
                    v = None if wo is None or w is None or wo == 0 else 100.0 * (wo - w) / wo
                    cells.append((_f(v, 1) + "%" if v is not None else "–") + f" [{pp[i]:.1f}%]")
                else:
                    cells.append(_f(w if cfg_name == "w/ MNR" else wo) + f" [{pp[i]:.2f}]")
        rows.append(cells)
    out += [_table(header, rows), ""]
    if not t4:
        out += ["(3f2n_median and cp2tv are not registered in this build: nothing to measure.)", ""]
    return out


def _noise_md(result, summary, levels) -> list[str]:
    noise = result.experiments["noise"]
    out = [
        "## Fig. 3: robustness to Gaussian noise",
        "",
        f"Zero-mean Gaussian noise of standard deviation sigma (depth units; the objects are 20-30 units away, "
        f"neighbouring pixels about 0.02 apart) added to the object's depth (background kept), seeded "
        f"(seed {result.config['seed']}, per frame and sigma, the same noise for the three versions). The paper "
        f"gives this study only as a figure without numbers, so there is nothing to print beside ours. "
        f"Figure: `fig3_noise.png`.",
        "",
    ]
    stds = list(dict.fromkeys(k.split("/", 1)[1] for k in noise))
    header = ["method", "level"] + [f"sigma {s}" for s in stds]
    rows = []
    for m in NOISE_METHODS:
        for lv in levels:
            if f"{m}/{stds[0] if stds else ''}" in noise:
                rows.append([m, lv] + [_f(_e(summary, noise.get(f"{m}/{s}"), lv)) for s in stds])
    out += [_table(header, rows) if rows else "(no D2NT method registered)", ""]
    return out


# ---------------------------------------------------------------------------- machine


def machine_meta(result: BenchResult) -> dict:
    import cv2
    import numba

    from .. import __version__
    from .peers import peer_versions

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = (
            subprocess.run(
                ["git", "rev-parse", "HEAD"],
                cwd=Path(__file__).resolve().parent,
                capture_output=True,
                text=True,
                timeout=10,
            ).stdout.strip()
            or None
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--", "."],
            cwd=Path(__file__).resolve().parents[1],
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
        if commit and dirty:
            commit += "+dirty"
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {
        "surfnorm": __version__,
        "git_commit": commit,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "opencv": cv2.__version__,
        "peers": peer_versions(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "threads": ", ".join(f"{k}={v}" for k, v in result.meta.get("threads", {}).items()),
        "jobs": result.meta.get("jobs"),
        "code_version": result.meta.get("code_version"),
        "stages": result.meta.get("stages"),
    }


def write_report(result: BenchResult, out_dir, *, elapsed_s: float | None = None) -> dict[str, Path]:
    """Write report.md, results.json and the PNG figures into ``out_dir``. Returns their paths by name."""
    from . import figures

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = summarise(result)
    meta = machine_meta(result)
    meta["elapsed_s"] = elapsed_s
    paths = {}
    tables = result.config["tables"]
    if "table3" in tables:
        paths["fig1"] = figures.tradeoff(out_dir / "fig1_tradeoff.png", table3_rows(result, summary), _levels(result))
    if "noise" in tables:
        paths["fig3"] = figures.noise(out_dir / "fig3_noise.png", result, summary, _levels(result))
    if "fig4" in tables:
        paths["fig4"], meta["panel_frame"] = figures.panel(out_dir / "fig4_panel.png", result)
    text = _markdown(result, summary, meta)
    if elapsed_s is not None:
        text += f"\nRun time: {elapsed_s:.0f} s in all (cached results reused where present)"
        stages = meta.get("stages") or {}
        if stages:
            text += "; " + ", ".join(
                f"{k} {v['wall_s']:.0f} s wall / {v['cpu_s']:.0f} s CPU" for k, v in stages.items()
            )
        text += ".\n"
    paths["report"] = atomic_write(out_dir / "report.md", lambda tmp: tmp.write_text(text))
    doc = {
        "meta": meta,
        "config": result.config,
        "frames": result.frames,
        "unreadable": result.unreadable,
        "skipped": result.skipped,
        "experiments": result.experiments,
        "summary": summary,
        "table3": table3_rows(result, summary),
        "accuracy": result.accuracy,
        "timing": result.timing,
    }
    paths["results"] = atomic_write(
        out_dir / "results.json", lambda tmp: tmp.write_text(json.dumps(_finite(doc), indent=1, allow_nan=False))
    )
    return paths


def _finite(obj):
    """JSON has no NaN: non-finite numbers become null; NumPy scalars become Python numbers."""
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
