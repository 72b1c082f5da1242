"""The ``surfnorm`` command line: each command maps options to one library call.

Every error a user can cause prints ONE line on stderr and exits with status 2:
Click's own usage errors (a bad option value, an unknown command or option, a
missing argument) as well as the library's errors (:mod:`surfnorm.errors`,
ValueError, OSError). :class:`OneLineGroup` does this for every command, so a
command only has to call the library. An unexpected exception (a bug) is one
line too, with exit status 1; ``SURFNORM_TRACEBACK=1`` shows its traceback.
"""

from __future__ import annotations

import os
import re
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from typer.core import TyperGroup

from .errors import SurfnormError
from .methods import DEFAULT_METHOD

console = Console()
err_console = Console(stderr=True)

#: Exit status of a usage error (Click's, and every error that bad input causes).
USAGE = 2


def one_line(message: str) -> str:
    """``message`` on one line: line breaks (and the spaces around them) become one space."""
    return re.sub(r"\s*[\r\n]+\s*", " ", str(message)).strip()


def say_error(message: str):
    """Print ``error: message`` as one line on stderr (never wrapped, markup escaped)."""
    err_console.print(f"[bold red]error:[/] {escape(one_line(message))}", highlight=False, soft_wrap=True)


def fail(message: str, code: int = USAGE):
    """Print ``message`` as one line on stderr and exit with ``code`` (2, a usage error, by default)."""
    say_error(message)
    raise typer.Exit(code)


def _click_exceptions():
    """(errors, passed through): Click's exception classes.

    From the Click that Typer uses (recent Typer versions carry their own copy as ``typer._click``) and from
    Click itself where it is installed.
    """
    import importlib

    modules = []
    for name in ("typer._click.exceptions", "click.exceptions"):
        try:
            modules.append(importlib.import_module(name))
        except ImportError:
            pass
    errors = tuple(m.ClickException for m in modules)
    passed = tuple(getattr(m, n) for m in modules for n in ("Exit", "Abort", "NoArgsIsHelpError") if hasattr(m, n))
    return errors, passed + (typer.Exit, typer.Abort)


_CLICK_ERRORS, _PASSED = _click_exceptions()


@contextmanager
def _one_line_errors():
    """Turn every error raised inside into one line on stderr and ``typer.Exit`` (2, or 1 for a bug)."""
    try:
        yield
    except (KeyboardInterrupt,) + _PASSED:
        raise  # exit codes, Ctrl-C (exit 130) and the help of a bare `surfnorm` stay Click's
    except _CLICK_ERRORS as exc:  # a bad option value, an unknown command or option, a missing argument
        where = exc.ctx.command_path if getattr(exc, "ctx", None) is not None else "surfnorm"
        fail(f"{where}: {exc.format_message()} (see '{where} --help')")
    except (SurfnormError, ValueError, OSError) as exc:  # InputError, DataFileError, ConnectionError, ...
        fail(str(exc) or type(exc).__name__)
    except Exception as exc:  # noqa: BLE001 - a bug: still one line, but not a usage error
        if os.environ.get("SURFNORM_TRACEBACK"):
            raise
        fail(f"unexpected {type(exc).__name__}: {exc} (a bug in surfnorm; SURFNORM_TRACEBACK=1 shows the traceback)", 1)


class OneLineGroup(TyperGroup):
    """The command group: usage and library errors of every command become one line on stderr, exit 2.

    Parsing (a bad value, a missing argument, an unknown option or command) happens in
    ``make_context`` of the group and, for the command, inside the group's ``invoke``, as
    does the command itself; both are wrapped, so no error reaches Typer's boxes or tracebacks.
    """

    def make_context(self, info_name, args, parent=None, **extra):
        """Parse the command line, turning a usage error into one line on stderr and exit status 2."""
        with _one_line_errors():
            return super().make_context(info_name, args, parent=parent, **extra)

    def invoke(self, ctx):
        """Run the command, turning a usage error into one line on stderr and exit status 2."""
        with _one_line_errors():
            return super().invoke(ctx)


