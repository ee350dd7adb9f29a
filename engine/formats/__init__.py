"""File formats: BVH (:mod:`.bvh`), glTF 2.0 / GLB characters (:mod:`.gltf`) and FBX scenes
(:mod:`.fbx`), and the one place that decides which of them a file is.

:data:`FORMATS` is the registry: per format its name, the suffixes it writes, a sniffer of a
file's first bytes, its reader and writer, and what it can hold. Everything outside this
package reads and writes through the functions here and never looks at a suffix itself:

* reading goes by **content**, never by the file's name: BVH is text starting with
  ``HIERARCHY`` (after an optional UTF-8 byte-order mark and blank space), glTF JSON is a JSON
  object with an ``"asset"`` member, GLB starts with the magic ``b"glTF"``. So a ``.vrm``
  avatar (a GLB) reads as glTF and a BVH saved as ``.txt`` reads as BVH. FBX is binary
  (``Kaydara FBX Binary``) or ASCII text (a ``; FBX`` comment or ``FBXHeaderExtension``). Only
  the first :data:`HEAD_BYTES` bytes are looked at; anything else raises
  :class:`~engine.errors.UnknownFormatError` naming the formats known.
* an FBX file is a character (its bind pose is :func:`read_motion`'s target) that may hold
  takes: :func:`read_performer` (and ``take=NAME`` anywhere) picks one, by default the first
  that moves a joint.
* writing goes by the **output's suffix** (``.bvh``, ``.glb``, ``.gltf``, ``.fbx``); any other
  suffix raises :class:`~engine.errors.UnsupportedFormatError`, which :func:`output_format`
  raises before any work is done.
"""
from __future__ import annotations

import os
import re
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import (ExportError, FBXError, FileFormatError, GLTFError, UnknownFormatError,
                      UnsupportedFormatError)
from ..motion import Motion
from .bvh import read_bvh, write_bvh

if TYPE_CHECKING:
    from .gltf import Character

# The glTF and FBX modules (about 50 ms of import) load when a file of theirs is first read
# or written, not with this package: reading a BVH clip or a project of BVH clips (the
# window's demo) never needs them. Their names stay importable from here (_LAZY, at the end).

__all__ = ["Format", "FORMATS", "BVH", "GLTF", "GLB", "FBX", "HEAD_BYTES", "sniff", "read_motion",
           "read_performer", "read_character", "output_format", "write_motion",
           "output_suffixes", "with_output_suffix", "open_filters", "save_filters"]

#: how many bytes of a file sniffing reads (a glTF JSON's ``"asset"`` member is looked for
#: in them; every other signature is in the first few bytes)
HEAD_BYTES = 64 * 1024

_BOM = b"\xef\xbb\xbf"
_ASCII_SPACE = b" \t\n\r\x0b\x0c"
_ASSET_KEY = re.compile(rb'"asset"\s*:')
_BVH_KEYWORD = re.compile(rb"HIERARCHY(\s|$)", re.IGNORECASE)


@dataclass(frozen=True)
class Format:
    """A file format the application reads and writes.

    Attributes:
        name: what the user sees ("BVH", "glTF", "GLB").
        description: the format in a few words, as file dialogs name it.
        suffixes: the suffixes it writes (lower case, with the dot); the first is the default.
        other_suffixes: suffixes its files also carry (a VRM avatar is GLB), offered in open
            dialogs only: reading never looks at a suffix.
        sniff: ``sniff(head)`` whether a file whose first bytes are ``head`` (at most
            :data:`HEAD_BYTES`) is in this format.
        read_motion: ``read_motion(path, **bvh_overrides) -> Motion``.
        read_character: ``read_character(path, up_axis=None) -> Character``, or ``None`` for
            a format that holds no mesh.
        write: ``write(motion, path, character, channels)``; ``character`` (may be ``None``)
            gives the mesh and skin of a format that holds them and is ignored by one that
            does not; ``channels`` is :func:`~engine.formats.bvh.format_bvh`'s (``"all"`` or
            ``"rotation"``), BVH's only; ``None`` for a format that is only read.
        motion: the format holds an animation.
        mesh: the format holds a character with a skinned mesh; its :attr:`read_motion` is
            the character's bind pose (``Character.rest_motion()``), a target, not a capture.
        read_take: ``read_take(path, take=None) -> Motion``: the named take of a character
            file that holds animations (FBX), by default its first, a performer clip; ``None``
            for a format without takes.
    """

    name: str
    description: str
    suffixes: tuple[str, ...]
    other_suffixes: tuple[str, ...]
    sniff: Callable[[bytes], bool]
    read_motion: Callable[..., Motion]
    read_character: Callable[..., Character] | None
    write: Callable[[Motion, str, Character | None, str], None] | None
    motion: bool
    mesh: bool
    read_take: Callable[..., Motion] | None = None


