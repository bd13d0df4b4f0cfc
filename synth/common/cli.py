"""What every ``loggrasp`` command shares, written once.

- **Flags from the config dataclasses**: :func:`option` takes a flag's default from the field of
  the config dataclass it sets, adds the field's unit (from its ``_m`` / ``_s`` / ``_kg`` … name)
  to the help, and records ``field name -> flag`` so that a library error naming the field
  (``max_pile_age_s must be > 0``) reaches the operator as the flag (``--max-pile-age must be > 0``).
- **Errors**: commands raise; one handler (``field.cli.run``) prints one line ``error: …`` on
  standard error and exits with a documented code (:data:`EXIT_CODES`). :class:`CliError` is
  what a command raises for a problem it finds itself.
- **Output for people and for scripts**: :class:`Output` writes results on standard output and
  progress on standard error; with ``--json`` standard output carries exactly one JSON document
  with a ``format`` and ``format_version`` (NaN written as ``null``).
- **Quiet C libraries**: :func:`quiet_c_streams` points file descriptors 1 and 2 (where pybullet,
  EGL/OpenGL and libpng print) at ``/dev/null`` while Python's own ``sys.stdout`` / ``sys.stderr``
  keep writing to the terminal.
- **Paths**: :func:`check_output_dir` / :func:`check_output_file` / :func:`check_input` fail
  before any work, creating nothing, and name the flag.
- :func:`format_table`: plain aligned tables that never truncate (logs, pipes, terminals alike).

Only the standard library and typer are imported here, so ``loggrasp --help`` stays instant.
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys
from pathlib import Path
from typing import Any, Iterable

#: exit codes of every ``loggrasp`` command
EXIT_OK = 0
EXIT_INTERNAL = 1  # a bug: rerun with --verbose for the traceback and report it
EXIT_INPUT = 2  # bad input: a flag, a path or a file (the message names it)
EXIT_LINK = 3  # the crane link: unknown URL, controller unreachable, link failure
EXIT_TRIAL = 4  # the trial did not succeed: refused before sending (a safety check, or no grasp succeeded
# in the twin: also ``plan --verify``), rejected by the crane, failed
EXIT_REPLAY_DIFFERS = 5  # ``replay``: the re-run plan, command or a verification trial differs from the record
EXIT_INTERRUPTED = 130  # Ctrl-C

EXIT_CODES = {
    EXIT_OK: "success",
    EXIT_INTERNAL: "internal error (a bug: rerun with --verbose for the traceback and report it)",
    EXIT_INPUT: "bad input: a flag, a path or a file (the message names it)",
    EXIT_LINK: "crane link: unknown or malformed URL, controller unreachable, link failure",
    EXIT_TRIAL: "trial not successful: refused before sending (a safety check, or no grasp succeeded in the twin; "
                "also plan --verify), declined, rejected by the crane, or failed",
    EXIT_REPLAY_DIFFERS: "replay: the re-run plan, command or a verification trial differs from the recorded one",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C)",
}


class CliError(Exception):
    """A problem a command found itself; ``code`` is one of the ``EXIT_*`` codes."""

    def __init__(self, message: str, code: int = EXIT_INPUT):
        super().__init__(message)
        self.code = code


# -- flags ---------------------------------------------------------------------------------------
#: suffix of a config field name -> unit shown in the help (longest suffix first)
UNIT_SUFFIXES = (("_kg_m3", "kg/m³"), ("_deg", "deg"), ("_px", "px"), ("_kg", "kg"), ("_ms", "ms"),
                 ("_mm", "mm"), ("_m", "m"), ("_s", "s"), ("_n", "N"))

#: config field name -> the flag that sets it (filled by :func:`option`; read by :func:`to_flags`)
FLAG_OF_FIELD: dict[str, str] = {}


def unit_of(field_name: str) -> str | None:
    for suffix, unit in UNIT_SUFFIXES:
        if field_name.endswith(suffix):
            return unit
    return None


def field_default(cls: type, name: str) -> Any:
    """The default of dataclass ``cls``'s field ``name`` (its factory called if it has one)."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            if f.default is not dataclasses.MISSING:
                return f.default
            if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
                return f.default_factory()  # type: ignore[misc]
            raise TypeError(f"{cls.__name__}.{name} has no default")
    raise TypeError(f"{cls.__name__} has no field {name!r}")


