"""Scenes as bytes, bundled the way `epr submit` bundles them (wire/scene_bundle.cpp).

A bundle is the entry file (an OBJ, a glTF or a scene JSON) plus every file it references, with
relative '/'-separated paths below the entry file's folder:

* a scene JSON's ``"obj"`` and ``"environment": {"image": ...}`` (relative to the JSON's folder), then that
  OBJ's or glTF's files;
* a glTF's (``.gltf`` or ``.glb``) ``buffers[i].uri`` and ``images[i].uri`` files (relative to the
  glTF, percent-decoded as tinygltf decodes them); ``data:`` URIs stay inline in the glTF, and a
  ``.glb`` file's binary chunk is part of it. An image file that does not exist is left out (the
  master names it if a material uses it); every other image file is sent, also one no material
  uses (which `epr submit` leaves out, giving another content hash);
* an OBJ's ``mtllib`` files (relative to the OBJ; several names per statement, blanks separate
  them, a backslash escapes the next character);
* an MTL's ``map_Kd`` textures (relative to the MTL, texture options such as ``-s 1 1 1`` skipped
  as tinyobjloader skips them, backslashes read as '/'). Other maps are not part of the material
  model and are not sent.

Files must stay inside the entry file's folder, also through symlinks; absolute paths are refused;
every file must be a regular file (FIFOs, devices and folders are refused before anything is read).
The rules and messages follow the C++ loader's path sandbox (common/scene_loader/path_sandbox.h).
Only the file names are read here: whether the scene loads (geometry, materials, light) is checked
by the master, which answers a broken scene with INVALID_ARGUMENT naming file and line.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

from .errors import SceneError

BUILTIN_PREFIX = "builtin:"
MAX_FILE_BYTES = 1 << 30  # LoadOptions::max_file_bytes
MAX_JSON_BYTES = 16 << 20  # scene JSON files are a few lines


@dataclass
class SceneBundle:
    """A scene as a job carries it: a built-in's name, or files with the entry file's path."""

    builtin: str = ""
    entry_path: str = ""
    files: List[Tuple[str, bytes]] = field(default_factory=list)  # (relative path, bytes), sorted by path

    @property
    def total_bytes(self) -> int:
        """Sum of the file sizes (0 for a built-in)."""
        return sum(len(data) for _, data in self.files)

    def content_hash(self) -> str:
        """Lowercase hex SHA-256 of the canonical serialisation (proto/epr/v1/scene.proto)."""
        h = hashlib.sha256()
        if self.builtin:
            h.update(b"epr-builtin-v1\n" + self.builtin.encode())
            return h.hexdigest()

        def put(b: bytes) -> None:
            h.update(len(b).to_bytes(8, "little"))
            h.update(b)

        h.update(b"epr-scene-v1\n")
        put(self.entry_path.encode())
        h.update(len(self.files).to_bytes(8, "little"))
        for path, data in sorted(self.files, key=lambda f: f[0].encode()):
            put(path.encode())
            put(data)
        return h.hexdigest()


def is_safe_relative_path(path: str) -> bool:
    """No leading '/', no '\\', no NUL byte, no empty, "." or ".." components, at most 1024 bytes."""
    if not path or len(path.encode()) > 1024 or path.startswith("/") or "\\" in path or "\0" in path:
        return False
    return all(part not in ("", ".", "..") for part in path.split("/"))


# ---- reading files inside the sandbox ------------------------------------------------------------


@dataclass
class _FileRef:
    real: str  # canonical path that is opened
    display: str  # as the user wrote it, joined to the referring file's folder


def _kind_problem(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "is a directory"
    if stat.S_ISFIFO(mode):
        return "is a FIFO (named pipe), not a regular file"
    if stat.S_ISCHR(mode):
        return "is a character device, not a regular file"
    if stat.S_ISBLK(mode):
        return "is a block device, not a regular file"
    if stat.S_ISSOCK(mode):
        return "is a socket, not a regular file"
    return "is not a regular file"


def _file_problem(path: str, max_bytes: int) -> Optional[str]:
    """Why `path` cannot be read as a scene file, or None. Never opens what is not a regular file."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "does not exist"
    except NotADirectoryError:
        return "does not exist"
    except OSError as e:
        return f"cannot open: {e.strerror}"
    if not stat.S_ISREG(st.st_mode):
        return _kind_problem(st.st_mode)
    if st.st_size > max_bytes:
        return f"has {st.st_size} bytes, over the limit of {max_bytes}"
    return None


