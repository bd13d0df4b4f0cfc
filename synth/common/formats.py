"""The one reader and writer of loggrasp's versioned JSON files.

Every file loggrasp writes names its ``format`` (``"loggrasp.pile"``) and ``format_version``
(``"1.2"``, major.minor). A reader accepts every minor version of its own major one and refuses
a file of another major version with one line that names the file, what it is and what to do::

    PILE = VersionedJson("loggrasp.pile", "1.0", "pile", PileFormatError,
                         fix="upgrade loggrasp or re-export the pile", filename="pile.json")
    PILE.write(path, body)      # {"format", "format_version", **body}, atomically
    d = PILE.read(path)         # a dict; PileFormatError when missing, not JSON, foreign, newer

Files whose JSON sits inside something else (the metadata of an ``.npz``, a gzip chunk, the
``loggrasp`` member of a GeoJSON) are opened by their own module and checked with
:meth:`VersionedJson.check`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from synth.common.files import atomic_write_bytes


def major(version: Any) -> str:
    """The major part of a ``major.minor`` version (``"1.2"`` -> ``"1"``)."""
    return str(version).split(".")[0]


@dataclass(frozen=True)
class VersionedJson:
    """A versioned JSON format: its name, the version this code writes, and how it fails."""

    name: str  # the "format" value, e.g. "loggrasp.pile"
    version: str  # the "format_version" written; files of the same major version are read
    what: str  # what a file of this format is, for messages ("pile", "trial record")
    error: type[Exception]  # the caller's error class, raised with a one-line message
    fix: str = "upgrade loggrasp"  # what to do about a file of another major version
    unreadable_fix: str = ""  # what to do about a missing or corrupt file ("" : nothing said)
    filename: str | None = None  # the file's name inside a folder: read(folder) reads folder/filename

    @property
    def major(self) -> str:
        return major(self.version)

    def path(self, path: str | Path) -> Path:
        """``path``, or ``path / filename`` when ``path`` is a folder."""
        path = Path(path)
        return path / self.filename if self.filename and path.is_dir() else path

    # -- checking --------------------------------------------------------------------------------
    def _fail(self, message: str) -> Exception:
        return self.error(message)

    def check_version(self, version: Any, path: str | Path | None = None) -> None:
        """Raise :attr:`error` unless ``version`` has this format's major version."""
        if major(version) == self.major:
            return
        newer = major(version).isdigit() and self.major.isdigit() and int(major(version)) > int(self.major)
        where = f"{path}: " if path is not None else ""
        raise self._fail(f"{where}{self.what} format version {version!r} is not supported (this loggrasp reads "
                         f"{self.major}.x{'; the file is newer' if newer else ''}); {self.fix}")

    def check(self, doc: Any, path: str | Path | None = None) -> dict:
        """``doc`` itself when it is a dict of this format and major version; else :attr:`error`."""
        where = f"{path}: " if path is not None else ""
        if not isinstance(doc, dict) or doc.get("format") != self.name:
            found = f"format {doc.get('format')!r}" if isinstance(doc, dict) else f"a JSON {type(doc).__name__}"
            raise self._fail(f"{where}not a loggrasp {self.what} ({found}, expected format {self.name!r})")
        self.check_version(doc.get("format_version", ""), path)
        return doc

    # -- reading and writing ---------------------------------------------------------------------
    def read(self, path: str | Path, *, decode: Callable[[bytes], bytes] | None = None) -> dict:
        """Read, parse and :meth:`check` the file at ``path`` (a folder: its :attr:`filename`).

        ``decode`` turns the file's bytes into JSON bytes (e.g. ``gzip.decompress``)."""
        path = self.path(path)
        fix = f"; {self.unreadable_fix}" if self.unreadable_fix else ""
        try:
            raw = path.read_bytes()
            if decode is not None:
                raw = decode(raw)
        except FileNotFoundError as exc:
            raise self._fail(f"cannot read {self.what} {path}: the file is missing{fix}") from exc
        except (OSError, EOFError, ValueError) as exc:
            raise self._fail(f"cannot read {self.what} {path}: {getattr(exc, 'strerror', None) or exc}{fix}") from exc
        try:
            doc = json.loads(raw)
        except (ValueError, UnicodeDecodeError) as exc:
            raise self._fail(f"cannot read {self.what} {path}: it is not valid JSON ({exc}){fix}") from exc
        return self.check(doc, path)

    def document(self, body: dict) -> dict:
        """``body`` with ``format`` and ``format_version`` first (``body``'s own ones replaced)."""
        return {"format": self.name, "format_version": self.version,
                **{k: v for k, v in body.items() if k not in ("format", "format_version")}}

    def dumps(self, body: dict, indent: int | None = 1, **kw: Any) -> str:
        return json.dumps(self.document(body), indent=indent, **kw)

    def write(self, path: str | Path, body: dict, indent: int | None = 1, **kw: Any) -> Path:
        """Write :meth:`document` of ``body`` to ``path`` (a folder: its :attr:`filename`)
        atomically; ``kw`` go to :func:`json.dumps`. Returns the path written."""
        path = self.path(path)
        atomic_write_bytes(path, self.dumps(body, indent=indent, **kw).encode())
        return path
