"""The PsychoPy dialog for a missing participant/session, typed into through XTEST.

Where Qt's X11 plugin cannot load (Debian packages libxcb-icccm4, libxcb-keysyms1,
libxcb-cursor0 missing) the app must say so and exit 2 instead of letting Qt abort; that branch
is checked, and then the test fails: `make test` installs those packages, so CI tests the dialog.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from experiment.__main__ import _dialog_problem

from .conftest import REPO, app_env

pytestmark = pytest.mark.xvfb


def _viewable_windows(d):
    from Xlib import X

    return [w for w in d.screen().root.query_tree().children
            if w.get_attributes().map_state == X.IsViewable]


def _type(d, text: str) -> None:
    from Xlib import XK, X
    from Xlib.ext import xtest

    shift = d.keysym_to_keycode(XK.XK_Shift_L)
    names = {" ": "space", "\t": "Tab", "\n": "Return"}
    for ch in text:
        code = d.keysym_to_keycode(XK.string_to_keysym(names.get(ch, ch)))
        upper = ch.isalpha() and ch.isupper()
        if upper:
            xtest.fake_input(d, X.KeyPress, shift)
        xtest.fake_input(d, X.KeyPress, code)
        xtest.fake_input(d, X.KeyRelease, code)
        if upper:
            xtest.fake_input(d, X.KeyRelease, shift)
        d.sync()
        time.sleep(0.05)


def test_dialog_asks_for_participant_and_session(session_files):
    f = session_files
    cmd = [sys.executable, "-m", "experiment", "run", "--stimuli", str(f["manifest"]),
           "--calibration", str(f["calibration"]), "--data", str(f["data"])]
    problem = _dialog_problem()
    if problem is not None:
        res = subprocess.run(cmd, cwd=REPO, env=app_env(), capture_output=True, text=True,
                             timeout=120, check=False)
        assert res.returncode == 2
        assert "cannot show the session dialog" in res.stderr and problem in res.stderr
        pytest.fail(f"the dialog could not be tested: {problem} (`make system-deps` installs the "
                    "Debian packages; the app's clear error for this case was checked)")
    from Xlib import display

    d = display.Display()
    before = len(_viewable_windows(d))
    proc = subprocess.Popen(cmd, cwd=REPO, env=app_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        t_end = time.monotonic() + 60
        while len(_viewable_windows(d)) <= before:
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < t_end, "no dialog appeared"
            time.sleep(0.1)
        time.sleep(1.0)
        # An invalid id typed into the dialog must reach the app's own check.
        _type(d, "P 7\t1\n")
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        d.close()
    assert proc.returncode == 2, err
    assert "participant id 'P 7' is not valid" in err