def _read_file(f: _FileRef, max_bytes: int) -> bytes:
    """The whole file, checked as _file_problem does before anything is read."""
    if problem := _file_problem(f.real, max_bytes):
        raise SceneError(f"{f.display}: {problem}")
    try:
        # O_NONBLOCK: a FIFO put in the file's place meanwhile cannot block the open.
        fd = os.open(f.real, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | os.O_NOCTTY)
    except OSError as e:
        raise SceneError(f"{f.display}: cannot open: {e.strerror}") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise SceneError(f"{f.display}: {_kind_problem(st.st_mode)}")
        if st.st_size > max_bytes:
            raise SceneError(f"{f.display}: has {st.st_size} bytes, over the limit of {max_bytes}")
        return fh.read(st.st_size)  # never more than the size checked


def _is_inside(root: str, path: str) -> bool:
    return os.path.commonpath([root, path]) == root


def _resolve_inside(root: str, folder: str, display_dir: str, name: str, file: str, line: int, what: str) -> _FileRef:
    """`name`, written in `file` at `line`, resolved against `folder`; must stay inside `root`."""
    where = f"{file}:{line}" if line else file
    if not name:
        raise SceneError(f"{where}: empty {what} path")
    if "\0" in name:
        raise SceneError(f"{where}: {what} path contains a NUL byte")
    if os.path.isabs(name):
        raise SceneError(
            f"{where}: {what} '{name}' is an absolute path; scene files must name files inside the scene folder"
        )
    real = os.path.realpath(os.path.join(folder, name))
    if not _is_inside(root, real):
        raise SceneError(f"{where}: {what} '{name}' leaves the scene folder")
    display = os.path.normpath(os.path.join(display_dir, name)) if display_dir else name
    return _FileRef(real, display)


# ---- the statements of OBJ and MTL files (common/scene_loader/text.h) ----------------------------


def _lines(text: bytes):
    """(line number, statement without comment and surrounding blanks) for each non-blank line."""
    number = 0
    pos = 0
    n = len(text)
    while pos < n:
        end = pos
        while end < n and text[end] not in b"\r\n":
            end += 1
        raw = text[pos:end]
        pos = end
        if pos < n:
            if text[pos] == ord("\r") and pos + 1 < n and text[pos + 1] == ord("\n"):
                pos += 1
            pos += 1
        number += 1
        yield number, raw


def _strip_comment(line: bytes) -> bytes:
    """Removes a comment (a '#' at the start or after a blank) and the surrounding blanks."""
    for i, c in enumerate(line):
        if c == ord("#") and (i == 0 or line[i - 1] in b" \t"):
            line = line[:i]
            break
    return line.strip(b" \t")


def _statements(text: bytes, file: str):
    """(line number, stripped line, tokens) of every statement; a NUL byte is refused."""
    for number, raw in _lines(text):
        if b"\0" in raw:
            raise SceneError(f"{file}:{number}: NUL byte in a text file")
        line = _strip_comment(raw)
        tokens = [t for t in line.replace(b"\t", b" ").split(b" ") if t]  # blanks separate tokens
        if tokens:
            yield number, line, tokens


def _rest_after_keyword(line: bytes, keyword: bytes) -> bytes:
    return line[len(keyword) :].lstrip(b" \t")


def _split_escaped(s: bytes) -> List[bytes]:
    """An mtllib argument: blanks separate names, a backslash escapes the next character."""
    out: List[bytes] = []
    cur = bytearray()
    escaping = False
    for c in s:
        if escaping:
            cur.append(c)
            escaping = False
        elif c == ord("\\"):
            escaping = True
        elif c in b" \t":
            if cur:
                out.append(bytes(cur))
            cur = bytearray()
        else:
            cur.append(c)
    if cur:
        out.append(bytes(cur))
    return out


# Texture options of a map_Kd statement and the words each takes (tinyobjloader's
# ParseTextureNameAndOption); what follows the options, to the end of the line, is the file name.
_TEXTURE_OPTIONS = {
    b"-blendu": 1,
    b"-blendv": 1,
    b"-clamp": 1,
    b"-boost": 1,
    b"-bm": 1,
    b"-o": 3,
    b"-s": 3,
    b"-t": 3,
    b"-type": 1,
    b"-texres": 1,
    b"-imfchan": 1,
    b"-mm": 2,
    b"-colorspace": 1,
}


