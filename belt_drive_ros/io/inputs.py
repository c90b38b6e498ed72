"""Bounded reading of files that come from outside: scenes, campaign files, profiles, parameter files.

Every user's file is read through :func:`read_text` (regular files only, never blocking on a FIFO, at most
``limit`` bytes, strict UTF-8), every YAML text through :func:`parse_yaml` (no aliases, anchors or merge keys,
nesting at most :data:`MAX_DEPTH`, duplicate keys an error, YAML 1.2's core schema: ``1e1`` a float, ``'2e4'`` a
string, ``0400`` the decimal 400, ``1:30``, ``20_000`` and ``yes`` strings). Standard library and PyYAML only, so that :mod:`msg_tools` can use it. Errors are one-line
:class:`~belt_drive_ros.core.errors.InputError`, naming the file, values quoted through
:func:`~belt_drive_ros.core.errors.short`.
"""

from __future__ import annotations

import math
import os
import re
import stat
from typing import Any

import yaml

from ..core.errors import MAX_INT, InputError, short

__all__ = ["MAX_DEPTH", "SCENE_LIMIT", "InputError", "check_path", "input_replaced", "open_regular", "parse_yaml",
           "read_text", "read_yaml", "still_at"]

#: largest scene / parameter YAML file [bytes]; the shipped scenes are ~2 kB
SCENE_LIMIT = 1 << 20
#: deepest nesting of YAML collections (a scene needs 4: schedule -> active -> harmonics -> value)
MAX_DEPTH = 32


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def check_path(path: str | os.PathLike, what: str = "file", folder: bool = False) -> os.stat_result:
    """``os.stat`` of ``path`` when it is a regular file (or, with ``folder``, a directory), else :class:`InputError`:
    the check before every ``open()`` of a user's path (a FIFO blocks ``open``, ``/dev/zero`` never ends)."""
    label = f"{what} {short(os.fspath(path), 200)}"
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{label}: not found") from None
    except OSError as exc:
        raise InputError(f"{label}: {exc.strerror or exc}") from None
    except ValueError as exc:  # a NUL byte; str with unpaired surrogates (UnicodeEncodeError)
        reason = "a NUL byte in the name" if "null" in str(exc) else "a name that cannot be encoded"
        raise InputError(f"{label}: not a usable path ({reason})") from None
    if stat.S_ISREG(st.st_mode) or (folder and stat.S_ISDIR(st.st_mode)):
        return st
    need = "a regular file or a folder" if folder else "a regular file"
    raise InputError(f"{label}: {_kind(st.st_mode)}; {need} is needed")


def input_replaced(output: str | os.PathLike, inputs, folder: bool = False) -> str | None:
    """The first of ``inputs`` (paths; None and missing ones skipped) that writing ``output`` would replace: the same
    file or folder (``os.path.samefile``: links and other spellings too), or, when ``output`` is a folder written
    whole (``folder``: a bag folder), one inside it; else None. An output never replaces an input of its own run,
    --force or not (a run written over the bag it reads loses the bag)."""
    try:
        if not os.path.exists(output):
            return None
        inside = os.path.realpath(output).rstrip(os.sep) + os.sep
        for given in inputs:
            if given is None or not os.path.exists(given):
                continue
            if os.path.samefile(output, given) or (folder and os.path.realpath(given).startswith(inside)):
                return os.fspath(given)
    except (OSError, ValueError):  # (a path that cannot be looked at is refused by the output's own checks)
        return None
    return None


def open_regular(path: str | os.PathLike, what: str = "file") -> int:
    """A read-only descriptor of the regular file ``path`` (the caller closes it), opened with ``O_NONBLOCK`` and
    checked again on the descriptor (a file swapped for a FIFO after :func:`check_path` cannot block either)."""
    check_path(path, what)
    label = f"{what} {short(os.fspath(path), 200)}"
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputError(f"{label}: {exc.strerror or exc}") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):  # swapped between stat and open
        os.close(fd)
        raise InputError(f"{label}: {_kind(st.st_mode)}; a regular file is needed")
    return fd


def still_at(fd: int, path: str | os.PathLike) -> bool:
    """True when the file open as ``fd`` is the one at ``path`` now (same device and inode; a symbolic link at
    ``path`` is not followed, so a link to it is another file), False when ``path`` is gone or is another file.

    A lock taken with ``flock`` on a file another process may remove or replace (a ``.part`` file, a bag folder's
    lock file) holds only while the file is still at its path: the one check of every such lock."""
    try:
        st = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