def option(flag: str, help: str, *, field: tuple[type, str] | None = None, default: Any = None,
           unit: str | None = None, metavar: str | None = None, names: Iterable[str] = (), **kw: Any) -> Any:
    """A ``typer.Option`` for ``flag``.

    ``field=(ConfigClass, "field_name")``: the default is that field's default (unless ``default``
    is given) and its unit (from the field name) is added to the help; ``field_name`` (and any
    ``names``, other Python names for the same setting) are recorded as set by ``flag`` so error
    messages can name the flag. ``default=...`` makes the option required."""
    import typer

    names = list(names)
    if field is not None:
        cls, name = field
        if default is None:
            default = field_default(cls, name)
        unit = unit or unit_of(name)
        names.append(name)
    for n in names:
        FLAG_OF_FIELD.setdefault(n, flag)
    if unit and f"[{unit}]" not in help:
        help = f"{help.rstrip('.')} [{unit}]."
    if metavar is None and not isinstance(default, bool):
        sample = default
        metavar = ("FLOAT" if isinstance(sample, float) else "INT" if isinstance(sample, int)
                   else "PATH" if isinstance(sample, Path) else "TEXT")
    return typer.Option(default, flag, help=help, metavar=metavar, **kw)


_NAME_RE_CACHE: dict[int, re.Pattern] = {}


def to_flags(message: str, flags: dict[str, str] | None = None) -> str:
    """Replace the Python names of settings in a library message by their flags:
    ``pass allow_float=True`` -> ``pass --allow-float``, ``set model.size_px=64`` ->
    ``set --size 64``, ``per_cell must be >= 1`` -> ``--per-cell must be >= 1``.

    Only names with an underscore, names written ``name=value`` and a name that starts a clause
    (``views must be one of …``) are replaced; a plain word such as ``logs`` in prose stays."""
    flags = FLAG_OF_FIELD if flags is None else flags
    if not flags:
        return message
    key = id(flags) ^ len(flags)
    pattern = _NAME_RE_CACHE.get(key)
    if pattern is None:
        alternatives = "|".join(re.escape(n) for n in sorted(flags, key=len, reverse=True))
        pattern = re.compile(rf"(?<![\w.\-/?&=])(?:[a-z_]+\.)?({alternatives})(?:=(True|False|[^\s,;)]+))?(?![\w])")
        _NAME_RE_CACHE.clear()
        _NAME_RE_CACHE[key] = pattern

    def sub(m: re.Match) -> str:
        name, value = m.group(1), m.group(2)
        starts = m.start() == 0 or message[max(0, m.start() - 2):m.start()] in ("; ", ": ")
        if "_" not in name and value is None and not (starts and message.startswith(" must", m.end())):
            return m.group(0)
        flag = flags[name]
        if value in (None, "True"):
            return flag
        if value == "False":
            return f"no {flag}"
        return f"{flag} {value}"

    return pattern.sub(sub, message)


# -- paths ---------------------------------------------------------------------------------------
#: path given on the command line -> its flag (filled by the checks; lets the handler name the flag
#: of a path an OSError names)
FLAG_OF_PATH: dict[str, str] = {}


def _note(path: Path, flag: str) -> None:
    FLAG_OF_PATH[str(path)] = flag
    try:
        FLAG_OF_PATH[str(path.resolve())] = flag
    except OSError:
        pass


def flag_of_path(filename: str | os.PathLike | None) -> str | None:
    """The flag whose path holds ``filename`` (the longest such path), if any."""
    if not filename:
        return None
    name = str(filename)
    candidates = [(p, f) for p, f in FLAG_OF_PATH.items()
                  if name == p or name.startswith(p.rstrip("/") + "/") or p.startswith(name.rstrip("/") + "/")]
    return max(candidates, key=lambda pf: len(pf[0]))[1] if candidates else None


def _first_existing(p: Path) -> Path:
    anc = p
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    return anc


