"""Reading text files other tools wrote: the encodings and CSV forms a lab's files arrive in.

A file the lab edits or re-saves comes back in whatever its tool writes. Every reader of the
project opens text through here, so that the same rules hold for a session CSV, a readings file,
a manifest, a plan, a gloss table, an analysis input and every TOML file:

- **Line ends**: LF, CRLF (Excel, MATLAB on Windows, RFC 4180) and CR are read alike.
- **Byte-order marks**: a UTF-8 BOM (Excel's "CSV UTF-8", Notepad) is dropped; a UTF-16 or
  UTF-32 file with its BOM (Excel's "Unicode text", Notepad's "Unicode") is decoded. An
  append-only record file in UTF-16 is refused (records are appended as UTF-8) with the fix.
- **Quoted fields** (RFC 4180: ``"a, b"``, ``""`` for a quote, a line break inside quotes) are
  read by the CSV parsers (:mod:`csv`, :func:`pandas.read_csv`) the readers use.
- **Other separators**: a CSV whose header is one field holding ``;``, tabs or ``|`` (Excel in
  a language with a decimal comma; "Unicode text" is tab-separated) is refused naming the
  separator and the fix, instead of "missing columns".
- **Other encodings**: bytes that are not UTF-8 (a Windows code page) are refused naming the
  first bad byte and the fix.

Every refusal is a :class:`~labfiles.LabFileError` whose one line names the file, the problem and
how to save the file instead. Files the project writes (UTF-8, LF, commas) read exactly as
before: nothing here changes a well-formed file's values.
"""

from __future__ import annotations

import codecs
import csv
import io
import tomllib
from pathlib import Path

from labfiles.errors import LabFileError

__all__ = [
    "SAVE_AS_UTF8",
    "check_comma_separated",
    "csv_separator",
    "decode_text",
    "read_csv_frame",
    "read_text",
    "read_toml",
    "separator_message",
    "text_encoding",
    "utf8_records",
]

#: How to save a file so that every reader takes it (the fix in each refusal).
SAVE_AS_UTF8 = ("save it as UTF-8 (Excel: Save As 'CSV UTF-8 (Comma delimited) (*.csv)'; "
                "Notepad: Save As with Encoding 'UTF-8'), then run the same command again")

# UTF-32-LE's BOM starts with UTF-16-LE's: look for the longer ones first.
_BOMS = (
    (codecs.BOM_UTF32_LE, "utf-32"),
    (codecs.BOM_UTF32_BE, "utf-32"),
    (codecs.BOM_UTF8, "utf-8-sig"),
    (codecs.BOM_UTF16_LE, "utf-16"),
    (codecs.BOM_UTF16_BE, "utf-16"),
)
_SEPARATORS = {";": "semicolons (';')", "\t": "tabs", "|": "bars ('|')"}


def text_encoding(data: bytes) -> str:
    """The codec a file's bytes are read with: from its byte-order mark, else ``"utf-8"``.

    Returns
    -------
    {"utf-8", "utf-8-sig", "utf-16", "utf-32"}
        The ``-sig``, ``utf-16`` and ``utf-32`` codecs drop the BOM when decoding.
    """
    for bom, name in _BOMS:
        if data.startswith(bom):
            return name
    return "utf-8"


def decode_text(data: bytes, path) -> str:
    """A file's bytes as text, its BOM dropped; line ends are left as they are.

    Parameters
    ----------
    data : bytes
        The whole file.
    path : str or Path
        For the message.

    Raises
    ------
    LabFileError
        If the bytes are not text in the encoding their BOM names (UTF-8 without one), naming
        the first bad byte and :data:`SAVE_AS_UTF8`.
    """
    encoding = text_encoding(data)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        what = "UTF-8" if encoding.startswith("utf-8") else encoding.upper()
        line = data.count(b"\n", 0, exc.start) + 1
        raise LabFileError(
            f"{path} is not {what} text (byte 0x{data[exc.start]:02x} on line {line}, offset "
            f"{exc.start}; "
            f"saved in a Windows code page, e.g. Excel's plain 'CSV (Comma delimited)'?): "
            f"{SAVE_AS_UTF8}") from None


