"""MkDocs hooks: the pages generated at build time from the code itself.

- ``kernels.md``: every registered method and where its code lives, read from ``surfnorm.methods()``;
- ``reference/cli.md``: the ``--help`` of ``surfnorm`` and of each of its commands;
- ``changelog.md``: ``CHANGELOG.md`` of the repository;
- in ``methods.md``, the table that :data:`METHODS_MARKER` marks: every registered method with its category and
  summary, from the registry's own entries;
- in ``methods.md``, the section that :data:`OPTIONS_MARKER` marks: every option of every method with its meaning,
  default and allowed values, from the registry's own text (what ``surfnorm methods NAME`` prints).

The kernel page shows every field of the registry's entries beyond name, category, paper, summary and options,
so a field that says where a kernel lives appears by itself once the registry has it; until then it shows the
function the registry calls.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import os
import re
import sys
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
if str(SRC) not in sys.path:  # document this checkout's sources, whatever else is installed
    sys.path.insert(0, str(SRC))

#: The fields of surfnorm.methods()'s entries that the kernel page shows in their own columns.
BASE_FIELDS = ("name", "category", "reference", "summary", "options")


def on_files(files, config):
    """Add the generated pages to the site."""
    pages = {"kernels.md": kernels_page(), "reference/cli.md": cli_page(), "changelog.md": changelog_page()}
    for path, text in pages.items():
        files.append(File.generated(config, path, content=text))
    return files


#: The line of docs/methods.md that the generated options section replaces.
OPTIONS_MARKER = "<!-- options of every method: generated from the registry by docs/hooks.py -->"


#: The line of docs/methods.md that the generated table of methods replaces.
METHODS_MARKER = "<!-- the methods: generated from the registry by docs/hooks.py -->"


def on_page_markdown(markdown, page, config, files):
    """Put the generated table of methods and options section where methods.md marks them."""
    if page.file.src_uri == "methods.md":
        for marker, section in ((METHODS_MARKER, methods_table), (OPTIONS_MARKER, options_section)):
            if marker not in markdown:
                raise RuntimeError(f"docs/methods.md: expected the line {marker!r}")
            markdown = markdown.replace(marker, section())
    return markdown


def methods_table() -> str:
    """Every registered method: name (the default marked), category, summary; then the ``+mnr`` recipes."""
    import surfnorm
    from surfnorm.methods import DEFAULT_METHOD

    lines = ["| name | category | what it is |", "|---|---|---|"]
    for name, info in surfnorm.methods().items():
        label = f"`{name}`" + (" (default)" if name == DEFAULT_METHOD else "")
        lines.append("| " + " | ".join(_cell(c) for c in (label, info.category, info.summary)) + " |")
    lines.append("| `<any>+mnr` | | any method followed by MNR (Table IV: `3f2n_median+mnr`, `cp2tv+mnr`) |")
    return "\n".join(lines) + "\n"


def options_section() -> str:
    """Every option of every registered method: default, allowed values, meaning (``surfnorm.methods.options_of``)."""
    import surfnorm
    from surfnorm.methods import options_of

    lines = []
    for name, info in surfnorm.methods().items():
        lines += [f"### `{name}`", "", f"{info.summary}. Paper: {info.reference}.", ""]
        lines += ["| option | default | allowed | meaning |", "|---|---|---|---|"]
        for o in options_of(name):
            cells = [f"`{o.name}`", f"`{o.default!r}`", o.allowed, o.doc]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
        lines.append("")
    lines += [
        "Any method followed by `+mnr` also takes `mnr_dlf`: " + _cell(options_of("d2nt_basic+mnr")[-1].doc) + ".",
        "",
    ]
    return "\n".join(lines)


def on_page_content(html, page, config, files):
    """Drop the Sphinx roles the docstrings use (``:func:`x```) in front of the code they mark."""
    return re.sub(r":(?:func|mod|class|meth|attr|data|obj):(?=<code>)", "", html)


# ---------------------------------------------------------------------------- method -> kernel


def _source(obj) -> str:
    """``src/surfnorm/...py:LINE`` of a function (a Numba dispatcher's Python function), or ''."""
    obj = getattr(obj, "py_func", obj)
    try:
        file, line = inspect.getsourcefile(obj), inspect.getsourcelines(obj)[1]
    except (TypeError, OSError):
        return ""
    if file is None:
        return ""
    try:
        file = os.path.relpath(file, ROOT)
    except ValueError:
        pass
    return f"{Path(file).as_posix()}:{line}"


def _resolve_dotted(path: str):
    """The object a dotted path ``package.module.function`` (or ``package.module:function``) names, or None."""
    module, _, attr = path.replace(":", ".").rpartition(".")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError):
        return None


