"""A file as other tools save it: what a lab's file looks like after Excel, Notepad, R or MATLAB.

Each function takes a file the project wrote (UTF-8, LF, commas) and writes it back the way a
tool re-saves it, byte for byte, so the readers' tests meet what an operator's files hold:

===================================  =====================================================
``excel_csv_utf8``                   Excel "CSV UTF-8 (Comma delimited)": a BOM, CRLF
``crlf``                             Excel "CSV (Comma delimited)", MATLAB on Windows: CRLF
``quoted``                           R ``write.csv``, MATLAB ``writetable``: every field in
                                     quotes ("" for a quote), RFC 4180
``notepad_unicode``                  Notepad "Unicode": UTF-16 LE with its BOM, CRLF
``excel_unicode_text``               Excel "Unicode text": UTF-16 LE, BOM, tab-separated
``excel_semicolons``                 Excel where the decimal mark is a comma: ``;`` between
                                     fields, decimal commas, CRLF
``windows_code_page``                Excel's plain "CSV" with a non-ASCII value: cp1252
===================================  =====================================================
"""

from __future__ import annotations

import codecs
import csv
import io
import re
from pathlib import Path


def _rows(path: Path) -> list[list[str]]:
    return list(csv.reader(io.StringIO(path.read_text(encoding="utf-8"), newline="")))


def _write_rows(rows, *, delimiter=",", quoting=csv.QUOTE_MINIMAL, lineterminator="\r\n") -> str:
    buf = io.StringIO()
    csv.writer(buf, delimiter=delimiter, quoting=quoting,
               lineterminator=lineterminator).writerows(rows)
    return buf.getvalue()


def crlf(path: Path) -> Path:
    """Line ends CRLF (RFC 4180's)."""
    text = path.read_text(encoding="utf-8")
    path.write_bytes(text.replace("\n", "\r\n").encode("utf-8"))
    return path


def excel_csv_utf8(path: Path) -> Path:
    """A UTF-8 BOM and CRLF line ends."""
    text = path.read_text(encoding="utf-8")
    path.write_bytes(codecs.BOM_UTF8 + text.replace("\n", "\r\n").encode("utf-8"))
    return path


def quoted(path: Path) -> Path:
    """Every field of a CSV in double quotes, LF line ends."""
    path.write_text(_write_rows(_rows(path), quoting=csv.QUOTE_ALL, lineterminator="\n"),
                    encoding="utf-8", newline="")
    return path


def notepad_unicode(path: Path) -> Path:
    """UTF-16 LE with its BOM, CRLF line ends."""
    text = path.read_text(encoding="utf-8")
    path.write_bytes(codecs.BOM_UTF16_LE + text.replace("\n", "\r\n").encode("utf-16-le"))
    return path


def excel_unicode_text(path: Path) -> Path:
    """UTF-16 LE with its BOM, fields separated by tabs, CRLF line ends."""
    text = _write_rows(_rows(path), delimiter="\t")
    path.write_bytes(codecs.BOM_UTF16_LE + text.encode("utf-16-le"))
    return path


_DECIMAL = re.compile(r"^-?\d+\.\d+(e[-+]?\d+)?$")


def excel_semicolons(path: Path) -> Path:
    """Fields separated by ';', numbers with a decimal comma, CRLF line ends."""
    rows = [[v.replace(".", ",") if _DECIMAL.match(v) else v for v in row] for row in _rows(path)]
    path.write_bytes(_write_rows(rows, delimiter=";").encode("utf-8"))
    return path


def windows_code_page(path: Path, *, column: str, value: str = "Müller") -> Path:
    """CRLF, cp1252 bytes, and ``value`` (non-ASCII) in the first data row's ``column``."""
    rows = _rows(path)
    rows[1][rows[0].index(column)] = value
    path.write_bytes(_write_rows(rows).encode("cp1252"))
    return path