def _check_creatable(p: Path, flag: str, what: str) -> None:
    anc = _first_existing(p.parent if p.name else p)
    if not anc.is_dir():
        raise CliError(f"{flag} {p}: {anc} is a file, so the {what} cannot be made there; choose another {flag}")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise CliError(f"{flag} {p}: no permission to write in {anc} (or it is read-only); choose another {flag}")


def check_output_dir(path: str | os.PathLike, flag: str) -> Path:
    """Fail now (creating nothing) when ``path`` cannot be an output folder."""
    p = Path(path)
    _note(p, flag)
    if str(path) == "":
        raise CliError(f"{flag} is empty; give a folder path")
    if p.exists() and not p.is_dir():
        raise CliError(f"{flag} {p} is a file, not a folder; choose a folder path")
    if p.is_dir():
        if not os.access(p, os.W_OK | os.X_OK):
            raise CliError(f"{flag} {p}: no permission to write in it (or it is read-only); choose another {flag}")
        return p
    _check_creatable(p, flag, "folder")
    return p


def check_output_file(path: str | os.PathLike, flag: str, suffix: str | None = None) -> Path:
    """Fail now (creating nothing) when ``path`` cannot be written as a file."""
    p = Path(path)
    _note(p, flag)
    if str(path) == "" or p.is_dir():
        raise CliError(f"{flag} {p} is a folder; give a file path" + (f" ending in {suffix}" if suffix else ""))
    if suffix and p.suffix.lower() != suffix:
        raise CliError(f"{flag} {p} must end in {suffix}")
    if p.exists() and not os.access(p, os.W_OK):
        raise CliError(f"{flag} {p}: no permission to overwrite it; choose another {flag}")
    _check_creatable(p, flag, "file")
    return p


def check_input(path: str | os.PathLike, flag: str, kind: str = "any") -> Path:
    """Fail now when input ``path`` does not exist (``kind``: ``file``, ``dir`` or ``any``)."""
    p = Path(path)
    _note(p, flag)
    if str(path) == "":
        raise CliError(f"{flag} is empty; give a path")
    if not p.exists():
        raise CliError(f"{flag} {p} does not exist")
    if kind == "file" and not p.is_file():
        raise CliError(f"{flag} {p} is a folder; give a file")
    if kind == "dir" and not p.is_dir():
        raise CliError(f"{flag} {p} is a file; give a folder")
    return p


# -- output ----------------------------------------------------------------------------------------
def dumps_json(obj: Any, indent: int | None = 1) -> str:
    """Strict JSON (NaN as ``null``); see :func:`synth.common.files.dumps_json`."""
    from synth.common.files import dumps_json as dumps

    return dumps(obj, indent=indent)


def versioned(fmt: str, obj: dict, version: str = "1.0") -> dict:
    """``obj`` with ``format`` and ``format_version`` first (kept if it has them already)."""
    if "format" in obj:
        return obj
    return {"format": fmt, "format_version": version, **obj}


