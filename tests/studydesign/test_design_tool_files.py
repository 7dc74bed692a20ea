"""design.toml as Notepad and Excel users save it (issue 33 items 6 and 7): a BOM, CRLF or UTF-16
reads as the shipped file does (it gave "Invalid statement (at line 1, column 1)" and a
UnicodeDecodeError traceback); a Windows code page is refused naming the byte and the fix.
Through ``python -m studydesign --design FILE check``."""

from __future__ import annotations

import codecs

import pytest

from studydesign import default_design_path, load_design
from studydesign.__main__ import main

FORMS = {
    "utf8_bom_crlf": lambda text: codecs.BOM_UTF8 + text.replace("\n", "\r\n").encode("utf-8"),
    "notepad_unicode": lambda text: (codecs.BOM_UTF16_LE
                                     + text.replace("\n", "\r\n").encode("utf-16-le")),
    "utf16_be": lambda text: codecs.BOM_UTF16_BE + text.encode("utf-16-be"),
}


@pytest.mark.parametrize("form", sorted(FORMS))
def test_a_design_saved_by_notepad_is_the_same_design(form, tmp_path, capsys):
    path = tmp_path / "design.toml"
    path.write_bytes(FORMS[form](default_design_path().read_text(encoding="utf-8")))
    assert main(["--design", str(path), "check"]) == 0
    assert "is a valid design (162 stimuli)" in capsys.readouterr().out
    ours, shipped = load_design(path), load_design()
    assert ours.stimuli().equals(shipped.stimuli())
    assert (ours.slider, ours.display, ours.sessions) == (shipped.slider, shipped.display,
                                                           shipped.sessions)


def test_a_design_in_a_windows_code_page_is_refused_with_the_fix(tmp_path, capsys):
    path = tmp_path / "design.toml"
    text = default_design_path().read_text(encoding="utf-8")
    path.write_bytes(("# viewing distance 57 cm, 1° = 1 cm\n" + text).encode("cp1252"))
    assert main(["--design", str(path), "check"]) != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "not UTF-8 text (byte 0xb0 on line 1, offset 27" in err and "save it as UTF-8" in err, err
