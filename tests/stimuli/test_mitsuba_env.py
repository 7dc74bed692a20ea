"""Mitsuba set-up: libLLVM version checks with the fix in the message; variant recorded."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from stimuli.mitsuba_env import LLVM_VARIANTS, MIN_LLVM_MAJOR, libllvm_major


@pytest.mark.parametrize("name,major", [("libLLVM.so.19.1", 19), ("libLLVM-15.so", 15),
                                        ("libLLVM-14.so.1", 14), ("libLLVM.so", None)])
def test_llvm_version_from_file_name(tmp_path, name, major):
    f = tmp_path / name
    f.write_bytes(b"")
    assert libllvm_major(f) == major


def _check_env(env_path):
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(env_path))
    return subprocess.run([sys.executable, "-m", "stimuli", "check-env"], env=env,
                          capture_output=True, text=True, timeout=120, check=False)


def test_old_libllvm_is_refused_with_the_fix(tmp_path):
    """libLLVM 15 would abort the process at the first kernel; we refuse it before loading it."""
    old = tmp_path / "libLLVM-15.so"
    old.write_bytes(b"")
    res = _check_env(old)
    assert res.returncode == 1
    assert "LLVM 15" in res.stderr and "libllvm19" in res.stderr and "DRJIT_LIBLLVM_PATH" in res.stderr
    assert MIN_LLVM_MAJOR == 17


def test_missing_libllvm_path_is_refused(tmp_path):
    res = _check_env(tmp_path / "nope.so")
    assert res.returncode == 1 and "is not a file" in res.stderr


def test_variant_is_an_llvm_one(mitsuba_variant):
    assert mitsuba_variant in LLVM_VARIANTS