class Output:
    """Where a command writes: results on stdout, progress and warnings on stderr.

    With ``as_json`` the human result lines go to stderr too and :meth:`result` writes the one
    JSON document on stdout."""

    def __init__(self, as_json: bool = False):
        self.as_json = as_json

    def say(self, text: str = "") -> None:
        """A result line for people (stdout; stderr under --json)."""
        stream = sys.stderr if self.as_json else sys.stdout
        print(text, file=stream, flush=True)

    def progress(self, text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    def warn(self, text: str) -> None:
        print(f"warning: {text}", file=sys.stderr, flush=True)

    def table(self, title: str, columns: list[str], rows: list[list[str]]) -> None:
        self.say(format_table(title, columns, rows))

    def result(self, fmt: str, obj: dict, version: str = "1.0") -> None:
        """The JSON document (only under --json)."""
        if self.as_json:
            sys.stdout.write(dumps_json(versioned(fmt, obj, version)) + "\n")
            sys.stdout.flush()


class LineProgress:
    """Progress for logs and pipes (standard error not a terminal): one line when a task starts,
    at most one every ``every_s`` seconds, and one when it ends. The subset of rich's ``Progress``
    API the commands use (``add_task``, ``update``, a context manager)."""

    def __init__(self, every_s: float = 10.0):
        import time

        self._time = time.monotonic
        self.every_s = every_s
        self.tasks: dict[int, dict] = {}

    def __enter__(self) -> "LineProgress":
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            for t in self.tasks.values():
                self._line(t)

    def add_task(self, description: str, total: float | None = None, info: str = "", **_: Any) -> int:
        k = len(self.tasks)
        self.tasks[k] = {"description": description, "total": total, "completed": 0, "info": info,
                         "t0": self._time(), "last": self._time()}
        return k

    def update(self, task: int, total: float | None = None, completed: float | None = None,
               info: str | None = None, **_: Any) -> None:
        t = self.tasks[task]
        if total is not None:
            t["total"] = total
        if completed is not None:
            t["completed"] = completed
        if info is not None:
            t["info"] = info
        if self._time() - t["last"] >= self.every_s:
            self._line(t)

    def _line(self, t: dict) -> None:
        state = (t["completed"], t["total"], t["info"])
        if t.get("printed") == state:
            return
        t["printed"] = state
        t["last"] = self._time()
        done = f"{t['completed']:g}" + (f"/{t['total']:g}" if t["total"] else "")
        info = f", {t['info']}" if t["info"] else ""
        print(f"{t['description']}: {done}{info} ({t['last'] - t['t0']:.0f} s)", file=sys.stderr, flush=True)


def progress_bar():
    """A progress display on standard error: rich's bar on a terminal, :class:`LineProgress` lines
    otherwise (logs, pipes)."""
    if not sys.stderr.isatty():
        return LineProgress()
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("{task.fields[info]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                    console=Console(stderr=True), transient=False)


def format_table(title: str, columns: list[str], rows: list[list[str]]) -> str:
    """A plain table: a title line, a header, aligned columns (text left, numbers right), never
    truncated and never wrapped inside a value."""
    cells = [[str(c) for c in row] for row in rows]
    widths = [max([len(c)] + [len(r[i]) for r in cells if i < len(r)]) for i, c in enumerate(columns)]

    def numeric(i: int) -> bool:
        vals = [r[i] for r in cells if i < len(r) and r[i] not in ("", "-")]
        return bool(vals) and all(re.fullmatch(r"[-+]?[\d.,]+(e[-+]?\d+)?%?", v) for v in vals)

    right = [numeric(i) for i in range(len(columns))]

    def line(vals: list[str]) -> str:
        return "  ".join(v.rjust(w) if r else v.ljust(w) for v, w, r in zip(vals, widths, right)).rstrip()

    out = [title] if title else []
    out.append(line(list(columns)))
    out.append("  ".join("-" * w for w in widths))
    out += [line(r + [""] * (len(columns) - len(r))) for r in cells]
    return "\n".join(out)


def plural(n: int, word: str, many: str | None = None) -> str:
    """``1 pile``, ``2 piles``."""
    return f"{n} {word if n == 1 else (many or word + 's')}"


# -- C libraries' output ------------------------------------------------------------------------------
def quiet_c_streams() -> None:
    """Send what C libraries print on file descriptors 1 and 2 (pybullet's build time, EGL /
    OpenGL driver lines, libpng) to ``/dev/null``; Python's ``sys.stdout`` and ``sys.stderr``
    go on writing to the original destinations through duplicated descriptors. Called once by
    the ``loggrasp`` entry point unless ``--verbose``."""
    sys.stdout.flush()
    sys.stderr.flush()
    out_fd, err_fd = os.dup(1), os.dup(2)
    for fd in (out_fd, err_fd):
        os.set_inheritable(fd, False)
    enc_out, enc_err = sys.stdout.encoding or "utf-8", sys.stderr.encoding or "utf-8"
    sys.stdout = os.fdopen(out_fd, "w", buffering=1 if os.isatty(out_fd) else -1, encoding=enc_out,
                           errors="replace")
    sys.stderr = os.fdopen(err_fd, "w", buffering=1, encoding=enc_err, errors="backslashreplace")
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    os.close(devnull)
