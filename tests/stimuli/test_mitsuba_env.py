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


def _setup_in_a_fresh_process(code: str, **env):
    return subprocess.run([sys.executable, "-c", code], env=dict(os.environ, **env),
                          capture_output=True, text=True, timeout=180, check=False)


def test_no_variant_on_a_cuda_machine_tries_cuda_first_and_falls_back_with_a_message():
    """setup_mitsuba() with no variant: where a GPU is reported, cuda_ad_mono is tried first
    (here, with no GPU behind the report, it really fails to load) and the CPU variant is taken
    with a message naming why; without a GPU, llvm_ad_mono as before, silently."""
    code = ("import stimuli.mitsuba_env as me\n"
            "me.cuda_available = lambda: True\n"
            "print(me.setup_mitsuba())\n")
    res = _setup_in_a_fresh_process(code)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "llvm_ad_mono"
    assert "cuda_ad_mono failed" in res.stderr and "falling back" in res.stderr
    res = _setup_in_a_fresh_process("import stimuli.mitsuba_env as me\nprint(me.setup_mitsuba())")
    assert res.returncode == 0 and res.stdout.strip() == "llvm_ad_mono"
    assert "falling back" not in res.stderr


def test_no_variant_on_a_cuda_machine_does_not_demand_libllvm(tmp_path):
    """The CUDA attempt comes before libLLVM is looked for: with a broken DRJIT_LIBLLVM_PATH the
    error is the LLVM one only after CUDA was tried (a GPU machine without libLLVM renders)."""
    code = ("import stimuli.mitsuba_env as me\n"
            "me.cuda_available = lambda: True\n"
            "me.setup_mitsuba()\n")
    res = _setup_in_a_fresh_process(code, DRJIT_LIBLLVM_PATH=str(tmp_path / "nope.so"))
    assert res.returncode != 0
    err = res.stderr
    assert err.index("cuda_ad_mono failed") < err.index("is not a file")
