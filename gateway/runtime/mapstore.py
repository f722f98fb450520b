"""Where maps and scenarios come from: name resolution and MovingAI downloads (DESIGN section 2).

A map or scenario argument is a path to an existing file, or a name. Names resolve, in order,
in ``--maps-dir``, in each folder of ``$FLEETGATE_MAPS`` (``os.pathsep``-separated), in the user
cache ``~/.cache/fleetgate/maps`` and in the maps the project ships
(``gateway/planning/maps``). A map name ``NAME`` is the file ``NAME.map``; a scenario name is
``NAME.scen``, also looked for in the ``scen``, ``scen-random`` and ``scen-even`` subfolders.
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import gateway.planning
from fleetgate.userio.files import make_folder, write_bytes
from gateway.runtime.exits import UsageError

Kind = Literal["map", "scen"]
KINDS: tuple[Kind, ...] = ("map", "scen")

ENV_MAPS = "FLEETGATE_MAPS"
"""Environment variable with extra map folders."""
ENV_BASE_URL = "FLEETGATE_MAPS_URL"
"""Environment variable overriding :data:`DEFAULT_BASE_URL`."""
DEFAULT_BASE_URL = "https://movingai.com/benchmarks/mapf/"
"""The MovingAI MAPF benchmark: ``NAME.map.zip``, ``NAME.map-scen-random.zip``, ``-even``."""
SHIPPED_DIR = Path(gateway.planning.__file__).resolve().parent / "maps"
"""The maps the project ships."""
SCEN_SUBDIRS = ("", "scen", "scen-random", "scen-even")
"""Subfolders of a map folder where scenario names are looked for."""
SCEN_KINDS = ("random", "even")
"""The MovingAI scenario sets."""

_SCEN_NAME = re.compile(r"^(?P<map>.+)-(?P<kind>random|even)-\d+$")


class MapNotFound(LookupError):
    """A map or scenario name resolves nowhere (the message says where it looked;
    ``public`` says the same without the folders, for a browser)."""

    def __init__(self, message: str, public: str | None = None) -> None:
        super().__init__(message)
        self.public = public or message


class DownloadError(RuntimeError):
    """A download failed or its archive held nothing usable."""


@dataclass(frozen=True)
class MapDir:
    """A folder that names resolve in, with where it came from (``--maps-dir``, ``cache`` ...)."""

    origin: str
    path: Path


def cache_dir() -> Path:
    """The user cache of downloaded maps: ``~/.cache/fleetgate/maps``."""
    return Path.home() / ".cache" / "fleetgate" / "maps"


def search_dirs(maps_dir: str | Path | None = None,
                environ: Mapping[str, str] | None = None) -> list[MapDir]:
    """The folders names resolve in, first match wins. UsageError if ``maps_dir`` (a user's
    ``--maps-dir``) is no folder: a typo there would silently fall through to the others."""
    if maps_dir and not Path(maps_dir).is_dir():
        raise UsageError(f"--maps-dir {maps_dir} is no folder")
    env = os.environ if environ is None else environ
    dirs = [MapDir("--maps-dir", Path(maps_dir))] if maps_dir else []
    dirs += [MapDir(f"${ENV_MAPS}", Path(p)) for p in env.get(ENV_MAPS, "").split(os.pathsep)
             if p]
    dirs += [MapDir("cache", cache_dir()), MapDir("shipped", SHIPPED_DIR)]
    return dirs


def _candidates(name: str, kind: Kind, folder: Path) -> list[Path]:
    file = name if name.endswith(f".{kind}") else f"{name}.{kind}"
    subdirs = SCEN_SUBDIRS if kind == "scen" else ("",)
    return [folder / sub / file for sub in subdirs]


def resolve(name: str | Path, kind: Kind, maps_dir: str | Path | None = None,
            environ: Mapping[str, str] | None = None) -> Path:
    """The file a map (``kind="map"``) or scenario (``"scen"``) argument stands for.

    An existing file wins; an argument with a folder in it must be one. Raises
    :class:`MapNotFound` otherwise.
    """
    text = str(name)
    if Path(text).is_file():
        return Path(text)
    if not text or os.sep in text or "/" in text:
        raise MapNotFound(f"{kind} file {text!r} does not exist")
    dirs = search_dirs(maps_dir, environ)
    for d in dirs:
        for candidate in _candidates(text, kind, d.path):
            if candidate.is_file():
                return candidate
    if text.endswith(f".{kind}"):  # a file name, not a name to download
        raise MapNotFound(f"{kind} file {text!r} does not exist")
    where = ", ".join(f"{d.path} ({d.origin})" for d in dirs)
    hint = "; try 'fleetgate maps download NAME'" if kind == "map" else ""
    raise MapNotFound(f"no {kind} named {text!r} in {where}{hint}",
                      f"no {kind} named {text!r} on the gateway")


@dataclass(frozen=True)
class Available:
    """One file that a name resolves to, or that an earlier folder shadows."""

    name: str
    kind: Kind
    path: Path
    origin: str
    shadowed: bool


def available(maps_dir: str | Path | None = None,
              environ: Mapping[str, str] | None = None) -> list[Available]:
    """Every map and scenario in the search folders, in resolution order."""
    seen: set[tuple[str, Kind]] = set()
    out: list[Available] = []
    for d in search_dirs(maps_dir, environ):
        for kind in KINDS:
            subdirs = SCEN_SUBDIRS if kind == "scen" else ("",)
            for sub in subdirs:
                folder = d.path / sub
                for path in sorted(folder.glob(f"*.{kind}")) if folder.is_dir() else []:
                    key = (path.stem, kind)
                    out.append(Available(path.stem, kind, path, d.origin, key in seen))
                    seen.add(key)
    return out


def archive_names(name: str, with_scen: bool = True) -> list[str]:
    """The MovingAI archives for a map name, or for the map of a scenario name."""
    match = _SCEN_NAME.match(name)
    map_name = match["map"] if match else name.removesuffix(".map")
    names = [f"{map_name}.map.zip"]
    if with_scen:
        names += [f"{map_name}.map-scen-{kind}.zip" for kind in SCEN_KINDS]
    return names


def _fetch(url: str, timeout: float) -> bytes:
    import urllib.error  # the network stack only when a download needs it
    import urllib.request

    try:
        with urllib.request.urlopen(url, timeout=timeout) as response:
            data: bytes = response.read()
            return data
    except urllib.error.HTTPError as exc:
        raise DownloadError(f"download of {url} failed: HTTP {exc.code} {exc.reason}") from exc
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise DownloadError(f"download of {url} failed: {reason}") from exc


def archive_members(data: bytes, source: str = "archive") -> list[tuple[str, bytes]]:
    """The ``.map`` and ``.scen`` files of a zip as ``(base name, content)``; folders inside
    the archive are dropped. Raises :class:`DownloadError` if there is none."""
    import zipfile

    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except zipfile.BadZipFile as exc:
        raise DownloadError(f"{source} is not a zip archive") from exc
    with archive:
        members = [(Path(m.filename).name, archive.read(m)) for m in archive.infolist()
                   if not m.is_dir() and m.filename.endswith((".map", ".scen"))
                   and not Path(m.filename).name.startswith(".")]
    if not members:
        raise DownloadError(f"{source} holds no .map or .scen file")
    return members


def store_members(members: list[tuple[str, bytes]], dest: Path) -> list[Path]:
    """Write maps into ``dest`` and scenarios into ``dest/scen``; returns the files written."""
    written: list[Path] = []
    for base, content in members:
        folder = dest / "scen" if base.endswith(".scen") else dest
        make_folder(folder)
        write_bytes(folder / base, content)
        written.append(folder / base)
    return written


def download(name: str, base_url: str | None = None, dest: Path | None = None,
             with_scen: bool = True, timeout: float = 60.0,
             environ: Mapping[str, str] | None = None) -> list[Path]:
    """Fetch a MovingAI map (and its scenario sets) and extract it into ``dest`` (the cache).

    ``base_url`` defaults to ``$FLEETGATE_MAPS_URL``, then :data:`DEFAULT_BASE_URL`. Every
    archive is fetched and opened before anything is written, so a failed download leaves the
    cache as it was. Raises :class:`DownloadError`.
    """
    env = os.environ if environ is None else environ
    base = base_url or env.get(ENV_BASE_URL) or DEFAULT_BASE_URL
    base = base if base.endswith("/") else base + "/"
    members: list[tuple[str, bytes]] = []
    for archive in archive_names(name, with_scen):
        url = base + archive
        members += archive_members(_fetch(url, timeout), url)
    return store_members(members, dest or cache_dir())