def _texture_name(args: bytes) -> Optional[bytes]:
    """The file name of a map_Kd statement's arguments, or None if it names none."""
    n = len(args)
    i = 0

    def skip_blanks(i: int) -> int:
        while i < n and args[i] in b" \t":
            i += 1
        return i

    def skip_word(i: int) -> int:
        i = skip_blanks(i)
        while i < n and args[i] not in b" \t\r":
            i += 1
        return i

    while i < n and args[i] not in b"\r\n\0":
        i = skip_blanks(i)
        for option, words in _TEXTURE_OPTIONS.items():
            end = i + len(option)
            if args.startswith(option, i) and end < n and args[end] in b" \t":
                i = end
                for _ in range(words):
                    i = skip_word(i)
                break
        else:
            return args[i:]  # the file name may contain blanks
    return None


# ---- bundling -----------------------------------------------------------------------------------


class _Bundler:
    """Collects the files of one scene, each once, the entry file first."""

    def __init__(self, root: str):
        self.root = root
        self.files: Dict[str, bytes] = {}  # real path -> bytes, in reading order

    def read(self, ref: _FileRef, max_bytes: int = MAX_FILE_BYTES) -> bytes:
        if ref.real not in self.files:
            self.files[ref.real] = _read_file(ref, max_bytes)
        return self.files[ref.real]

    def obj(self, ref: _FileRef) -> None:
        text = self.read(ref)
        folder = os.path.dirname(ref.real)
        display_dir = os.path.dirname(ref.display)
        for number, line, tokens in _statements(text, ref.display):
            if tokens[0] != b"mtllib":
                continue
            names = _split_escaped(_rest_after_keyword(line, b"mtllib"))
            if not names:
                raise SceneError(f"{ref.display}:{number}: mtllib names no file")
            mtls = []
            for raw in names:
                name = os.fsdecode(raw)
                mtl = _resolve_inside(self.root, folder, display_dir, name, ref.display, number, "mtllib")
                if problem := _file_problem(mtl.real, MAX_FILE_BYTES):
                    raise SceneError(f"{ref.display}:{number}: mtllib '{name}' {problem}")
                mtls.append(mtl)
            for mtl in mtls:
                if mtl.real not in self.files:
                    self.mtl(mtl)

    def mtl(self, ref: _FileRef) -> None:
        text = self.read(ref)
        folder = os.path.dirname(ref.real)
        display_dir = os.path.dirname(ref.display)
        current = False  # a newmtl came
        for number, line, tokens in _statements(text, ref.display):
            if tokens[0] == b"newmtl":
                current = len(tokens) > 1 or current
            elif tokens[0] == b"map_Kd":
                if not current:
                    raise SceneError(f"{ref.display}:{number}: map_Kd before any newmtl")
                raw = _texture_name(_rest_after_keyword(line, b"map_Kd"))
                raw = _strip_comment(raw) if raw is not None else b""
                if not raw:
                    raise SceneError(f"{ref.display}:{number}: map_Kd without a texture file name")
                name = os.fsdecode(raw)
                portable = name.replace("\\", "/")  # textures named on Windows
                tex = _resolve_inside(self.root, folder, display_dir, portable, ref.display, number, "texture")
                if problem := _file_problem(tex.real, MAX_FILE_BYTES):
                    raise SceneError(f"{ref.display}:{number}: texture '{name}' {problem}")
                self.read(tex)

    def scene_json(self, ref: _FileRef) -> None:
        text = self.read(ref, min(MAX_FILE_BYTES, MAX_JSON_BYTES))
        try:
            doc = json.loads(_strip_json_comments(text.decode("utf-8")))
        except UnicodeDecodeError as e:
            raise SceneError(f"{ref.display}: invalid JSON: not UTF-8 ({e.reason})") from None
        except json.JSONDecodeError as e:
            raise SceneError(f"{ref.display}:{e.lineno}: invalid JSON: {e.msg}") from None
        if not isinstance(doc, dict):
            return  # a malformed file, which the master names
        env = doc.get("environment")
        if isinstance(env, dict) and isinstance(env.get("image"), str):  # an equirectangular sky
            sky = _resolve_inside(self.root, self.root, os.path.dirname(ref.display), env["image"], ref.display, 0,
                                  "environment image")
            if problem := _file_problem(sky.real, MAX_FILE_BYTES):
                raise SceneError(f"{ref.display}: environment image '{env['image']}' {problem}")
            self.read(sky)
        if "obj" not in doc:
            return  # a built-in scene
        name = doc["obj"]
        if not isinstance(name, str):
            raise SceneError(f"{ref.display}: \"obj\" must be a string")
        display_dir = os.path.dirname(ref.display)
        obj = _resolve_inside(self.root, self.root, display_dir, name, ref.display, 0, "obj")
        if problem := _file_problem(obj.real, MAX_FILE_BYTES):
            raise SceneError(f"{ref.display}: obj file '{name}' {problem}")
        if is_gltf_path(name):
            _gltf_files(self, obj)
        else:
            self.obj(obj)