app = typer.Typer(
    cls=OneLineGroup,
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Surface normals from depth images: D2NT (ICRA 2023) and the estimators it is compared with.",
)


def method_names() -> list[str]:
    """The registered method names, the choices of ``--method``."""
    from .methods import methods

    return list(methods())


METHOD_HELP = (
    "Estimator, with options: NAME or NAME:option=value,option=value (e.g. plane_pca:window=5); "
    "`surfnorm methods NAME` lists its options. Any name may end in +mnr."
)
INTRINSICS_HELP = (
    "Camera intrinsics file: JSON/YAML (fx, fy, cx, cy or K), ROS camera_info YAML, OpenCV YAML, 3F2N params.txt."
)
FORMAT_HELP = (
    "Output format: npy (float32), png16 (lossless, 3F2N encoding), png8 (picture) or ply (point cloud of the "
    "pixels with a normal: points, normals)."
)
KINECT_HELP = "The file holds Kinect v1 raw 11-bit disparity (NYU Depth v2 raw frames): convert to metres, a / (b - d), NYU toolbox constants."
SUN_RGBD_HELP = (
    "The file is a SUN RGB-D depth PNG (millimetres, bits rotated left by 3): rotate back, convert to metres."
)
BYTE_ORDER_HELP = (
    "Byte order of 16-bit .pgm samples: big (netpbm, default) or little (libfreenect dumps, NYU Depth v2 raw d-*.pgm)."
)


def _intrinsics(intrinsics: Optional[Path], fx, fy, cx, cy, depth_path: Optional[Path] = None):
    """The camera from --intrinsics or --fx --fy --cx --cy.

    A depth file falls back to its 3F2N params.txt (beside it or in the folder above, whether its path is
    relative or absolute).
    """
    from .io.intrinsics import resolve_intrinsics
    from .io.threef2n import params_for

    cam = resolve_intrinsics(intrinsics, fx=fx, fy=fy, cx=cx, cy=cy)
    if cam is None and depth_path is not None and params_for(depth_path) is not None:
        cam = resolve_intrinsics(params_for(depth_path))
    if cam is None:
        fail("intrinsics: expected --intrinsics FILE or all of --fx --fy --cx --cy")
    return cam


def _check_format(fmt: str) -> str:
    from .io.normals import OUTPUT_FORMATS

    if fmt not in OUTPUT_FORMATS:
        fail(f"--format: expected one of {', '.join(OUTPUT_FORMATS)}, got {fmt!r}")
    return fmt