# --------------------------------------------------------------------------- signatures
def _text_start(head: bytes) -> bytes:
    """``head`` without a UTF-8 byte-order mark and the blank space before the first word."""
    return head.removeprefix(_BOM).lstrip(_ASCII_SPACE)


def _is_bvh(head: bytes) -> bool:
    return _BVH_KEYWORD.match(_text_start(head)) is not None


def _is_gltf_json(head: bytes) -> bool:
    """A JSON object naming ``"asset"`` in its first bytes; a longer object that does not may
    still name it further on, and is left to the glTF reader to check."""
    return _text_start(head)[:1] == b"{" and (_ASSET_KEY.search(head) is not None or
                                              len(head) >= HEAD_BYTES)


def _is_glb(head: bytes) -> bool:
    return head[:4] == b"glTF"


def _is_fbx(head: bytes) -> bool:
    """Binary FBX (``Kaydara FBX Binary``) or ASCII FBX (a ``; FBX`` comment or the
    ``FBXHeaderExtension`` it opens with)."""
    start = _text_start(head)
    return (head.startswith(b"Kaydara FBX Binary") or start.startswith(b"; FBX") or
            start.startswith(b"FBXHeaderExtension"))


# --------------------------------------------------------------------------- readers, writers
def _read_gltf(path, up_axis: str | None = None) -> Character:
    from .gltf import read_gltf
    return read_gltf(path, up_axis=up_axis)


def _read_fbx(path, up_axis: str | None = None) -> Character:
    from .fbx.scene import read_fbx
    return read_fbx(path, up_axis=up_axis)


def _gltf_rest_motion(path, up_axis: str | None = None, **bvh_overrides) -> Motion:
    """A glTF character's bind pose as a one-frame motion (glTF is metres, so the BVH
    reader's other overrides do not apply; the up axis of a file written with another
    one may be given)."""
    if bvh_overrides:
        raise GLTFError(f"{', '.join(sorted(bvh_overrides))} apply to BVH files only; glTF is "
                        "metres by definition (its up axis may be given)", path)
    return _read_gltf(path, up_axis).rest_motion()


def _write_bvh(motion: Motion, path, character: Character | None, channels: str) -> None:
    write_bvh(motion, path, channels=channels)


def _write_gltf(motion: Motion, path, character: Character | None, channels: str) -> None:
    if channels != "all":
        raise ExportError(f"rotation-only channels are a BVH option; a glTF file "
                          f"({Path(path).name}) animates every joint by its own node")
    from .gltf import write_gltf
    write_gltf(motion, character, path)


def _write_fbx(motion: Motion, path, character: Character | None, channels: str) -> None:
    if channels != "all":
        raise ExportError(f"rotation-only channels are a BVH option; an FBX file "
                          f"({Path(path).name}) animates every joint's translation and rotation")
    from .fbx.write import write_fbx
    write_fbx(motion, path, character=character)


def _fbx_options(path, bvh_overrides: dict) -> None:
    if bvh_overrides:
        raise FBXError(f"{', '.join(sorted(bvh_overrides))} apply to BVH files only; an FBX "
                       "file states its units (GlobalSettings; its up axis may be given)",
                       path)


def _fbx_rest_motion(path, take: str | None = None, up_axis: str | None = None,
                     **bvh_overrides) -> Motion:
    """An FBX character's bind pose (one frame), or its take ``take`` when named."""
    _fbx_options(path, bvh_overrides)
    character = _read_fbx(path, up_axis)
    if take is None:
        return character.rest_motion()
    from .fbx.scene import take_motion
    return take_motion(character, take)


def _fbx_take(path, take: str | None = None, up_axis: str | None = None,
              **bvh_overrides) -> Motion:
    """An FBX file's take ``take`` (by default its first), a performer clip."""
    _fbx_options(path, bvh_overrides)
    from .fbx.scene import take_motion
    return take_motion(_read_fbx(path, up_axis), take)


BVH = Format("BVH", "BVH motion", (".bvh",), (), _is_bvh, read_bvh, None, _write_bvh,
             motion=True, mesh=False)
