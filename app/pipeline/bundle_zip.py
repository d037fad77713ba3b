"""Reading an uploaded journey zip without trusting it.

Every entry name is checked before anything is read (relative, no ``..`` component, no backslash,
no drive letter, no NUL, not a symlink, not encrypted, not duplicated). Sizes are bounded twice:
by the sizes the zip declares, before reading, and by the bytes actually decompressed, while
reading, because a hostile zip can declare anything. Any failure is a ``BundleError``.
"""

from __future__ import annotations

import re
import stat
import struct
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

from app.pipeline.types import BundleError

_CHUNK_BYTES = 1 << 20
_DRIVE = re.compile(r"^[A-Za-z]:")
_ZIP_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, struct.error, OSError,
               EOFError, ValueError, NotImplementedError, RuntimeError, IndexError, KeyError)


@dataclass(frozen=True)
class BundleLimits:
    """Upper bounds on what a bundle may unpack to (declared and actually read)."""

    max_uncompressed_bytes: int = 8 * 2**30
    max_files: int = 200_000
    max_frames: int = 100_000
    # One entry is read into memory to be checked; frames and tables are far smaller than this.
    max_member_bytes: int = 256 * 2**20
    # Checked on the image header before decoding: a tiny PNG can declare gigapixels.
    max_frame_pixels: int = 64 * 2**20


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

    def __init__(self, zf: zipfile.ZipFile, limits: BundleLimits):
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

    def __enter__(self) -> "BundleZip":
        return self

    def __exit__(self, *exc) -> None:
        self._zf.close()

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
            raise BundleError(f"{name} in the bundle is corrupt or unreadable ({exc}); "
                              "re-create the zip") from None
        return b"".join(chunks)


def open_bundle(zip_path: Path, limits: BundleLimits) -> BundleZip:
    """Open and name-check a bundle (close it with ``with``)."""
    try:
        zf = zipfile.ZipFile(zip_path)
    except _ZIP_ERRORS as exc:
        raise BundleError(f"not a zip file (or a corrupt one): {exc}; upload the journey as a "
                          ".zip bundle") from None
    try:
        return BundleZip(zf, limits)
    except BaseException:
        zf.close()
        raise
