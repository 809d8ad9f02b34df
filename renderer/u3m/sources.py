"""Where a U3M's files come from: the folder beside a `.u3m` document, or a `.u3ma` zip archive that
holds the document and its images. The kind is told by the bytes (a zip's local-header or empty-archive
signature), never by the file's name. Every file is read whole into memory, with a byte cap, and only
the files the document names are read: nothing is extracted to disk.

The spec's rule for the paths a document names (u3m_additional_spec.txt, "paths"): relative, '/'
separated, no `.`, `..` or `~` component (the "directory changers"), no drive letter or other ':', no
'\\', no control character. Here a path that breaks it is refused whatever the schema version says
(1.0's schema has no pattern for paths), and a folder's path is also refused when a symbolic link takes
it out of the folder.
"""

from __future__ import annotations

import io
import os
import posixpath
import re
import stat
import struct
import zipfile
import zlib
from pathlib import Path
from typing import BinaryIO

from ..errors import MaterialError
from .limits import RATIO_FLOOR_BYTES, U3MLimits

# A zip's first local file header, or the end record of an empty archive (APPNOTE.TXT 4.3.7, 4.3.16).
ZIP_SIGNATURES = (b"PK\x03\x04", b"PK\x05\x06")
_END_RECORD = struct.Struct("<4s4H2LH")   # end of central directory record, 22 bytes
_MAX_ZIP_COMMENT = 0xFFFF
# A central directory record is 46 bytes and its name; a U3MA's have no extra field nor comment.
_MAX_DIRECTORY_BYTES_PER_MEMBER = 46 + 1024
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
_DRIVE = re.compile(r"^[A-Za-z]:")


def path_problem(path: str) -> str | None:
    """Why `path` is not a relative path the U3M spec allows (a reason for a message), or None."""
    if not path:
        return "is empty"
    if _CONTROL.search(path):
        return "holds a control character"
    if "\\" in path:
        return "holds a '\\' (U3M paths are POSIX paths, '/' separated)"
    if path.startswith("/"):
        return "is absolute (U3M paths are relative to the document)"
    if _DRIVE.match(path) or ":" in path:
        return "holds a ':' (a drive letter or a stream name; U3M paths are relative POSIX paths)"
    for part in path.split("/"):
        if part == "":
            return "holds an empty component ('//', or a '/' at its end)"
        if part in (".", "..", "~"):
            return f"holds a {part!r} component (the spec forbids '.', '..' and '~': a path stays inside the " \
                   "material's folder or archive)"
    return None


def _hidden(name: str) -> bool:
    """A member an archiver added beside the material (macOS's __MACOSX/ and ._ files): never its document."""
    return any(part == "__MACOSX" or part.startswith(".") for part in name.split("/"))


