"""The ``surfnorm`` command line: each command maps options to one library call.

Usage errors (bad arguments, unreadable input) print one line and exit 2.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from .errors import SurfnormError

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Surface normals from depth images: D2NT (ICRA 2023) and the estimators it is compared with.")
console = Console()
err_console = Console(stderr=True)


def fail(message: str, code: int = 2):
    err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def method_names() -> list[str]:
    from .methods import methods

    return list(methods())


def _intrinsics(params: Optional[Path], fx, fy, cx, cy):
    from .camera import Intrinsics
    from .io.threef2n import read_params

    if params is not None:
        return read_params(params)
    if None in (fx, fy, cx, cy):
        fail("intrinsics: expected --params FILE or all of --fx --fy --cx --cy")
    return Intrinsics(fx, fy, cx, cy)


@app.command()
def estimate(
    depth: Path = typer.Argument(..., help="Depth file (.bin, .npy, .npz, 16-bit .png, float .tif)."),
    output: Path = typer.Argument(..., help="Output prefix: writes PREFIX.npy (float32 normals) and PREFIX.png (picture)."),
    method: str = typer.Option("d2nt_v3", "--method", "-m", help="Estimator; see `surfnorm methods`. Any name may end in +mnr."),
    params: Optional[Path] = typer.Option(None, help="3F2N params.txt with fx fy u0 v0 (1-based)."),
    fx: Optional[float] = typer.Option(None, help="Focal length x, pixels."),
    fy: Optional[float] = typer.Option(None, help="Focal length y, pixels."),
    cx: Optional[float] = typer.Option(None, help="Principal point x, pixels, 0-based."),
    cy: Optional[float] = typer.Option(None, help="Principal point y, pixels, 0-based."),
    depth_scale: Optional[float] = typer.Option(None, help="Divide integer depth by this (1000 for mm, 5000 for TUM)."),
):
    """Estimate the normals of one depth image."""
    import numpy as np

    from . import estimate as estimate_
    from .io._atomic import atomic_write
    from .io.depth import read_depth
    from .io.pictures import normal_to_rgb8, write_rgb8

    try:
        cam = _intrinsics(params, fx, fy, cx, cy)
        z = read_depth(depth, depth_scale=depth_scale)
        normals = estimate_(z, cam, method=method)
        if output.is_dir():
            fail(f"output: expected a file prefix, got the directory {output}")
        npy = output.with_name(output.name + ".npy")
        atomic_write(npy, lambda tmp: np.save(open(tmp, "wb"), normals))
        write_rgb8(output.with_name(output.name + ".png"), normal_to_rgb8(normals))
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    console.print(f"wrote {npy} and {output.with_name(output.name + '.png')}")


@app.command("methods")
def list_methods():
    """List the registered estimators with their category and paper."""
    from .methods import methods

    table = Table("method", "category", "reference", "options")
    for info in methods().values():
        table.add_row(info.name, info.category, info.reference, ", ".join(f"{k}={v!r}" for k, v in info.options.items()))
    console.print(table)
    console.print("Any method name followed by +mnr refines its output with MNR.")


@app.command()
def demo(
    out: Path = typer.Argument(Path("demo-output"), help="Folder for the normal and error maps (PNG)."),
):
    """Run every method on the sample frames shipped with surfnorm; print e_A next to the authors' figures."""
    from rich.progress import Progress

    from .demo import demo_methods, run_demo
    from .io.threef2n import find_frames, sample_root

    names = demo_methods()
    total = len(names) * len(find_frames(sample_root()))
    try:
        with Progress(console=err_console, transient=True) as progress:
            task = progress.add_task("estimating", total=total)
            rows = run_demo(out, methods_=names, progress=lambda: progress.advance(task))
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    frames = list(dict.fromkeys(r.frame for r in rows))
    table = Table(title="e_A (degrees) on the shipped 3F2N frames; authors' figure in brackets", title_justify="left")
    table.add_column("method")
    for f in frames:
        table.add_column(f, justify="right")
    table.add_column("ms (1 frame)", justify="right")
    for name in names:
        cells = []
        for f in frames:
            r = next(r for r in rows if r.frame == f and r.method == name)
            cells.append(f"{r.e_a:.3f}" + (f" [{r.official:.3f}]" if r.official is not None else ""))
        ms = sorted(r.ms for r in rows if r.method == name)[len(frames) // 2]
        table.add_row(name, *cells, f"{ms:.1f}")
    console.print(table)
    console.print(f"normal maps and error maps (PNG) written to {out}/")


@app.command()
def bench(
    dataset: Optional[Path] = typer.Argument(None, help="Folder in the 3F2N layout (Easy|Medium|Hard/<object>/depth|normal, params.txt). Default: the frames shipped in surfnorm."),
    out: Path = typer.Option(..., "--out", "-o", help="Report folder: report.md, results.json, PNG figures, and a cache of finished per-frame results."),
    methods_: Optional[list[str]] = typer.Option(None, "--methods", "-m", help="Table III rows: registered names (+mnr allowed), repeatable or comma-separated. Default: every registered method."),
    peers: Optional[list[str]] = typer.Option(None, "--peers", help="Peer libraries: d2nt, kornia, open3d, opencv, or none. Repeatable or comma-separated. Default: all."),
    levels: Optional[list[str]] = typer.Option(None, "--levels", help="Easy, Medium, Hard (repeatable or comma-separated). Default: all."),
    frames_per_object: Optional[int] = typer.Option(None, "--frames-per-object", help="At most this many frames of each object (the first ones). Default: all."),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", help="Processes for the accuracy runs (timing runs are always single-process, one thread). Default: one per core."),
    seed: int = typer.Option(0, "--seed", help="Seed of the noise study's Gaussian noise."),
    tables: Optional[list[str]] = typer.Option(None, "--tables", help="Experiments to run: table2, table3, table4, noise, fig4 (repeatable or comma-separated). Default: all."),
    repeats: int = typer.Option(7, "--repeats", help="Timed calls per method and frame after the warm-up (3 for methods over 200 ms)."),
):
    """Regenerate the paper's Tables II-IV and Figs. 1, 3, 4 (with today's peers) on data in the 3F2N layout."""
    import os
    import time

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from .bench import BenchConfig, run_bench, write_report
    from .bench.runner import TABLES
    from .io.threef2n import LEVELS, sample_root

    def split(values):
        return None if values is None else [v.strip() for x in values for v in x.split(",") if v.strip()]

    peer_list = split(peers)
    if peer_list is not None and "none" in peer_list:
        peer_list = []
    cfg = BenchConfig(root=dataset if dataset is not None else sample_root(), out=out, methods=split(methods_),
                      peers=peer_list, levels=tuple(split(levels) or LEVELS), frames_per_object=frames_per_object,
                      jobs=jobs if jobs is not None else (os.cpu_count() or 1), seed=seed, repeats=repeats,
                      tables=tuple(split(tables) or TABLES))
    t0 = time.perf_counter()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=err_console, transient=True) as progress:
            tasks = {}

            def report(stage, done, total):
                if stage not in tasks:
                    tasks[stage] = progress.add_task(f"{stage} (frames)", total=total)
                progress.update(tasks[stage], completed=done, total=total)

            result = run_bench(cfg, progress=report)
        paths = write_report(result, out, elapsed_s=time.perf_counter() - t0)
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    for name, why in result.unreadable.items():
        err_console.print(f"[yellow]not evaluated:[/] {name}: {why}", highlight=False, soft_wrap=True)
    for name, why in result.skipped.items():
        err_console.print(f"[yellow]skipped:[/] {name}: {why}", highlight=False, soft_wrap=True)
    console.print(_table3_text(paths["report"]), highlight=False, soft_wrap=True)
    console.print(f"wrote {paths['report']}, {paths['results']} and figures in {out}/ in {time.perf_counter() - t0:.0f} s")


def _table3_text(report_path: Path) -> str:
    text = report_path.read_text()
    start = text.index("## Table III")
    end = text.find("\n## ", start + 1)
    return text[start:end if end >= 0 else None].strip()


def main():  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