@app.command()
def estimate(
    depth: Path = typer.Argument(
        ..., help="Depth file (.bin, .bin.gz, .npy, .npz, 16-bit .png or .pgm, float .tif, .exr or .pfm)."
    ),
    output: Path = typer.Argument(
        ...,
        help="Output prefix: writes PREFIX.npy (float32 normals) and PREFIX.png (picture); "
        "or a name ending in .ply: a PLY point cloud of the pixels with a normal (points, normals).",
    ),
    method: str = typer.Option(DEFAULT_METHOD, "--method", "-m", help=METHOD_HELP),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", "--params", "-k", help=INTRINSICS_HELP),
    fx: Optional[float] = typer.Option(None, help="Focal length x, pixels."),
    fy: Optional[float] = typer.Option(None, help="Focal length y, pixels."),
    cx: Optional[float] = typer.Option(None, help="Principal point x, pixels, 0-based."),
    cy: Optional[float] = typer.Option(None, help="Principal point y, pixels, 0-based."),
    depth_scale: Optional[float] = typer.Option(
        None, help="Divide stored depth by this (1000 for mm PNG, 5000 for TUM)."
    ),
    mask: Optional[Path] = typer.Option(None, help="Mask image or .npy: non-zero where depth may be used."),
    scale_invariant: bool = typer.Option(
        False,
        "--scale-invariant",
        help="Thresholds relative to each pixel's own depth: the same normals in any unit of depth.",
    ),
    disparity: bool = typer.Option(False, "--disparity", help="The input holds disparity (inverse depth up to scale)."),
    fmt: Optional[str] = typer.Option(
        None, "--format", "-f", help=FORMAT_HELP + " Default: npy and png8; ply for an OUTPUT ending in .ply."
    ),
    color: Optional[Path] = typer.Option(
        None,
        "--color",
        help="Colour image (PNG, JPEG) registered to the depth, of its size: adds red, green, blue to a PLY output.",
    ),
    kinect_disparity: bool = typer.Option(False, "--kinect-disparity", help=KINECT_HELP),
    byte_order: Optional[str] = typer.Option(None, "--byte-order", help=BYTE_ORDER_HELP),
    sun_rgbd: bool = typer.Option(False, "--sun-rgbd", help=SUN_RGBD_HELP),
    overwrite: bool = typer.Option(
        False,
        "--overwrite",
        help="Replace output files that exist (never the files read: depth, mask, intrinsics, colour image).",
    ),
    verbose: bool = typer.Option(
        False, "--verbose", "-v", help="Also print what the default method ran on this frame, and why."
    ),
    uncertainty: bool = typer.Option(
        False,
        "--uncertainty",
        help="Also each normal's predicted RMS angular error in degrees (methods auto, adaptive_fit, d2nt_v3): the "
        "PLY's quality property, or OUTPUT.sigma.npy (float32, NaN where no normal) beside the other formats.",
    ),
):
    """Estimate the normals of one depth image.

    An OUTPUT ending in .ply (or --format ply) writes a PLY point cloud of the pixels that have a normal: their
    points (camera frame, depth's unit) and normals, with --color their colours.

    An output file that exists is an error (exit status 2) unless --overwrite; an output that is one of the
    files read (the depth, the mask, the intrinsics) is an error always.
    """
    from . import estimate as estimate_
    from .io._files import check_outputs
    from .io.depth import read_depth, read_mask
    from .io.normals import FORMAT_SUFFIX, write_normals
    from .io.ply import PLY_SUFFIX, read_colors, write_ply
    from .io.threef2n import params_for
    from .methods import parse_method

    written = []
    try:
        named_ply = output.suffix.lower() == PLY_SUFFIX
        if named_ply and fmt not in (None, "ply"):
            fail(f"--format: {output} names a PLY point cloud, got --format {fmt}; drop --format, or give a prefix")
        formats = [_check_format(fmt)] if fmt is not None else ["ply"] if named_ply else ["npy", "png8"]
        if output.is_dir():
            fail(f"output: expected a file prefix, got the directory {output}")
        if formats == ["ply"]:
            paths = [output if named_ply else output.with_name(output.name + PLY_SUFFIX)]
            if disparity:
                fail("--disparity: a PLY output back-projects depth to points; expected depth, not disparity")
        else:
            paths = [output.with_name(output.name + FORMAT_SUFFIX[f]) for f in formats]
            if color is not None:
                fail(f"--color: adds colours to a PLY point cloud; expected an OUTPUT ending in .ply, got {output}")
        sigma_path = output.with_name(output.name + ".sigma.npy") if uncertainty and formats != ["ply"] else None
        reads = [depth, mask, intrinsics, color, params_for(depth) if intrinsics is None else None]
        check_outputs(paths + ([sigma_path] if sigma_path is not None else []), reads, overwrite=overwrite)
        cam = _intrinsics(intrinsics, fx, fy, cx, cy, depth)
        z = read_depth(
            depth, depth_scale=depth_scale, kinect_disparity=kinect_disparity, byte_order=byte_order, sun_rgbd=sun_rgbd
        )
        user_mask = read_mask(mask) if mask is not None else None
        rgb = read_colors(color) if color is not None else None
        if rgb is not None and rgb.shape[:2] != z.shape:
            fail(
                f"--color: {color} is {rgb.shape[1]}x{rgb.shape[0]} pixels and the depth {z.shape[1]}x{z.shape[0]}; "
                "expected a colour image registered to the depth frame, of its size"
            )
        name, options = parse_method(method)
        with warnings.catch_warnings(record=True) as caught:  # each warning as one line, not Python's two
            result = estimate_(
                z,
                cam,
                method=name,
                mask=user_mask,
                scale_invariant=scale_invariant,
                disparity=disparity,
                uncertainty=uncertainty,
                **options,
            )
        normals, sigma = result if uncertainty else (result, None)
        for w in caught:
            err_console.print(
                f"[yellow]warning:[/] {escape(one_line(str(w.message)))}", highlight=False, soft_wrap=True
            )
        if verbose and name.split("+")[0] == DEFAULT_METHOD:
            from ._api import auto_decision

            console.print(str(auto_decision(z, cam, mask=user_mask, disparity=disparity)), highlight=False)
        elif verbose:
            console.print(f"ran {method}, as named", highlight=False)
        for path, f in zip(paths, formats):
            if f == "ply":
                written.append(write_ply(path, z, cam, normals, colors=rgb, sigma=sigma))
            else:
                written.append(write_normals(path, normals, fmt=f))
        if sigma_path is not None:
            import numpy as np

            from .io._atomic import atomic_write

            def save(tmp, sigma=sigma):
                with open(tmp, "wb") as fh:
                    np.save(fh, sigma)

            written.append(atomic_write(sigma_path, save))
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    console.print(f"wrote {' and '.join(map(str, written))}", highlight=False)