def read_text(path: str | os.PathLike, what: str = "file", limit: int = SCENE_LIMIT) -> str:
    """UTF-8 text of the regular file ``path``, at most ``limit`` bytes (never more than ``limit + 1`` read);
    :class:`InputError` if it is missing, not a regular file, larger, unreadable or not UTF-8."""
    label = f"{what} {short(os.fspath(path), 200)}"
    st = check_path(path, what)
    if st.st_size > limit:
        raise InputError(f"{label}: {st.st_size} bytes, more than the limit of {limit} bytes")
    fd = open_regular(path, what)
    try:
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 16, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise InputError(f"{label}: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if size > limit:
        raise InputError(f"{label}: more than the limit of {limit} bytes")
    data = b"".join(chunks)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{label}: not UTF-8 text (byte {exc.start}: {short(data[exc.start:exc.start + 4])})") from None


# ------------------------------------------------------------------ YAML
#: the plain scalars YAML 1.2's core schema reads as numbers, booleans and null (PyYAML's SafeLoader reads YAML 1.1's:
#: ``0400`` octal 256, ``1:30`` sexagesimal 90, ``20_000`` 20000, ``yes``/``off`` booleans, ``1e5`` a string); every
#: other plain scalar is a string, which a number's check then names
_INT_12 = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
_FLOAT_12 = re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")
_BOOL_12 = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
_NULL_12 = re.compile(r"^(?:~|null|Null|NULL|)$")


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader without aliases/anchors/merge keys, with a depth limit and duplicate keys refused."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise InputError(f"line {event.start_mark.line + 1}: YAML aliases (*{short(event.anchor, 40)}) are not allowed")
        event = self.peek_event()
        if getattr(event, "anchor", None) is not None:
            raise InputError(f"line {event.start_mark.line + 1}: YAML anchors (&{short(event.anchor, 40)}) are not allowed")
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > MAX_DEPTH:
                raise InputError(f"line {event.start_mark.line + 1}: nested deeper than {MAX_DEPTH} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        if not isinstance(node, yaml.MappingNode):
            return super().construct_mapping(node, deep=deep)
        seen: dict = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                raise InputError(f"line {key_node.start_mark.line + 1}: YAML merge keys (<<) are not allowed")
            key = self.construct_object(key_node, deep=True)
            try:
                hash(key)
            except TypeError:
                raise InputError(f"line {key_node.start_mark.line + 1}: a mapping key must be a plain value") from None
            if key in seen:
                raise InputError(
                    f"line {key_node.start_mark.line + 1}: duplicate key {short(key, 40)} "
                    f"(first on line {seen[key] + 1})"
                )
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)


def _construct_int(loader, node):
    """A YAML 1.2 integer: decimal (leading zeros too: ``0400`` is 400), ``0o`` octal, ``0x`` hexadecimal."""
    text = str(loader.construct_scalar(node))
    try:
        value = int(text[2:], 8) if text.startswith("0o") else int(text, 16) if text.startswith("0x") else int(text, 10)
    except ValueError:  # more than 4300 digits: Python refuses to convert the text at all (or an explicit !!int tag
        value = math.inf  # on no integer)
    if abs(value) > MAX_INT:
        raise InputError(f"line {node.start_mark.line + 1}: integer {short(node.value, 40)} is too large (|n| > 2^63)")
    return value


def _construct_float(loader, node):
    """A YAML 1.2 float (``.inf``, ``-.inf``, ``.nan`` included)."""
    text = str(loader.construct_scalar(node)).lower()
    if text.lstrip("+-") == ".inf":
        return -math.inf if text.startswith("-") else math.inf
    if text == ".nan":
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise InputError(f"line {node.start_mark.line + 1}: {short(node.value, 40)} is not a number") from None


#: YAML 1.2's core schema for plain scalars, in place of SafeLoader's YAML 1.1 resolvers of ints, floats, booleans and
#: null (strings, timestamps are strings too: no resolver of a type the files do not use)
_BoundedLoader.yaml_implicit_resolvers = {}
for _tag, _pattern, _first in (
    ("tag:yaml.org,2002:bool", _BOOL_12, list("tTfF")),
    ("tag:yaml.org,2002:int", _INT_12, list("-+0123456789")),
    ("tag:yaml.org,2002:float", _FLOAT_12, list("-+.0123456789")),
    ("tag:yaml.org,2002:null", _NULL_12, ["~", "n", "N", ""]),
    ("tag:yaml.org,2002:merge", re.compile(r"^(?:<<)$"), ["<"]),  # (found to be refused: construct_mapping)
):
    _BoundedLoader.add_implicit_resolver(_tag, _pattern, _first)
_BoundedLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)
_BoundedLoader.add_constructor("tag:yaml.org,2002:float", _construct_float)


def parse_yaml(text: str, label: str = "YAML") -> Any:
    """Data of the YAML ``text`` under the bounded rules of this module; :class:`InputError` starting with
    ``label`` for a syntax error (PyYAML's first line), aliases, anchors, merge keys, nesting deeper than
    :data:`MAX_DEPTH`, duplicate keys or more than one document."""
    try:
        loader = _BoundedLoader(text)
        try:
            return loader.get_single_data()
        finally:
            loader.dispose()
    except InputError as exc:
        raise InputError(f"{label}: {exc}") from None
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise InputError(f"{label}: not valid YAML: {short(first, 160)}{where}") from None
    except RecursionError:
        raise InputError(f"{label}: nested too deeply") from None


def read_yaml(path: str | os.PathLike, what: str = "YAML file", limit: int = SCENE_LIMIT) -> Any:
    """:func:`read_text` then :func:`parse_yaml` (errors name the file)."""
    text = read_text(path, what, limit)
    return parse_yaml(text, f"{what} {short(str(path), 200)}")
