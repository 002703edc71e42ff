"""Import formats by name: each importer registers its loader with a detector.

An importer module decorates its ``load(path, **options) -> ImportedSamples``
with `register_import`, giving the format's name and a ``detect(path,
document)`` that says whether a path is in that format (``document()`` returns
the file's YAML, parsed once for all detectors). `IMPORTER_MODULES` lists
the importer modules; adding a format is one new module plus its name there
(docs/architecture.md has a worked example).
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import yaml

from handeye.app.errors import SessionError
from handeye.app.files import read_text_file
from handeye.app.formats.common import ImportedSamples

#: Importer modules of `handeye.app.formats`, in the order their formats are tried on a file.
#: opencv_storage comes first: its ``%YAML:1.0`` header is not YAML the others' detectors could parse.
IMPORTER_MODULES = ("opencv_storage", "pose_csv", "easy_handeye", "industrial", "visp", "image_folder", "moveit",
                    "ros2_bag")


@dataclass(frozen=True)
class ImportFormat:
    """A registered import format.

    Attributes
    ----------
    name : str
    load : callable(path, **options) -> ImportedSamples
    detect : callable(path, document) -> bool
        ``document()`` is the file's YAML (`SessionError` if unreadable).
    open_setup : bool
        The files may leave the setup open: ``load`` then takes ``setup=``.
    options : tuple of str
        Keyword options ``load`` takes from the caller's config and command line
        (e.g. ``frames``, ``target``); `handeye.app.devices.import_observations` passes only these.
    """

    name: str
    load: Callable[..., ImportedSamples]
    detect: Callable[[Path, Callable[[], object]], bool]
    open_setup: bool = False
    options: tuple[str, ...] = ()


_FORMATS: dict[str, ImportFormat] = {}


def register_import(name: str, detect: Callable[[Path, Callable[[], object]], bool], *, open_setup: bool = False,
                    options: tuple[str, ...] = ()):
    """Decorator for an importer's ``load``: register it as import format ``name``."""

    def decorate(load):
        _FORMATS[name] = ImportFormat(name, load, detect, open_setup, tuple(options))
        return load

    return decorate


def import_formats() -> dict[str, ImportFormat]:
    """Every registered import format by name, in the order of `IMPORTER_MODULES` (importing the importer modules
    on first use). The order is that list's whatever imported a format's module before: `detect_format` tries
    them in it, and ``opencv_storage`` tried after a detector that parses YAML loses its files."""
    for module in IMPORTER_MODULES:
        importlib.import_module(f"handeye.app.formats.{module}")
    rank = {f"handeye.app.formats.{module}": i for i, module in enumerate(IMPORTER_MODULES)}
    return dict(sorted(_FORMATS.items(), key=lambda item: rank.get(item[1].load.__module__, len(rank))))


def detect_format(path) -> str:
    """Name of the import format of ``path``; `SessionError` if none recognises it."""
    path = Path(path)
    formats = import_formats()

    @functools.cache
    def document():
        try:
            return yaml.safe_load(read_text_file(path, SessionError))
        except (yaml.YAMLError, RecursionError, ValueError) as e:
            raise SessionError(f"{path}: cannot read ({str(e)[:200]})") from None

    for fmt in formats.values():
        if fmt.detect(path, document):
            return fmt.name
    known = f"a handeye session (a directory with session.json), or {', '.join(formats)}"
    if path.is_dir():
        raise SessionError(f"{path}: directory holds no known sample format; known: {known}")
    raise SessionError(f"{path}: not a known sample format; known: {known}")


def get_format(name: str) -> ImportFormat:
    """The import format called ``name``; `SessionError` naming the known ones otherwise."""
    formats = import_formats()
    if name not in formats:
        raise SessionError(f"unknown import format {name!r} (use one of {list(formats)})")
    return formats[name]