class Source:
    """The document and the files it names. `document_file` names the document in messages."""

    document_file: str

    def read_document(self) -> bytes:
        raise NotImplementedError

    def read(self, path: str, field: str) -> tuple[bytes, str]:
        """The bytes of the file at `path` (relative to the document, already checked by `path_problem`)
        and its name for messages; `field` is the JSON path that names it."""
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_source(source: str | os.PathLike | bytes, limits: U3MLimits, name: str | None = None) -> Source:
    """The source of a `.u3m` file (its folder), a `.u3ma` file, or the bytes of either (`name` names
    them in messages; a document given as bytes has no folder, so it can name no image)."""
    if isinstance(source, bytes | bytearray | memoryview):
        data = bytes(source)
        file = name or "<bytes>"
        if data[:4] in ZIP_SIGNATURES:
            return ZipSource(io.BytesIO(data), len(data), file, limits)
        return BytesSource(data, file, limits)
    path = Path(source)
    file = name or str(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise MaterialError("no such file", file=file) from None
    except OSError as e:
        raise MaterialError(f"cannot be read: {e.strerror or e}", file=file) from None
    if stat.S_ISDIR(st.st_mode):
        raise MaterialError("is a folder: give the .u3m document inside it, or a .u3ma archive", file=file)
    if not stat.S_ISREG(st.st_mode):
        raise MaterialError("is not a regular file", file=file)
    handle = path.open("rb")
    try:
        if handle.read(4) in ZIP_SIGNATURES:
            return ZipSource(handle, st.st_size, file, limits)
    except BaseException:
        handle.close()
        raise
    handle.close()
    return FolderSource(path, st.st_size, file, limits)


_CHUNK_BYTES = 1 << 20


def _read_capped(handle: BinaryIO, cap: int) -> bytes:
    """At most cap + 1 bytes, so that a caller tells a file over the cap from one at it; read a chunk at
    a time, so that memory follows the bytes there are, not the cap (`read(n)` of a file allocates n)."""
    parts, n = [], 0
    while n <= cap:
        part = handle.read(min(_CHUNK_BYTES, cap + 1 - n))
        if not part:
            break
        parts.append(part)
        n += len(part)
    return b"".join(parts)


class BytesSource(Source):
    """A document given as bytes: no folder beside it."""

    def __init__(self, data: bytes, file: str, limits: U3MLimits):
        if len(data) > limits.max_document_bytes:
            raise MaterialError(f"the document is {len(data)} bytes; the limit is {limits.max_document_bytes} "
                                "(U3MLimits.max_document_bytes)", file=file)
        self._data, self.document_file = data, file

    def read_document(self) -> bytes:
        return self._data

    def read(self, path: str, field: str) -> tuple[bytes, str]:
        raise MaterialError(f"names the file '{path}', but a document given as bytes has no folder to read it from "
                            "(give the .u3m file's path, or a .u3ma archive)", file=self.document_file, field=field)


class FolderSource(Source):
    """A `.u3m` document and the folder it lies in."""

    def __init__(self, path: Path, size: int, file: str, limits: U3MLimits):
        if size > limits.max_document_bytes:
            raise MaterialError(f"the document is {size} bytes; the limit is {limits.max_document_bytes} "
                                "(U3MLimits.max_document_bytes)", file=file)
        self._path, self._limits, self.document_file = path, limits, file
        self._folder = path.parent
        self._real_folder = os.path.realpath(self._folder)

    def read_document(self) -> bytes:
        with self._path.open("rb") as f:
            data = _read_capped(f, self._limits.max_document_bytes)
        if len(data) > self._limits.max_document_bytes:   # it grew since it was measured
            raise MaterialError(f"the document is over {self._limits.max_document_bytes} bytes "
                                "(U3MLimits.max_document_bytes)", file=self.document_file)
        return data

    def read(self, path: str, field: str) -> tuple[bytes, str]:
        shown = str(self._folder / path)
        real = os.path.realpath(os.path.join(self._folder, *path.split("/")))
        if os.path.commonpath([real, self._real_folder]) != self._real_folder:
            raise MaterialError(f"'{path}' leads out of the material's folder {self._real_folder} (through a symbolic "
                                f"link, to {real}); a U3M names files inside its folder only",
                                file=self.document_file, field=field)
        try:
            st = os.stat(real)
        except FileNotFoundError:
            raise MaterialError(f"names the image '{path}', which is missing (no file {shown})",
                                file=self.document_file, field=field) from None
        except OSError as e:
            raise MaterialError(f"names '{path}', which cannot be read: {e.strerror or e}",
                                file=self.document_file, field=field) from None
        if not stat.S_ISREG(st.st_mode):
            raise MaterialError(f"names '{path}', which is not a regular file", file=self.document_file, field=field)
        cap = self._limits.max_file_bytes
        if st.st_size > cap:
            raise MaterialError(f"the file is {st.st_size} bytes; the limit is {cap} (U3MLimits.max_file_bytes)",
                                file=shown, field=field)
        try:
            with open(real, "rb") as f:
                data = _read_capped(f, cap)
        except OSError as e:
            raise MaterialError(f"cannot be read: {e.strerror or e}", file=shown, field=field) from None
        if len(data) > cap:
            raise MaterialError(f"the file is over {cap} bytes (U3MLimits.max_file_bytes)", file=shown, field=field)
        return data, shown


class ZipSource(Source):
    """A `.u3ma` archive: the zip's directory is judged (member count, declared sizes, compression
    ratios, names, encryption) before any member is read; members are then read with a byte cap."""

    def __init__(self, handle: BinaryIO, size: int, file: str, limits: U3MLimits):
        self._handle, self._limits, self._archive = handle, limits, file
        try:
            self._zip = self._open(size)
            self._judge(self._zip.infolist())
        except BaseException:
            handle.close()
            raise
        self._infos = {info.filename: info for info in self._zip.infolist()}
        documents = [n for n, info in self._infos.items()
                     if n.lower().endswith(".u3m") and not info.is_dir() and not _hidden(n)]
        if len(documents) != 1:
            found = ", ".join(sorted(documents)[:5]) or "none"
            self.close()
            raise MaterialError(f"a U3MA archive holds exactly one .u3m document; found {len(documents)} ({found})",
                                file=file)
        self._document = documents[0]
        self._base = posixpath.dirname(self._document)
        self.document_file = f"{file}:{self._document}"

    def _open(self, size: int) -> zipfile.ZipFile:
        limits, file = self._limits, self._archive
        if size > limits.max_archive_bytes:
            raise MaterialError(f"the archive is {size} bytes; the limit is {limits.max_archive_bytes} "
                                "(U3MLimits.max_archive_bytes)", file=file)
        # The end record, read by hand first: zipfile would parse the whole central directory (a ZipInfo
        # a record) before the member count could be judged.
        tail_size = min(size, _END_RECORD.size + _MAX_ZIP_COMMENT)
        self._handle.seek(size - tail_size)
        tail = self._handle.read(tail_size)
        at = tail.rfind(b"PK\x05\x06")
        if at < 0 or len(tail) - at < _END_RECORD.size:
            raise MaterialError("not a readable zip archive: no end-of-central-directory record (truncated?)",
                                file=file)
        _, _, _, _, members, directory_bytes, _, _ = _END_RECORD.unpack_from(tail, at)
        if members == 0xFFFF or directory_bytes == 0xFFFFFFFF:
            raise MaterialError("a ZIP64 archive; a U3MA is a plain zip (the spec disables ZIP64)", file=file)
        if members > limits.max_members or directory_bytes > limits.max_members * _MAX_DIRECTORY_BYTES_PER_MEMBER:
            raise MaterialError(f"the archive's directory declares {members} members in {directory_bytes} bytes; the "
                                f"limit is {limits.max_members} members (U3MLimits.max_members)", file=file)
        self._handle.seek(0)
        try:
            return zipfile.ZipFile(self._handle)
        except (zipfile.BadZipFile, OSError, EOFError, ValueError, struct.error) as e:
            raise MaterialError(f"not a readable zip archive (truncated or corrupt): {e}", file=file) from None

    def _judge(self, infos: list[zipfile.ZipInfo]) -> None:
        limits, file = self._limits, self._archive
        if len(infos) > limits.max_members:
            raise MaterialError(f"the archive holds {len(infos)} members; the limit is {limits.max_members} "
                                "(U3MLimits.max_members)", file=file)
        names: set[str] = set()
        total = 0
        for info in infos:
            member = f"{file}:{info.filename}"
            if info.filename in names:
                raise MaterialError("appears twice in the archive (U3MA names are unique)", file=member)
            names.add(info.filename)
            name = info.filename[:-1] if info.is_dir() else info.filename
            if (problem := path_problem(name)) is not None:
                raise MaterialError(f"the member's name {problem}", file=member)
            if info.flag_bits & 0x1:
                raise MaterialError("is encrypted (a U3MA's members are not)", file=member)
            if info.file_size > limits.max_file_bytes:
                raise MaterialError(f"declares {info.file_size} bytes uncompressed; the limit is "
                                    f"{limits.max_file_bytes} (U3MLimits.max_file_bytes)", file=member)
            ratio = info.file_size / max(info.compress_size, 1)
            if info.file_size > RATIO_FLOOR_BYTES and ratio > limits.max_compression_ratio:
                raise MaterialError(f"declares {info.file_size} bytes compressed into {info.compress_size} (a ratio "
                                    f"of {ratio:.0f}:1, over {limits.max_compression_ratio:.0f}:1: a zip bomb?)",
                                    file=member)
            total += info.file_size
        if total > limits.max_archive_bytes:
            raise MaterialError(f"its members declare {total} bytes uncompressed in all; the limit is "
                                f"{limits.max_archive_bytes} (U3MLimits.max_archive_bytes)", file=file)

    def _member(self, name: str, cap: int, field: str | None) -> bytes:
        info = self._infos[name]
        shown = f"{self._archive}:{name}"
        try:
            with self._zip.open(info) as f:
                data = _read_capped(f, cap)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError, NotImplementedError,
                RuntimeError) as e:
            raise MaterialError(f"cannot be read from the archive (corrupt or truncated): {e}", file=shown,
                                field=field) from None
        if len(data) > cap or len(data) != info.file_size:
            raise MaterialError(f"holds {'over ' if len(data) > cap else ''}{len(data)} bytes, not the "
                                f"{info.file_size} its directory declares", file=shown, field=field)
        return data

    def read_document(self) -> bytes:
        info = self._infos[self._document]
        if info.file_size > self._limits.max_document_bytes:
            raise MaterialError(f"the document is {info.file_size} bytes; the limit is "
                                f"{self._limits.max_document_bytes} (U3MLimits.max_document_bytes)",
                                file=self.document_file)
        return self._member(self._document, self._limits.max_document_bytes, None)

    def read(self, path: str, field: str) -> tuple[bytes, str]:
        name = posixpath.join(self._base, path)
        info = self._infos.get(name)
        if info is None or info.is_dir():
            raise MaterialError(f"names the image '{path}', which is missing (no member {name} in the archive)",
                                file=self.document_file, field=field)
        return self._member(name, self._limits.max_file_bytes, field), f"{self._archive}:{name}"

    def close(self) -> None:
        if hasattr(self, "_zip"):
            self._zip.close()
        self._handle.close()