GLTF = Format("glTF", "glTF JSON", (".gltf",), (), _is_gltf_json, _gltf_rest_motion,
              _read_gltf, _write_gltf, motion=True, mesh=True)
GLB = Format("GLB", "GLB, binary glTF", (".glb",), (".vrm",), _is_glb, _gltf_rest_motion,
             _read_gltf, _write_gltf, motion=True, mesh=True)
FBX = Format("FBX", "FBX scene", (".fbx",), (), _is_fbx, _fbx_rest_motion, _read_fbx,
             _write_fbx, motion=True, mesh=True, read_take=_fbx_take)

#: every format read and written, in the order dialogs list them
FORMATS: tuple[Format, ...] = (BVH, GLB, GLTF, FBX)


def _known() -> str:
    names = [f.name for f in FORMATS]
    return ", ".join(names[:-1]) + " or " + names[-1]


# --------------------------------------------------------------------------- reading
def _head(path) -> bytes:
    """The first :data:`HEAD_BYTES` bytes of a regular file (a folder or a device is refused
    before anything is read)."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise FileFormatError("no such file", path) from None
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"cannot be read: {getattr(exc, 'strerror', None) or exc}",
                              path) from None
    if stat.S_ISDIR(info.st_mode):
        raise FileFormatError(f"this is a folder, not a motion file ({_known()})", path)
    if not stat.S_ISREG(info.st_mode):
        raise FileFormatError(f"not a regular file (a device, pipe or socket); expected a "
                              f"motion file ({_known()})", path)
    try:
        with open(path, "rb") as handle:
            return handle.read(HEAD_BYTES)
    except OSError as exc:
        raise FileFormatError(f"cannot be read: {exc.strerror or exc}", path) from None


def _unknown(head: bytes, path) -> UnknownFormatError:
    """The error for content that is none of :data:`FORMATS`: what was found, and where."""
    if not head.strip(_ASCII_SPACE) and len(head) < HEAD_BYTES:
        return UnknownFormatError(f"the file is empty; expected a motion file ({_known()})",
                                  path)
    if b"\x00" in head:
        return UnknownFormatError(f"this is a binary file in no format this application "
                                  f"reads (it contains NUL bytes); expected a motion file "
                                  f"({_known()})", path)
    body = head.removeprefix(_BOM)
    start = len(body) - len(body.lstrip(_ASCII_SPACE))
    line = body[:start].replace(b"\r\n", b"\n").replace(b"\r", b"\n").count(b"\n") + 1
    word = re.match(rb"\S*", body[start:]).group().decode("latin-1")
    if word.startswith("{"):
        return UnknownFormatError(f"JSON, but not glTF (no \"asset\" member); expected a "
                                  f"motion file ({_known()})", path, line)
    return UnknownFormatError(f"expected the keyword HIERARCHY (BVH), a JSON object with "
                              f"\"asset\" (glTF) or the bytes b'glTF' (GLB), found "
                              f"{word[:40]!r}", path, line)


def sniff(path: str | os.PathLike) -> Format:
    """The format of the file at ``path``, from its first bytes.

    Raises:
        FileFormatError: for a missing file, a folder or a device (before reading it).
        UnknownFormatError: for anything that is none of :data:`FORMATS`.
    """
    head = _head(path)
    for fmt in FORMATS:
        if fmt.sniff(head):
            return fmt
    raise _unknown(head, path)


def _without_take(options: dict) -> dict:
    """The reader options of a format without takes: a ``take`` names one of an FBX file's
    takes, and a file with one motion (BVH, glTF) has nothing to choose (a project keeps
    the name; the command line refuses ``--take`` for such a file)."""
    options.pop("take", None)
    return options


def read_motion(path: str | os.PathLike, **bvh_overrides) -> Motion:
    """The motion a file holds: a BVH's clip, or a glTF or FBX character's bind pose (one
    frame); ``take=NAME`` gives an FBX file's take instead.

    ``bvh_overrides`` (``units``, ``scale``, ``up_axis``, ``position_mode``) go to
    :func:`~engine.formats.bvh.read_bvh`; given for a glTF or FBX file they raise its format
    error, but ``up_axis`` (the axis its figure stands along, for a file written with
    another axis up than it says).
    """
    fmt = sniff(path)
    if fmt.read_take is None:
        _without_take(bvh_overrides)
    return fmt.read_motion(path, **bvh_overrides)


def read_performer(path: str | os.PathLike, **bvh_overrides) -> Motion:
    """A captured clip to retarget: a BVH's clip or an FBX file's take (``take=NAME``, by
    default its first).

    Raises:
        UnsupportedFormatError: for a glTF character, which is a target: its motion here is
            its bind pose.
        FBXError: for an FBX file without a take that moves a joint (a character only).
    """
    fmt = sniff(path)
    if fmt.read_take is not None:
        return fmt.read_take(path, **bvh_overrides)
    _without_take(bvh_overrides)
    if fmt.mesh:
        raise UnsupportedFormatError(f"a {fmt.name} file is a character; use it as the target "
                                     "(the performer is a BVH clip or an FBX take)", path)
    return fmt.read_motion(path, **bvh_overrides)


def read_character(path: str | os.PathLike, up_axis: str | None = None) -> Character | None:
    """The glTF or FBX character (skeleton, meshes, skins, animations or takes) a file holds,
    or ``None`` for a format that holds no mesh (BVH). ``up_axis``: the axis its figure
    stands along, for a file written with another axis up than it says (see
    :func:`~engine.formats.gltf.read_gltf`); by default what the file says."""
    fmt = sniff(path)
    if not fmt.mesh:
        return None
    return fmt.read_character(path, up_axis) if up_axis is not None else \
        fmt.read_character(path)


# --------------------------------------------------------------------------- writing
def output_suffixes() -> tuple[str, ...]:
    """Every suffix a writer writes (``.bvh``, ``.glb``, ``.gltf``, ``.fbx``)."""
    return tuple(s for fmt in FORMATS if fmt.write is not None for s in fmt.suffixes)


def output_format(path: str | os.PathLike) -> Format:
    """The format written to ``path``, by its suffix (case-insensitive).

    Raises:
        UnsupportedFormatError: for a suffix no format writes.
    """
    suffix = Path(path).suffix.lower()
    for fmt in FORMATS:
        if suffix in fmt.suffixes and fmt.write is not None:
            return fmt
    written = ", ".join(f"{s} ({fmt.name})" for fmt in FORMATS if fmt.write is not None
                        for s in fmt.suffixes)
    what = f"a {suffix} file" if suffix else "a file without a suffix"
    raise UnsupportedFormatError(f"cannot write {what}; the formats written are {written}",
                                 path)


def write_motion(motion: Motion, path: str | os.PathLike,
                 character: Character | None = None, *, channels: str = "all") -> None:
    """Write ``motion`` to ``path`` in the format its suffix names, atomically.

    ``character`` gives a glTF or FBX output the character's meshes and skin (``None``: a
    skeleton-only file); BVH ignores it. ``channels="rotation"`` writes a BVH file with
    rotation channels only on every joint but the root (see
    :func:`~engine.formats.bvh.format_bvh`); glTF and FBX refuse it.

    Raises:
        UnsupportedFormatError: for a suffix no format writes (nothing is written).
        ExportError: when the motion cannot be written in that format.
    """
    output_format(path).write(motion, path, character, channels)


def with_output_suffix(path: str | os.PathLike, default: Format = BVH) -> str:
    """``path`` itself when a format writes its suffix, else ``path`` with ``default``'s
    suffix added (a name typed in a save dialog without one)."""
    path = os.fspath(path)
    if Path(path).suffix.lower() in output_suffixes():
        return path
    return path + default.suffixes[0]


# --------------------------------------------------------------------------- file dialogs
def _patterns(suffixes) -> str:
    return " ".join(f"*{s}" for s in suffixes)


def open_filters() -> str:
    """The filter string of an open-file dialog (Qt's ``"Name (*.a *.b);;..."`` syntax):
    every readable format together, each on its own, then all files (reading goes by
    content, so a file of any name may be chosen)."""
    every = [s for fmt in FORMATS for s in fmt.suffixes + fmt.other_suffixes]
    items = [f"Motion files ({_patterns(every)})"]
    items += [f"{fmt.description} ({_patterns(fmt.suffixes + fmt.other_suffixes)})"
              for fmt in FORMATS]
    return ";;".join(items + ["All files (*)"])


def save_filters() -> str:
    """The filter string of a save-file dialog: one entry per written format, the default
    (BVH) first."""
    return ";;".join(f"{fmt.description} ({_patterns(fmt.suffixes)})" for fmt in FORMATS
                     if fmt.write is not None)


#: names this package gives from the glTF and FBX modules, loaded when first asked for
_LAZY = {"Character": ".gltf", "read_gltf": ".gltf", "write_gltf": ".gltf",
         "read_fbx": ".fbx.scene", "take_motion": ".fbx.scene", "write_fbx": ".fbx.write"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