@app.command("methods")
def list_methods(
    name: Optional[str] = typer.Argument(
        None, help="A method: print each of its options with its meaning, default and allowed values."
    ),
):
    """List the registered estimators with their category, paper and kernel; with NAME, that method's options."""
    from .methods import methods, options_of

    if name is not None:
        try:
            options = options_of(name)
        except SurfnormError as exc:
            fail(f"NAME: {exc}")
        info = methods()[name.removesuffix("+mnr")]
        console.print(f"{name} ({info.category}): {info.summary}", highlight=False, soft_wrap=True)
        console.print(f"paper: {info.reference}", highlight=False, soft_wrap=True)
        console.print(f"kernel: {info.kernel}", highlight=False, soft_wrap=True)
        table = Table("option", "default", "allowed", "meaning")
        for o in options:
            table.add_row(o.name, repr(o.default), o.allowed, o.doc)
        console.print(table)
        console.print(
            f"Set them with -m {name}:option=value,option=value (estimate, convert) or as keyword "
            "arguments of surfnorm.estimate.",
            highlight=False,
            soft_wrap=True,
        )
        return
    table = Table("method", "category", "reference", "options", "kernel")
    for info in methods().values():
        table.add_row(
            info.name,
            info.category,
            info.reference,
            ", ".join(f"{k}={v!r}" for k, v in info.options.items()),
            info.kernel,
        )
    console.print(table)
    console.print("Any method name followed by +mnr refines its output with MNR.")
    console.print("`surfnorm methods NAME`: each option of a method with its meaning, default and allowed values.")


@app.command()
def sample(
    name: str = typer.Argument(
        ..., help="A sample frame shipped in surfnorm: realsense-d435, 3f2n-easy, 3f2n-medium, 3f2n-hard."
    ),
    path: Path = typer.Argument(
        Path("frame.png"), help="The 16-bit PNG to write; its intrinsics go beside it as .json."
    ),
    depth_scale: float = typer.Option(1000.0, help="Stored value per unit of depth (1000: millimetres)."),
):
    """Write a sample frame as a camera would: a 16-bit depth PNG and its intrinsics as JSON, to try the commands on."""
    from .io.samples import write_sample

    try:
        png, js = write_sample(name, path, depth_scale=depth_scale)
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    console.print(f"wrote {png} (depth x {depth_scale:g}) and {js}", highlight=False)


@app.command()
def demo(
    out: Path = typer.Argument(Path("demo-output"), help="Folder for the normal and error maps (PNG)."),
):
    """Run every method on the sample frames shipped with surfnorm; print e_A next to the authors' figures.

    Then the default estimator on a real RealSense D435 frame, beside OpenCV's RgbdNormals where OpenCV has it.
    """
    from rich.progress import Progress

    from .demo import CONTACT_SHEET, demo_methods, run_demo
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
    console.print(
        f"contact sheet (every frame and method on one picture): {out / CONTACT_SHEET}", highlight=False, soft_wrap=True
    )
    _sensor_demo(out)