def is_gltf_path(path: str) -> bool:
    """True for a .gltf or .glb name (any case), which the loader reads as glTF 2.0."""
    return os.path.splitext(path)[1].lower() in (".gltf", ".glb")


def _decode_uri(uri: str) -> str:
    """A glTF uri as a file name: '+' is a blank, %XX a byte (tinygltf's dlib::urldecode)."""

    def hex_value(c: int) -> int:
        for lo, hi, base in ((0x30, 0x39, 0), (0x61, 0x66, 10), (0x41, 0x46, 10)):
            if lo <= c <= hi:
                return c - lo + base
        return 0

    raw = os.fsencode(uri)
    out = bytearray()
    i = 0
    while i < len(raw):
        c = raw[i]
        if c == ord("+"):
            out.append(ord(" "))
        elif c == ord("%") and len(raw) > i + 2:
            out.append((hex_value(raw[i + 1]) << 4) | hex_value(raw[i + 2]))
            i += 2
        else:
            out.append(c)
        i += 1
    return os.fsdecode(bytes(out))


def _quote_token(token: str) -> str:
    """As the loader quotes names in messages: at most 40 characters, control characters as '?'."""
    s = "".join("?" if ord(c) < 0x20 or ord(c) == 0x7F else c for c in token[:40])
    return f"'{s}...'" if len(token) > 40 else f"'{s}'"


def _glb_json(data: bytes, display: str) -> bytes:
    """The JSON chunk of a .glb file (its binary chunk travels inside the file)."""
    le32 = lambda at: int.from_bytes(data[at : at + 4], "little")  # noqa: E731
    if len(data) < 20:
        raise SceneError(f"{display}: not a valid .glb file: shorter than its header")
    if le32(4) != 2:
        raise SceneError(f"{display}: glTF binary version {le32(4)} (only 2 is read)")
    if le32(16) != 0x4E4F534A:
        raise SceneError(f"{display}: not a valid .glb file: the first chunk is not JSON")
    length = le32(12)
    if length + 20 > len(data):
        raise SceneError(
            f"{display}: not a valid .glb file: its JSON chunk of {length} bytes runs past the end of the file"
        )
    return data[20 : 20 + length]


