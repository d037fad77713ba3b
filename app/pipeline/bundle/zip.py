"""Reading an uploaded journey zip without trusting it.

Every entry name is checked before anything is read (relative, no ``..`` component, no backslash,
no drive letter, no NUL, not a symlink, not encrypted, not duplicated). Sizes are bounded twice:
by the sizes the zip declares, before reading, and by the bytes actually decompressed, while
reading, because a hostile zip can declare anything (``zipfile`` itself never yields more than the
declared size of an entry, and fails its CRC check when there was more). The declared total is also
bounded relative to the zip's own size (``BundleLimits.max_unpack_ratio``): real frames are already
compressed, so a bundle that inflates many times over is padding. Any failure is a ``BundleError``.
"""

from __future__ import annotations

import io
import os
import re
import shutil
import stat
import struct
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import BinaryIO, Mapping

from app.pipeline.config import BundleLimits
from app.pipeline.types import BundleError

__all__ = ["BundleLimits", "BundleZip", "open_bundle", "unsafe_reason"]

_CHUNK_BYTES = 1 << 20
_DRIVE = re.compile(r"^[A-Za-z]:")
_ZIP_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, struct.error, OSError,
               EOFError, ValueError, NotImplementedError, RuntimeError, IndexError, KeyError)


def _mb(n_bytes: int) -> str:
    return f"{n_bytes / 2**20:.1f} MiB" if n_bytes >= 2**20 else f"{n_bytes} bytes"


def unsafe_reason(name: str) -> str | None:
    """Why an entry name could escape the extraction directory, or None when it is safe."""
    if not name or name.startswith("/"):
        return "absolute path"
    if "\\" in name:
        return "backslash in name"
    if _DRIVE.match(name):
        return "drive letter"
    if "\x00" in name:
        return "NUL in name"
    if ".." in name.split("/"):
        return "'..' component"
    return None