def _describe(value) -> tuple[str, str]:
    """(what, where): a field's value as text, and the source location of what it names (if anything)."""
    if value is None:
        return "", ""
    if isinstance(value, str):
        target = _resolve_dotted(value) if "." in value and " " not in value else None
        return f"`{value}`", _source(target) if target is not None else ""
    if isinstance(value, (tuple, list)) and len(value) == 2 and all(isinstance(v, str) for v in value):
        return _describe(".".join(value))  # (module, function)
    module, function = getattr(value, "module", None), getattr(value, "function", None)
    if isinstance(module, str) and isinstance(function, str):  # a lazy reference: module and function by name
        return _describe(f"{module}.{function}")
    if isinstance(value, functools.partial):  # a kernel with some options fixed
        text, where = _describe(value.func)
        fixed = ", ".join(f"{k}={v!r}" for k, v in value.keywords.items())
        return (f"{text} ({fixed})" if fixed else text), where
    if callable(value):
        func = getattr(value, "py_func", value)
        name = f"{getattr(func, '__module__', '?')}.{getattr(func, '__qualname__', repr(func))}"
        return f"`{name}`", _source(func)
    if dataclasses.is_dataclass(value) or isinstance(value, dict):
        items = dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
        return ", ".join(f"{k}={v!r}" for k, v in items.items()), ""
    return f"`{value!r}`", ""


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def kernels_page() -> str:
    """The method -> kernel table, from the registry of this checkout."""
    import surfnorm

    registry = importlib.import_module("surfnorm.methods")  # the module (the package's ``methods`` is the function)

    infos = surfnorm.methods()
    first = next(iter(infos.values()))
    extra = [f.name for f in dataclasses.fields(first) if f.name not in BASE_FIELDS]
    private = getattr(registry, "_REGISTRY", {})  # the entries themselves, for the function each one calls
    lines = [
        "# Methods and their kernels",
        "",
        "Generated when the documentation is built, from `surfnorm.methods()` (`src/surfnorm/methods.py`): every",
        "registered method, its category and paper, and where its code lives. Any method may also be followed by",
        "`+mnr`, which runs MNR (`surfnorm.refine`) after it.",
        "",
    ]
    header = ["method", "category"] + [f.replace("_", " ") for f in extra]
    if not extra:
        header.append("registered function (calls the kernels)")
    header += ["source", "paper"]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name, info in infos.items():
        cells, where = [f"`{name}`", info.category], ""
        for field in extra:
            text, loc = _describe(getattr(info, field))
            cells.append(text)
            where = where or loc
        if not extra:
            run = getattr(private.get(name), "run", None)
            text, where = _describe(run) if run is not None else ("", "")
            cells.append(text)
        cells += [f"`{where}`" if where else "", info.reference]
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    lines += ["", "Each method's options, with their meaning and values: [Methods, options](methods.md#options)."]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- command line


def cli_page() -> str:
    """``surfnorm --help`` and each command's ``--help``, as the terminal shows them (80 columns)."""
    from typer.main import get_command
    from typer.testing import CliRunner

    from surfnorm.cli import app

    group = get_command(app)
    runner = CliRunner()
    env = {"COLUMNS": "100", "TERM": "dumb", "NO_COLOR": "1"}
    lines = [
        "# Command line",
        "",
        "Generated when the documentation is built, from `surfnorm --help` and each command's `--help`.",
        "Usage errors print one line on stderr and exit with status 2 ([files and the command line](../files-cli.md)).",
        "",
    ]
    for args, title in [([], "surfnorm")] + [([name], f"surfnorm {name}") for name in group.commands]:
        result = runner.invoke(app, [*args, "--help"], env=env, terminal_width=100, prog_name="surfnorm")
        if result.exit_code != 0:
            raise RuntimeError(f"{title} --help exited with {result.exit_code}: {result.output}")
        lines += [f"## `{title}`", "", "```text", result.output.rstrip(), "```", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------- changelog


def changelog_page() -> str:
    """CHANGELOG.md of the repository."""
    return (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
