"""labfiles.text: the encodings, line ends and separators other tools save files in, read or
refused with the fix; append-only record files re-saved by such a tool."""

from __future__ import annotations

import codecs
import io
import warnings

import pandas as pd
import pytest

from labfiles import (
    LabFileError,
    RecordFile,
    TornTailWarning,
    csv_fields_check,
    csv_separator,
    decode_text,
    read_csv_frame,
    read_csv_records,
    read_records,
    read_text,
    read_toml,
)

TEXT = 'name,value\r\n"Müller, A.",1.5\r\n"say ""hi""\r\nthere",2\r\n'


@pytest.mark.parametrize("data", [
    TEXT.encode("utf-8"),
    codecs.BOM_UTF8 + TEXT.encode("utf-8"),
    codecs.BOM_UTF16_LE + TEXT.encode("utf-16-le"),
    codecs.BOM_UTF16_BE + TEXT.encode("utf-16-be"),
    codecs.BOM_UTF32_LE + TEXT.encode("utf-32-le"),
], ids=["utf8", "utf8_bom", "utf16_le", "utf16_be", "utf32_le"])
def test_every_unicode_form_decodes_to_the_same_text(data, tmp_path):
    assert decode_text(data, "f.csv") == TEXT
    path = tmp_path / "f.csv"
    path.write_bytes(data)
    assert read_text(path) == TEXT.replace("\r\n", "\n")
    frame = read_csv_frame(path)
    assert frame["name"].tolist() == ["Müller, A.", 'say "hi"\nthere']
    assert frame["value"].tolist() == [1.5, 2]


def test_a_plain_file_reads_exactly_as_pandas_reads_it(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("a,b,c\n1,x,\n2,,0.1\n", encoding="utf-8")
    pd.testing.assert_frame_equal(read_csv_frame(path, dtype={"b": str}),
                                  pd.read_csv(path, dtype={"b": str}))


def test_a_code_page_byte_is_refused_naming_its_line_and_the_fix(tmp_path):
    path = tmp_path / "f.csv"
    path.write_bytes("a,b\r\n1,2\r\n3,µ\r\n".encode("cp1252"))
    with pytest.raises(LabFileError, match=r"not UTF-8 text \(byte 0xb5 on line 3.*save it as "
                                           r"UTF-8 \(Excel: Save As 'CSV UTF-8"):
        read_csv_frame(path)


@pytest.mark.parametrize("header, sep", [("a;b;c", ";"), ("a\tb", "\t"), ("a|b", "|"),
                                         ("a,b", ","), ("a", ","), ('"a;b",c', ",")])
def test_the_separator_of_a_header(header, sep):
    assert csv_separator(header) == sep


def test_a_semicolon_csv_is_refused_naming_the_separator(tmp_path):
    path = tmp_path / "f.csv"
    path.write_bytes(b"# a comment, with a comma\r\nlevel;lum\r\n0,5;1,25\r\n")
    with pytest.raises(LabFileError, match=r"separated by semicolons.*'\.' as the decimal mark"):
        read_csv_frame(path, comment="#")


def test_a_toml_with_a_bom_and_crlf_is_read(tmp_path):
    path = tmp_path / "x.toml"
    path.write_bytes(codecs.BOM_UTF8 + b"[a]\r\nb = 1\r\n")
    assert read_toml(path) == {"a": {"b": 1}}


def test_records_appended_to_an_excel_resave_end_as_its_lines_do(tmp_path):
    """A BOM, CRLF and quoted header names (Excel, R): the same header; new records CRLF."""
    path = tmp_path / "r.csv"
    path.write_bytes(codecs.BOM_UTF8 + b'"a","b","c"\r\n1,2,3\r\n')
    with RecordFile(path, header="a,b,c", check=csv_fields_check(3)) as rec:
        rec.append("4,5,6")
    assert path.read_bytes() == codecs.BOM_UTF8 + b'"a","b","c"\r\n1,2,3\r\n4,5,6\r\n'
    assert read_records(path, check=csv_fields_check(3)) == ['"a","b","c"', "1,2,3", "4,5,6"]
    assert read_csv_records(path)["a"].tolist() == [1, 4]


@pytest.mark.parametrize("data, match", [
    (b"a;b;c\r\n1;2;3,5\r\n", "separated by semicolons"),
    (codecs.BOM_UTF16_LE + "a,b,c\r\n1,2,3\r\n".encode("utf-16-le"), "UTF-16 text"),
], ids=["semicolons", "utf16"])
def test_a_record_file_in_another_form_is_refused_untouched(data, match, tmp_path):
    path = tmp_path / "r.csv"
    path.write_bytes(data)
    with pytest.raises(LabFileError, match=match):
        RecordFile(path, header="a,b,c", check=csv_fields_check(3)).__enter__()
    assert path.read_bytes() == data
    assert list(tmp_path.iterdir()) == [path]


def test_a_utf16_record_file_is_read_with_the_torn_tail_rule_and_left_as_it_is(tmp_path):
    path = tmp_path / "r.csv"
    data = codecs.BOM_UTF16_LE + "a,b,c\r\n1,2,3\r\n4,5".encode("utf-16-le")
    path.write_bytes(data)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TornTailWarning)
        frame = read_csv_records(path, repair=False)
    assert frame.to_dict("list") == {"a": [1], "b": [2], "c": [3]}
    assert any("line 3 is torn" in str(w.message) for w in caught)
    assert path.read_bytes() == data
    assert pd.read_csv(io.StringIO(read_text(path))).shape == (2, 3)
