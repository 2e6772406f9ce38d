"""Reading (compressed) text files by content: gzip, Unix compress (``.Z``, older IGS archives), bzip2 and zip,
decoded as latin-1 (any byte is accepted); broken compressed data, binary data and a cut final line are refused
naming the file and line. Used by every GNSS reader (RINEX, SP3, IONEX, Bias-SINEX)."""

from __future__ import annotations

import gzip
import io
import zipfile
from pathlib import Path

from distnav.errors import DataFileError
from distnav.formats.text import text_bytes

__all__ = ["COMPRESSED_MAGIC", "read_bytes", "read_text_file"]


COMPRESSED_MAGIC = (b"\x1f\x9d", b"BZh", b"PK\x03\x04")  # Unix compress (.Z), bzip2, zip


def _unix_decompress(raw: bytes, path: Path) -> bytes:
    try:
        import ncompress  # installed with hatanaka (the gnss extra)
    except ImportError:
        from distnav._optional import install_hint

        raise DataFileError(
            f"{path}: Unix-compressed (.Z); install the 'ncompress' package ({install_hint('gnss')})"
        ) from None
    out: bytes = ncompress.decompress(raw)
    return out


def _decompress(path: Path, raw: bytes) -> bytes:
    """``raw`` decompressed by content (gzip, Unix compress, bzip2, zip; unchanged when none of them);
    :class:`DataFileError` naming the file and the format when the compressed data are broken."""
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except EOFError:
            raise DataFileError(f"{path}: the gzip data end early (the file is truncated; download it again)") from None
        except OSError:  # gzip.BadGzipFile and zlib errors
            raise DataFileError(
                f"{path}: starts like gzip but is not valid gzip data (expected a .gz file written by gzip)"
            ) from None
    if raw.startswith(COMPRESSED_MAGIC):
        kind = "Unix compress (.Z)" if raw[:2] == b"\x1f\x9d" else "bzip2" if raw[:3] == b"BZh" else "zip"
        try:
            if raw[:2] == b"\x1f\x9d":
                raw = _unix_decompress(raw, path)
            elif raw[:3] == b"BZh":
                import bz2

                raw = bz2.decompress(raw)
            else:
                with zipfile.ZipFile(io.BytesIO(raw)) as z:
                    names = z.namelist()
                    if len(names) != 1:
                        raise DataFileError(f"{path}: a zip archive of {len(names)} files (one expected)")
                    raw = z.read(names[0])
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            raise DataFileError(
                f"{path}: starts like {kind} data but could not be decompressed (truncated or "
                f"not {kind}; download it again)"
            ) from None
    return raw


def read_bytes(path: Path) -> bytes:
    """A file's bytes, decompressed by content: gzip, Unix compress (``.Z``, older IGS archives), bzip2, zip (Hatanaka
    compression is left to the caller)."""
    if not path.exists():
        raise DataFileError(f"{path}: file not found")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read the file ({exc.strerror or 'read error'})") from None
    return _decompress(path, raw)


def _text_lines(path: Path, raw: bytes) -> list[str]:
    return text_bytes(path, raw).decode("latin-1").splitlines()


def read_text_file(path: Path, *, whole_lines: bool = False) -> list[str]:
    """The lines of a plain or compressed (:func:`read_bytes`) text file, decoded as latin-1 (any byte is accepted);
    broken compressed data and a file with NUL bytes (binary data, UTF-16) are refused naming the file (and line);
    a leading UTF-8 byte-order mark is dropped.
    ``whole_lines``: a file that ends inside a line (no final newline: a cut download) is refused too."""
    raw = text_bytes(path, read_bytes(path))
    if whole_lines:
        _ends_with_newline(path, raw)
    return _text_lines(path, raw)


def _ends_with_newline(path: Path, raw: bytes) -> None:
    if raw and not raw.endswith(b"\n"):  # records are lines: a cut download ends inside one
        last = raw.count(b"\n") + 1
        raise DataFileError(f"{path}, line {last}: the file ends inside a line (no final newline): it is truncated")