def read_text(path) -> str:
    """A text file, decoded (:func:`decode_text`) and with CRLF and CR line ends read as LF
    (as Python's text mode does).

    Raises
    ------
    LabFileError
        Not text in a known encoding.
    OSError
        As the system raises it (e.g. ``FileNotFoundError``).
    """
    text = decode_text(Path(path).read_bytes(), path)
    return text.replace("\r\n", "\n").replace("\r", "\n")


def read_toml(path) -> dict:
    """A TOML file, parsed, whatever its line ends and BOM (:func:`read_text`).

    Raises
    ------
    LabFileError
        Not text in a known encoding.
    tomllib.TOMLDecodeError
        Not valid TOML (the caller names what the file is).
    """
    return tomllib.loads(read_text(path))


def csv_separator(header: str) -> str:
    """``","``, or the separator a CSV's header line plainly uses instead.

    A header that parses into one field holding ``;``, a tab or ``|`` uses that character.
    """
    fields = next(csv.reader([header.rstrip("\r\n")]), [])
    if len(fields) == 1:
        for sep in _SEPARATORS:
            if sep in fields[0]:
                return sep
    return ","


def separator_message(path, sep: str) -> str:
    """The refusal of a CSV separated by ``sep``: the problem and how to save it instead."""
    return (f"{path}: its columns are separated by {_SEPARATORS.get(sep, repr(sep))}, not "
            "commas (Excel writes so where the decimal mark is a comma, and as 'Unicode text'); "
            "save it as 'CSV UTF-8 (Comma delimited) (*.csv)' with '.' as the decimal mark, "
            "then run the same command again")


def check_comma_separated(text: str, path, *, comment: str | None = None) -> None:
    """Refuse a CSV (as text) whose header is separated by something other than commas.

    Parameters
    ----------
    text : str
        The decoded file.
    path : str or Path
        For the message.
    comment : str, optional
        Lines starting with it (before the header) are skipped, as ``pandas.read_csv`` does.

    Raises
    ------
    LabFileError
        Naming the separator and the fix (:func:`separator_message`).
    """
    for line in io.StringIO(text):
        if line.strip() and not (comment and line.lstrip().startswith(comment)):
            sep = csv_separator(line)
            if sep != ",":
                raise LabFileError(separator_message(path, sep))
            return


def read_csv_frame(path, **read_csv_kw):
    """A CSV file as a DataFrame: any line ends, BOM or UTF-16, commas required.

    Parameters
    ----------
    path : str or Path
    **read_csv_kw
        Passed to :func:`pandas.read_csv` (e.g. ``dtype``, ``comment``).

    Raises
    ------
    LabFileError
        Not text in a known encoding, or another separator than commas.
    OSError, pandas.errors.ParserError, pandas.errors.EmptyDataError
        As :func:`pandas.read_csv` raises them.
    """
    import pandas as pd

    text = read_text(path)
    check_comma_separated(text, path, comment=read_csv_kw.get("comment"))
    return pd.read_csv(io.StringIO(text), **read_csv_kw)


def utf8_records(data: bytes, path, *, writing: bool) -> bytes:
    """The bytes of an append-only record file as UTF-8, for the torn-tail rule.

    A UTF-8 file (with or without a BOM) is returned as it is. A UTF-16 or UTF-32 file is
    transcoded for a reader; a writer, which appends UTF-8 records, refuses it.

    Raises
    ------
    LabFileError
        A UTF-16/32 file opened for ``writing``, or bytes that do not decode.
    """
    encoding = text_encoding(data)
    if encoding in ("utf-8", "utf-8-sig"):
        return data
    if writing:
        raise LabFileError(
            f"{path} is {encoding.upper()} text (Excel's 'Unicode text' or Notepad's 'Unicode'?), "
            f"and records are appended to it as UTF-8: {SAVE_AS_UTF8}")
    return decode_text(data, path).encode("utf-8")
