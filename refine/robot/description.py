"""A robot description as users have it: a URDF or a xacro, with ROS package references resolved.

ROS-Industrial support packages describe an arm as a xacro (macros, ``$(find pkg)`` includes) whose
meshes are named ``package://pkg/...``. :func:`resolve_description` expands such a file with xacrodoc
and writes the plain URDF, every mesh an absolute file path, to a cache folder; a plain URDF without
package references is used as it stands.

A package is the folder whose ``package.xml`` names it. It is looked for, nearest first, in the
description's own folder and every folder above it, and in the folders beside each of these (support
packages sit side by side, as in a ROS workspace's ``src/``: ``fanuc_m20ia_support`` next to
``fanuc_resources``); ``packages`` names folders for packages found nowhere there (``[robot]
packages`` in a problem file).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path

from lxml import etree

from refine.errors import InputError

CACHE_FOLDER = "refine-descriptions"
"""The folder under the system's temporary folder that holds expanded descriptions."""

_REFERENCES = ("package://", "$(find", "xmlns:xacro", "<xacro:")


def needs_expansion(path: str | Path) -> bool:
    """Whether a description must go through xacro: a ``.xacro`` file, or one naming ROS packages."""
    path = Path(path)
    if path.suffix == ".xacro":
        return True
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read robot description {path}: {e}") from e
    return any(token in text for token in _REFERENCES)


def package_name(folder: Path) -> str | None:
    """The name a folder's ``package.xml`` gives its package; None without one (or unreadable)."""
    manifest = folder / "package.xml"
    if not manifest.is_file():
        return None
    try:
        name = etree.parse(str(manifest)).getroot().findtext("name")
    except (OSError, etree.XMLSyntaxError):
        return None
    return name.strip() if name else None


def search_folders(description: Path) -> list[Path]:
    """The folders searched for packages, nearest first: the description's folder and those above it."""
    return [description.parent, *description.parent.parents]


def find_packages(description: str | Path) -> dict[str, Path]:
    """Every package in the folders above ``description`` and beside them, the nearest of each name.

    Each folder of :func:`search_folders` is a package when its ``package.xml`` says so, and so is
    each folder directly inside it; a name found twice keeps the folder nearer the description.
    """
    found: dict[str, Path] = {}
    for folder in search_folders(Path(description).resolve()):
        candidates = [folder]
        try:
            candidates += sorted(p for p in folder.iterdir() if p.is_dir())
        except OSError:  # an unreadable folder holds nothing we can use
            pass
        for candidate in candidates:
            name = package_name(candidate)
            if name and name not in found:
                found[name] = candidate
    return found


def package_folders(value: object, root: Path) -> tuple[tuple[str, Path], ...]:
    """``[robot] packages`` checked: (ROS package name, its folder resolved against ``root``) pairs.

    Raises:
        InputError: the value is no table, a name is no package name, or a folder is missing.
    """
    if not isinstance(value, dict):
        raise InputError(f'robot.packages must be a table {{ package = "folder" }}, got {value!r}')
    out = []
    for name, folder in value.items():
        if not re.fullmatch(r"[A-Za-z0-9_-]{1,128}", str(name)):
            raise InputError(
                f"robot.packages: {name!r} is not a ROS package name (letters, digits, '_', '-')"
            )
        if not isinstance(folder, str) or not folder:
            raise InputError(
                f"robot.packages.{name} must be a folder relative to the problem folder, got {folder!r}"
            )
        resolved = (root / folder).resolve()
        if not resolved.is_dir():
            raise InputError(f"robot.packages.{name} = {folder!r}: not a folder at {resolved}")
        out.append((str(name), resolved))
    return tuple(out)


def resolve_description(path: str | Path, packages: Mapping[str, str | Path] | None = None) -> Path:
    """The plain URDF of a robot description, every mesh named by an absolute path.

    Args:
        path: a ``.urdf`` or ``.xacro`` file.
        packages: package name -> folder for packages not found beside the description; they take
            precedence over the ones found.

    Returns:
        ``path`` itself when it is a URDF with no package reference; else the expanded URDF, written
        once per content to ``<temp>/refine-descriptions/<stem>-<hash>.urdf``.

    Raises:
        InputError: the file is missing or unreadable, a package is found nowhere (the message names
            it and where it was looked for), a given package folder is missing, or xacro fails.
    """
    path = Path(path).resolve()
    if not path.is_file():
        raise InputError(f"robot description not found: {path}")
    if not needs_expansion(path):
        return path
    given = {}
    for name, folder in (packages or {}).items():
        folder = Path(folder).resolve()
        if not folder.is_dir():
            raise InputError(f"robot.packages.{name} = {str(folder)!r}: not a folder")
        given[name] = folder
    found = {**find_packages(path), **given}
    text = _expand(path, found, given)
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
    stem = path.name.split(".")[0]
    out = Path(tempfile.gettempdir()) / CACHE_FOLDER / f"{stem}-{digest}.urdf"
    if not out.is_file():
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(
            "w", dir=out.parent, suffix=".part", delete=False, encoding="utf-8"
        ) as f:
            f.write(text)
        os.replace(f.name, out)  # atomic: a concurrent reader sees the whole file or none
    return out


def _expand(path: Path, found: dict[str, Path], given: dict[str, Path]) -> str:
    """The URDF text of ``path`` expanded by xacrodoc with the packages ``found``."""
    from xacrodoc import XacroDoc
    from xacrodoc import packages as xacro_packages

    xacro_packages.reset()
    xacro_packages.update_package_cache({name: str(folder) for name, folder in found.items()})
    try:
        doc = XacroDoc.from_file(str(path), walk_up=False)
        text = doc.to_urdf_string(use_protocols=False)
    except Exception as e:  # xacro raises its own kinds and wraps the package finder's
        missing = _missing_package(e)
        if missing is not None:
            above = ", ".join(str(f) for f in search_folders(path))
            raise InputError(
                f"robot description {path}: package {missing!r} not found: no package.xml naming it in "
                f"the folders above the description or beside them ({above}), nor in [robot] packages "
                f"({', '.join(f'{k} = {v}' for k, v in given.items()) or 'none given'}); give its folder "
                f'as [robot] packages = {{ {missing} = "path/to/{missing}" }}'
            ) from e
        raise InputError(f"robot description {path}: xacro cannot expand it: {e}") from e
    finally:
        xacro_packages.reset()
    leftover = re.findall(r'filename="([a-z]+://[^"]*)"', text)
    if leftover:
        raise InputError(f"robot description {path}: file URLs left after expansion: {', '.join(leftover)}")
    return text


def _missing_package(error: BaseException) -> str | None:
    """The package a xacro or xacrodoc error says is missing, from the error and its causes."""
    seen: BaseException | None = error
    while seen is not None:
        if type(seen).__name__ == "PackageNotFoundError" and seen.args:
            return str(seen.args[0])
        match = re.search(r"Package not found: (\S+)", str(seen))
        if match:
            return match.group(1)
        seen = seen.__cause__ or seen.__context__
    return None
