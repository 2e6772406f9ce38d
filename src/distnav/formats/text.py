"""The one preamble of every text reader (RINEX and the other GNSS products, APRIL range logs, the UWB CSV files,
the ``--graph`` file): the bytes checked to be text before anything else is judged.

NUL bytes (binary data, text saved as UTF-16) are refused naming the line — they seldom end with a newline, and are
not a "truncated" file; a leading UTF-8 byte-order mark (a Windows editor's) is dropped, as it is not part of the
first line; a byte the reader's encoding does not allow is refused naming the line and the byte. The CSV readers
(UWB files, ``--graph``) then split lines with :func:`csv_rows`, which names a line the csv module refuses.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path

from distnav.errors import DataFileError

__all__ = ["csv_rows", "decoded_text", "plain_text", "text_bytes"]

UTF8_BOM = b"\xef\xbb\xbf"


def text_bytes(path: Path, raw: bytes, expected: str = "a plain ASCII text file") -> bytes:
    """``raw`` (the bytes of ``path``, decompressed) without a leading UTF-8 byte-order mark; NUL bytes refused with
    a :class:`DataFileError` naming the file, the line and what was ``expected``."""
    nul = raw.find(b"\x00")
    if nul >= 0:
        line = raw.count(b"\n", 0, nul) + 1
        raise DataFileError(
            f"{path}, line {line}: binary data (NUL bytes): expected {expected} (not UTF-16, not a binary format)"
        )
    return raw[len(UTF8_BOM) :] if raw.startswith(UTF8_BOM) else raw


def decoded_text(raw: bytes, p: Path, encoding: str, expected: str) -> str:
    """``raw`` (the bytes of file ``p``) decoded with ``encoding``, or a :class:`DataFileError` naming the file, the
    line and the byte that is not ``expected`` (its message goes on from "byte 0x.. is not ")."""
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise DataFileError(f"{p}, line {line}: byte 0x{raw[exc.start]:02x} is not {expected}") from None


def plain_text(path: Path, raw: bytes, *, encoding: str, expected: str, undecodable: str) -> str:
    """:func:`text_bytes` then :func:`decoded_text`: the text of ``path`` (``expected`` names what it should hold,
    ``undecodable`` goes on from "byte 0x.. is not ")."""
    return decoded_text(text_bytes(path, raw, expected), path, encoding, undecodable)


def csv_rows(p: Path, lines: list[str]) -> Iterator[tuple[int, list[str]]]:
    """The fields of each line, numbered from 1; a line the csv module refuses (a field over its 128 KiB limit,
    which was a traceback) is a :class:`DataFileError` naming it."""
    reader = csv.reader(lines)
    number = 0
    while True:
        number += 1
        try:
            fields = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise DataFileError(f"{p}:{number}: not a CSV line ({exc})") from None
        yield number, fields