def _sensor_demo(out: Path):
    """The default's normals on the shipped RealSense frame beside OpenCV's, with the plane metric."""
    from .demo import run_sensor_demo

    try:
        with err_console.status("estimating on the RealSense D435 frame"):
            rows, skipped, picture = run_sensor_demo(out)
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    table = Table(
        title="Real sensor depth: RealSense D435 frame (ClearGrasp, Apache-2.0), angle to its reference planes",
        title_justify="left",
    )
    for name in ("estimator", "mean angle (deg)", "coverage", "ms"):
        table.add_column(name, justify="left" if name == "estimator" else "right")
    for r in rows:
        table.add_row(r.estimator, f"{r.plane_error:.1f}", f"{r.coverage:.1%}", f"{r.ms:.1f}")
    console.print(table)
    if skipped:
        console.print(f"OpenCV RgbdNormals skipped: {skipped}", highlight=False, soft_wrap=True)
    console.print(f"normal maps side by side: {picture}", highlight=False)


@app.command()
def convert(
    inputs: str = typer.Argument(
        ..., metavar="INPUT", help="A depth file, a folder (searched recursively) or a quoted glob pattern."
    ),
    output_dir: Path = typer.Argument(
        ..., help="Folder for the normal files (created if missing); sub-folders mirror INPUT."
    ),
    method: str = typer.Option(DEFAULT_METHOD, "--method", "-m", help=METHOD_HELP),
    depth_scale: Optional[float] = typer.Option(
        None, help="Divide stored depth by this (1000 for mm PNG, 5000 for TUM)."
    ),
    intrinsics: Optional[Path] = typer.Option(
        None, "--intrinsics", "--params", "-k", help=INTRINSICS_HELP + " Default: each 3F2N file's params.txt."
    ),
    fx: Optional[float] = typer.Option(None, help="Focal length x, pixels."),
    fy: Optional[float] = typer.Option(None, help="Focal length y, pixels."),
    cx: Optional[float] = typer.Option(None, help="Principal point x, pixels, 0-based."),
    cy: Optional[float] = typer.Option(None, help="Principal point y, pixels, 0-based."),
    fmt: str = typer.Option("npy", "--format", "-f", help=FORMAT_HELP),
    jobs: int = typer.Option(1, "--jobs", "-j", help="Parallel processes."),
    scale_invariant: bool = typer.Option(
        False,
        "--scale-invariant",
        help="Thresholds relative to each pixel's own depth: the same normals in any unit of depth.",
    ),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="Replace outputs that exist (default: skip them, so a re-run resumes)."
    ),
    cluster: Optional[str] = typer.Option(
        None,
        "--cluster",
        metavar="ADDRESS",
        help="Run on the Dask scheduler at ADDRESS (tcp://host:8786); every worker must see INPUT and OUTPUT_DIR at the same paths.",
    ),
    local_cluster: Optional[int] = typer.Option(
        None, "--local-cluster", metavar="N", help="Run on a Dask LocalCluster of N worker processes."
    ),
    shard_size: Optional[int] = typer.Option(
        None, "--shard-size", help="Files per Dask task (default: about 4 per worker thread, 8 to 64 files)."
    ),
    kinect_disparity: bool = typer.Option(False, "--kinect-disparity", help=KINECT_HELP),
    byte_order: Optional[str] = typer.Option(None, "--byte-order", help=BYTE_ORDER_HELP),
    sun_rgbd: bool = typer.Option(False, "--sun-rgbd", help=SUN_RGBD_HELP),
):
    """Convert many depth files to normal files, in parallel; a re-run skips finished outputs.

    Exit status: 0 when every file was written or skipped, 1 when some file failed
    (each is named), 2 for a usage error.
    """
    from contextlib import nullcontext

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from .batch import convert as convert_
    from .batch import plan_tasks
    from .methods import parse_method

    _check_format(fmt)
    if jobs < 1:
        fail(f"--jobs: expected a positive integer, got {jobs}")
    on_dask = cluster is not None or local_cluster is not None
    if cluster is not None and local_cluster is not None:
        fail("--cluster and --local-cluster: expected one of them, got both")
    if on_dask and jobs != 1:
        fail("--jobs: a local process pool and a Dask cluster are alternatives; drop --jobs or the cluster option")
    if shard_size is not None and not on_dask:
        fail("--shard-size: applies to a Dask run; add --cluster ADDRESS or --local-cluster N")
    if shard_size is not None and shard_size < 1:
        fail(f"--shard-size: expected a positive integer, got {shard_size}")
    try:
        from .io.intrinsics import resolve_intrinsics

        cam = resolve_intrinsics(intrinsics, fx=fx, fy=fy, cx=cx, cy=cy)
        method_name, method_options = parse_method(method)
        # the options that go to convert_ as given: how each file is read and written, and how the run goes
        reading: dict[str, Any] = dict(
            fmt=fmt,
            depth_scale=depth_scale,
            kinect_disparity=kinect_disparity,
            byte_order=byte_order,
            sun_rgbd=sun_rgbd,
        )
        running: dict[str, Any] = dict(jobs=jobs, shard_size=shard_size, overwrite=overwrite)
        columns = (TextColumn("converting"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
        if on_dask:
            from .batch.cluster import cluster_client
        dask_client = cluster_client(cluster, local_workers=local_cluster) if on_dask else nullcontext()
        with dask_client as client, Progress(*columns, console=err_console, transient=True) as bar:
            task = bar.add_task("convert", total=None)

            def advance(result):
                if result.status == "error":
                    bar.console.print(f"[bold red]failed:[/] {result.message}", highlight=False, soft_wrap=True)
                bar.advance(task)

            bar.update(task, total=len(plan_tasks(inputs, output_dir, fmt)))
            summary = convert_(
                inputs,
                output_dir,
                method=method_name,
                scale_invariant=scale_invariant,
                intrinsics=cam,
                progress=advance,
                client=client,
                **reading,
                **running,
                **method_options,
            )
    except KeyboardInterrupt:
        fail("interrupted: finished outputs are complete; run the same command again to do the rest", 130)
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    console.print(
        f"{summary.written} written, {summary.skipped} skipped (output existed), {len(summary.errors)} failed "
        f"-> {output_dir}",
        highlight=False,
    )
    if summary.errors:
        for r in summary.errors:
            err_console.print(f"[bold red]error:[/] {r.message}", highlight=False, soft_wrap=True)
        raise typer.Exit(1)


def _stage_progress():
    """The benchmarks' progress bar on stderr: a stage's name, its bar, frames done of all, time elapsed."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    return Progress(*columns, console=err_console, transient=True)


@app.command()
def bench(
    dataset: Optional[Path] = typer.Argument(
        None,
        help="Folder in the 3F2N layout (Easy|Medium|Hard/<object>/depth|normal, params.txt). Default: the frames shipped in surfnorm.",
    ),
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="Report folder: report.md, results.json, PNG figures, and a cache of finished per-frame results.",
    ),
    methods_: Optional[list[str]] = typer.Option(
        None,
        "--methods",
        "-m",
        help="Table III rows: registered names (+mnr allowed), repeatable or comma-separated. Default: every registered method.",
    ),
    peers: Optional[list[str]] = typer.Option(
        None,
        "--peers",
        help="Peer libraries: d2nt, kornia, open3d, opencv, or none. Repeatable or comma-separated. Default: all.",
    ),
    levels: Optional[list[str]] = typer.Option(
        None, "--levels", help="Easy, Medium, Hard (repeatable or comma-separated). Default: all."
    ),
    frames_per_object: Optional[int] = typer.Option(
        None, "--frames-per-object", help="At most this many frames of each object (the first ones). Default: all."
    ),
    jobs: Optional[int] = typer.Option(
        None,
        "--jobs",
        "-j",
        help="Processes for the accuracy runs (timing runs are always single-process, one thread). Default: one per core.",
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the noise study's Gaussian noise."),
    tables: Optional[list[str]] = typer.Option(
        None,
        "--tables",
        help="Experiments to run: table2, table3, table4, noise, fig4 (repeatable or comma-separated). Default: all.",
    ),
    repeats: int = typer.Option(
        7, "--repeats", help="Timed calls per method and frame after the warm-up (3 for methods over 200 ms)."
    ),
    sensor: Optional[Path] = typer.Option(
        None,
        "--sensor",
        help="Instead: the sensor benchmark on a folder of real frames (<frame>/depth.npy in metres, K.json, planes.npz or gt.npy); --methods then also takes peer names and name:option=value.",
    ),
):
    """Regenerate the paper's Tables II-IV and Figs. 1, 3, 4 (with today's peers) on data in the 3F2N layout.

    With --sensor DIR: the plane metric (or e_A against gt.npy) and time of every method and peer on real sensor frames,
    and the default's uncertainty (sigma): its calibration on the simulated sensors over the 3F2N frames of DATASET
    (default: those shipped in the package) and its sparsification on the real frames.
    """
    import os
    import time

    if sensor is not None:
        return _bench_sensor(sensor, dataset, out, methods_, peers, repeats)

    from .bench import BenchConfig, run_bench, write_report
    from .bench.runner import TABLES
    from .io.threef2n import LEVELS, sample_root

    def split(values):
        return None if values is None else [v.strip() for x in values for v in x.split(",") if v.strip()]

    peer_list = split(peers)
    if peer_list is not None and "none" in peer_list:
        peer_list = []
    cfg = BenchConfig(
        root=dataset if dataset is not None else sample_root(),
        out=out,
        methods=split(methods_),
        peers=peer_list,
        levels=tuple(split(levels) or LEVELS),
        frames_per_object=frames_per_object,
        jobs=jobs if jobs is not None else (os.cpu_count() or 1),
        seed=seed,
        repeats=repeats,
        tables=tuple(split(tables) or TABLES),
    )
    t0 = time.perf_counter()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with _stage_progress() as progress:
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
    console.print(
        f"wrote {paths['report']}, {paths['results']} and figures in {out}/ in {time.perf_counter() - t0:.0f} s"
    )


def _bench_sensor(folder: Path, dataset, out: Path, methods_, peers, repeats: int):
    """``surfnorm bench --sensor DIR``: see :func:`surfnorm.bench.sensor.sensor_bench`."""
    import time

    from .bench.sensor import sensor_bench

    names = None if methods_ is None else [v.strip() for x in methods_ for v in x.split(",") if v.strip()]
    libs = None if peers is None else [v.strip() for x in peers for v in x.split(",") if v.strip()]
    if libs is not None and "none" in libs:
        libs = []
    t0 = time.perf_counter()
    try:
        # the folder and the dataset checked before the progress bar starts (its end would add a line to an error)
        from .bench.sensor import find_sensor_frames
        from .bench.uncertainty import calibration_frames

        find_sensor_frames(folder)
        calibration_frames(dataset)
        with _stage_progress() as progress:
            task = progress.add_task("sensor frames", total=None)
            result, paths = sensor_bench(
                folder,
                out,
                names=names,
                peer_libraries=libs,
                repeats=repeats,
                progress=lambda stage, done, total: progress.update(task, completed=done, total=total),
                calibration_root=dataset,
            )
    except (SurfnormError, OSError) as exc:
        fail(str(exc))
    for name, why in result["absent"].items():
        err_console.print(f"[yellow]absent:[/] {name}: {why}", highlight=False, soft_wrap=True)
    for e in result["errors"]:
        err_console.print(
            f"[yellow]failed:[/] {e['entry']} on {e['frame']}: {e['error']}", highlight=False, soft_wrap=True
        )
    text = paths["report"].read_text()
    console.print(text[text.index("## Angle") : text.index("## Coverage")].strip(), highlight=False, soft_wrap=True)
    figures = " and ".join(str(paths[k]) for k in ("figure", "uncertainty") if k in paths)
    console.print(f"wrote {paths['report']}, {paths['results']} and {figures} in {time.perf_counter() - t0:.0f} s")


def _table3_text(report_path: Path) -> str:
    text = report_path.read_text()
    start = text.index("## Table III")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else None].strip()


def main():  # pragma: no cover
    """Run the ``surfnorm`` command."""
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