def _gltf_files(bundler: "_Bundler", ref: _FileRef) -> None:
    """The glTF `ref` and its buffer and image files, checked as common/scene_loader/gltf_files.cpp checks them."""
    data = bundler.read(ref)
    text = _glb_json(data, ref.display) if data[:4] == b"glTF" else data  # binary by content, as the loader
    if b"\0" in text:
        raise SceneError(f"{ref.display}: NUL byte in the JSON text")
    try:
        doc = json.loads(text.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise SceneError(f"{ref.display}: invalid JSON: not UTF-8 ({e.reason})") from None
    except json.JSONDecodeError as e:
        raise SceneError(f"{ref.display}:{e.lineno}: invalid JSON: {e.msg}") from None
    if not isinstance(doc, dict):
        raise SceneError(f"{ref.display}: a glTF file must hold a JSON object")
    folder = os.path.dirname(ref.real)
    display_dir = os.path.dirname(ref.display)
    for kind in ("buffers", "images"):
        items = doc.get(kind)
        if not isinstance(items, list):
            continue
        for i, item in enumerate(items):
            if not isinstance(item, dict) or not isinstance(item.get("uri"), str):
                continue  # an image in a bufferView, or the .glb's binary chunk
            uri = item["uri"]
            if uri.startswith("data:"):
                continue  # inline in the glTF
            where = f"{kind}[{i}]"
            name = _decode_uri(uri)
            file = _resolve_inside(bundler.root, folder, display_dir, name, f"{ref.display}: {where}", 0, "uri")
            if kind == "images":  # read as the loader reads textures: backslashes as '/'
                file = _resolve_inside(
                    bundler.root, folder, display_dir, name.replace("\\", "/"), f"{ref.display}: {where}", 0, "texture"
                )
            problem = _file_problem(file.real, MAX_FILE_BYTES)
            if problem == "does not exist" and kind == "images":
                continue  # the master names it if a material uses it
            if problem:
                raise SceneError(f"{ref.display}: {where}: uri {_quote_token(uri)} {problem}")
            bundler.read(file)


def _strip_json_comments(text: str) -> str:
    """`text` with // and /* */ comments outside strings blanked (the loader ignores them)."""
    out = []
    i, n = 0, len(text)
    in_string = False
    while i < n:
        c = text[i]
        if in_string:
            out.append(c)
            if c == "\\" and i + 1 < n:
                out.append(text[i + 1])
                i += 1
            elif c == '"':
                in_string = False
        elif c == '"':
            in_string = True
            out.append(c)
        elif text.startswith("//", i):
            while i < n and text[i] != "\n":
                i += 1
            continue
        elif text.startswith("/*", i):
            end = text.find("*/", i + 2)
            end = n if end < 0 else end + 2
            out.append("\n" * text.count("\n", i, end))  # keeps line numbers
            i = end
            continue
        else:
            out.append(c)
        i += 1
    return "".join(out)


def bundle_scene(spec: str) -> SceneBundle:
    """The bundle of `spec`: ``builtin:NAME[?k=v...]``, an OBJ path, a glTF path (*.gltf, *.glb) or a
    scene JSON path (*.json).

    Raises SceneError naming the file (and line) when a file cannot be read or leaves the folder.
    """
    if spec.startswith(BUILTIN_PREFIX) and "\0" not in spec:
        return SceneBundle(builtin=spec)
    if "\0" in spec:
        raise SceneError(f"{spec!r}: the path contains a NUL byte")
    real = os.path.realpath(os.path.abspath(spec))
    root = os.path.dirname(real)
    bundler = _Bundler(root)
    entry = _FileRef(real, spec)
    if spec.lower().endswith(".json"):
        bundler.scene_json(entry)
    elif is_gltf_path(spec):
        _gltf_files(bundler, entry)
    else:
        bundler.obj(entry)
    files = []
    for path, data in bundler.files.items():
        rel = os.path.relpath(path, root).replace(os.sep, "/")
        if not is_safe_relative_path(rel):
            raise SceneError(f"{spec}: '{rel}' lies outside the scene folder {root}")
        files.append((rel, data))
    files.sort(key=lambda f: f[0].encode())
    return SceneBundle(entry_path=os.path.basename(real), files=files)


def bundle_scene_with_image(spec: str, image: str) -> Tuple[SceneBundle, str]:
    """The bundle of `spec` with an environment image, and the image's path inside the bundle, as
    `epr submit --env FILE` sends them. `image` is a path as given (relative to the working folder).
    With a built-in scene the image may lie anywhere: it travels beside a generated scene JSON naming
    the built-in. With a file scene it must lie inside the scene's folder, with the scene's files.
    """
    if "\0" in image:
        raise SceneError(f"{image!r}: the path contains a NUL byte")
    real = os.path.realpath(os.path.abspath(image))
    if problem := _file_problem(real, MAX_FILE_BYTES):
        raise SceneError(f"environment image '{image}' {problem}")
    if spec.startswith(BUILTIN_PREFIX) and "\0" not in spec:
        name = os.path.basename(real)
        entry = "builtin-scene.json" if name == "builtin.json" else "builtin.json"
        doc = json.dumps({"builtin": spec[len(BUILTIN_PREFIX) :]}, ensure_ascii=False, separators=(",", ":")) + "\n"
        files = [(entry, doc.encode()), (name, _read_file(_FileRef(real, image), MAX_FILE_BYTES))]
        files.sort(key=lambda f: f[0].encode())
        return SceneBundle(entry_path=entry, files=files), name
    bundle = bundle_scene(spec)
    root = os.path.dirname(os.path.realpath(os.path.abspath(spec)))
    rel = os.path.relpath(real, root).replace(os.sep, "/")
    if not _is_inside(root, real) or not is_safe_relative_path(rel):
        raise SceneError(
            f"environment image '{image}' lies outside the scene's folder {root}: the image travels with the "
            "scene's files, so copy it there"
        )
    if rel not in {path for path, _ in bundle.files}:
        bundle.files.append((rel, _read_file(_FileRef(real, image), MAX_FILE_BYTES)))
        bundle.files.sort(key=lambda f: f[0].encode())
    return bundle, rel