class BundleZip:
    """An opened, name-checked bundle; ``files`` maps entry name -> ZipInfo (directories left out).

    Use as a context manager; ``read`` keeps a running count of decompressed bytes."""

    def __init__(self, zf: zipfile.ZipFile, limits: BundleLimits, zip_bytes: int):
        self._zf = zf
        self._limits = limits
        self._read_bytes = 0
        self.files: dict[str, zipfile.ZipInfo] = {}
        infos = zf.infolist()
        if len(infos) > limits.max_files:
            raise BundleError(f"bundle has {len(infos)} entries, more than the limit of "
                              f"{limits.max_files}")
        for info in infos:
            reason = unsafe_reason(info.filename)
            if reason is None and stat.S_ISLNK(info.external_attr >> 16):
                reason = "symbolic link"
            if reason:
                raise BundleError(f"unsafe path in bundle: {info.filename!r} ({reason}); entries "
                                  "must be plain relative paths like frames/000000.png")
            if info.flag_bits & 0x1:
                raise BundleError(f"bundle entry {info.filename} is encrypted; upload an "
                                  "unencrypted zip")
            if info.is_dir():
                continue
            if info.filename in self.files:
                raise BundleError(f"bundle contains {info.filename} twice")
            self.files[info.filename] = info
        declared = sum(i.file_size for i in self.files.values())
        if declared > limits.max_uncompressed_bytes:
            raise BundleError(f"bundle unpacks to {_mb(declared)}, more than the limit of "
                              f"{_mb(limits.max_uncompressed_bytes)}")
        if (declared > limits.max_unpack_ratio_floor_bytes
                and declared > limits.max_unpack_ratio * max(zip_bytes, 1)):
            raise BundleError(f"bundle unpacks to {_mb(declared)} from a {_mb(zip_bytes)} zip, "
                              f"more than {limits.max_unpack_ratio:g} times its size; frames are JPEG "
                              "or PNG and do not shrink in a zip, so this is padding")

    def __enter__(self) -> "BundleZip":
        return self

    def __exit__(self, *exc) -> None:
        self._zf.close()

    def check_sizes(self, caps: Mapping[str, int]) -> None:
        """Refuse, before anything is unpacked, an entry declaring more bytes than its cap."""
        for name, cap in caps.items():
            size = self.files[name].file_size
            if size > cap:
                raise BundleError(f"{name} is {_mb(size)}, more than the limit of {_mb(cap)} for "
                                  "this file")

    def open(self, name: str) -> BinaryIO:
        """A buffered stream of the entry (never more than its declared size; close it). Errors
        while it is read are BundleErrors; callers check the declared size first."""
        try:
            stream = self._zf.open(self.files[name])
        except _ZIP_ERRORS as exc:
            raise _corrupt(name, exc) from None
        return io.BufferedReader(_Member(name, stream), 1 << 16)

    def extract(self, name: str, out: Path) -> Path:
        """Write the entry to ``out`` in chunks (a video does not fit in memory), whole or not at
        all: it appears under its name only once complete. Callers check the declared size
        first."""
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, part = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".part")
        try:
            with os.fdopen(fd, "wb") as dst, self.open(name) as src:
                shutil.copyfileobj(src, dst, _CHUNK_BYTES)
            os.replace(part, out)
        finally:
            Path(part).unlink(missing_ok=True)
        return out

    def read(self, name: str, max_bytes: int | None = None) -> bytes:
        """The entry's bytes, stopping as soon as any size limit is passed."""
        info = self.files[name]
        cap = min(self._limits.max_member_bytes, max_bytes or self._limits.max_member_bytes)
        if info.file_size > cap:
            raise BundleError(f"{name} is {_mb(info.file_size)}, more than the limit of "
                              f"{_mb(cap)} for this file")
        chunks, n_bytes = [], 0
        try:
            with self._zf.open(info) as stream:
                while chunk := stream.read(_CHUNK_BYTES):
                    n_bytes += len(chunk)
                    self._read_bytes += len(chunk)
                    if n_bytes > min(cap, info.file_size):
                        raise BundleError(f"{name} unpacks to more bytes than the zip declares; "
                                          "the bundle is corrupt or hostile")
                    if self._read_bytes > self._limits.max_uncompressed_bytes:
                        raise BundleError("bundle unpacks to more than the limit of "
                                          f"{_mb(self._limits.max_uncompressed_bytes)}")
                    chunks.append(chunk)
        except BundleError:
            raise
        except _ZIP_ERRORS as exc:
            raise _corrupt(name, exc) from None
        return b"".join(chunks)


def _corrupt(name: str, exc: Exception) -> BundleError:
    return BundleError(f"{name} in the bundle is corrupt or unreadable ({exc}); re-create the zip")


class _Member(io.RawIOBase):
    """An entry's decompressing stream whose zip errors surface as BundleErrors."""

    def __init__(self, name: str, stream: BinaryIO):
        self._name, self._stream = name, stream

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        try:
            data = self._stream.read(len(buffer))
        except _ZIP_ERRORS as exc:
            raise _corrupt(self._name, exc) from None
        buffer[:len(data)] = data
        return len(data)

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        try:
            return self._stream.seek(offset, whence)
        except _ZIP_ERRORS as exc:
            raise _corrupt(self._name, exc) from None

    def tell(self) -> int:
        return self._stream.tell()

    def close(self) -> None:
        self._stream.close()
        super().close()


def open_bundle(zip_path: Path, limits: BundleLimits) -> BundleZip:
    """Open and name-check a bundle (close it with ``with``)."""
    try:
        zf = zipfile.ZipFile(zip_path)
    except _ZIP_ERRORS as exc:
        raise BundleError(f"not a zip file (or a corrupt one): {exc}; upload the journey as a "
                          ".zip bundle") from None
    try:
        return BundleZip(zf, limits, zip_path.stat().st_size)
    except BaseException:
        zf.close()
        raise
