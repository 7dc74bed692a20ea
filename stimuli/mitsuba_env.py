"""Mitsuba 3 set-up: the variant, the libLLVM it needs, and a smoke-test render.

Variants (:data:`SUPPORTED_VARIANTS`): ``llvm_ad_*`` on the CPU, ``cuda_ad_*`` on an NVIDIA GPU, each
in ``mono`` (one luminance channel), ``rgb`` or ``spectral``. The stimuli are achromatic (grey Ward
materials): light transport is linear in the emitted radiance and a grey BSDF treats every
wavelength alike, so the luminance of a render under a coloured probe equals the render under the
probe's luminance. Monochrome rendering is therefore exact for them and the default
(:func:`default_variant`); spectral is kept for chromatic materials. Mitsuba's JIT variants compile
every render into one vectorised kernel; the Python Ward BSDF (:mod:`stimuli.ward`) is traced into
that kernel, so it runs as fast as the built-in C++ BSDFs.
Dr.Jit loads libLLVM at run time. libLLVM 15 and 16 let the variant load and then abort the whole
process at the first kernel that uses ``dr.maximum`` ("LLVM ERROR: Cannot select: fmaximum"), which
no ``try`` can catch. So :func:`setup_mitsuba` checks the library's version *before* Dr.Jit loads it
(from ``DRJIT_LIBLLVM_PATH``, or the newest libLLVM >= 17 found in the system library folders) and
then renders a tiny scene with the Ward BSDF; any failure raises :class:`MitsubaSetupError` naming
the fix (``apt-get install libllvm19`` and ``export DRJIT_LIBLLVM_PATH=...``).
"""

from __future__ import annotations

import os
import re
import threading
from pathlib import Path

from stimuli.errors import MitsubaSetupError

__all__ = [
    "LLVM_VARIANTS",
    "MIN_LLVM_MAJOR",
    "SUPPORTED_VARIANTS",
    "cuda_available",
    "default_variant",
    "find_libllvm",
    "is_monochrome",
    "libllvm_major",
    "setup_mitsuba",
    "use_llvm_hint",
]

#: CPU variants tried in order when none is named: monochrome (exact for the achromatic stimuli),
#: spectral (as the source study rendered), RGB.
LLVM_VARIANTS = ("llvm_ad_mono", "llvm_ad_spectral", "llvm_ad_rgb")
#: GPU variants (the same three colour modes on CUDA).
CUDA_VARIANTS = ("cuda_ad_mono", "cuda_ad_spectral", "cuda_ad_rgb")
#: Variants the renderer and the Ward plugin support (scalar ones for small tests only).
SUPPORTED_VARIANTS = LLVM_VARIANTS + CUDA_VARIANTS + ("scalar_rgb", "scalar_spectral")
#: Oldest libLLVM that compiles Dr.Jit's kernels (15 and 16 abort at ``dr.maximum``).
MIN_LLVM_MAJOR = 17
_LIB_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
             "/usr/local/lib")
_FIX = ("install LLVM >= 17 (Debian/Ubuntu: `sudo apt-get install libllvm19`, which `make` does) "
        "and point Dr.Jit at it: `export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1`")

_state: dict = {}
#: One set-up at a time per process: a Dask worker runs tasks on several threads, and two threads
#: importing Mitsuba or selecting its variant at once saw a half-initialised module
#: ("module 'mitsuba' has no attribute 'variants'").
_setup_lock = threading.RLock()


def libllvm_major(path: str | Path) -> int | None:
    """LLVM major version from a library file name (``libLLVM.so.19.1``, ``libLLVM-15.so``).

    Follows symbolic links first. Returns None when the name carries no version.
    """
    real = Path(os.path.realpath(path)).name
    for name in (real, Path(path).name):
        m = re.search(r"libLLVM[-.](?:so\.)?(\d+)", name)
        if m:
            return int(m.group(1))
    return None


def find_libllvm() -> Path | None:
    """The newest ``libLLVM`` >= :data:`MIN_LLVM_MAJOR` in the system library folders, or None."""
    best: tuple[int, Path] | None = None
    for d in _LIB_DIRS:
        folder = Path(d)
        if not folder.is_dir():
            continue
        for f in folder.glob("libLLVM*.so*"):
            major = libllvm_major(f)
            if major is not None and major >= MIN_LLVM_MAJOR and (best is None or major > best[0]):
                best = (major, f)
    return None if best is None else best[1]


def _check_llvm_path() -> str:
    """Make ``DRJIT_LIBLLVM_PATH`` point at a libLLVM >= 17 before Dr.Jit loads one."""
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path:
        if not Path(path).is_file():
            raise MitsubaSetupError(f"DRJIT_LIBLLVM_PATH={path} is not a file; {_FIX}")
        major = libllvm_major(path)
        if major is not None and major < MIN_LLVM_MAJOR:
            raise MitsubaSetupError(
                f"DRJIT_LIBLLVM_PATH={path} is LLVM {major}; Mitsuba's LLVM variants abort with "
                f"'Cannot select: fmaximum' on LLVM < {MIN_LLVM_MAJOR}; {_FIX}"
            )
        return path
    found = find_libllvm()
    if found is None:
        raise MitsubaSetupError(
            f"no libLLVM >= {MIN_LLVM_MAJOR} found in {list(_LIB_DIRS)} and DRJIT_LIBLLVM_PATH is "
            f"unset (the system default libLLVM 15/16 aborts Mitsuba's kernels); {_FIX}"
        )
    os.environ["DRJIT_LIBLLVM_PATH"] = str(found)
    return str(found)


def is_monochrome(variant: str) -> bool:
    """True for Mitsuba's one-channel variants (``*_mono``): they render luminance only."""
    return variant.split("_")[-1] == "mono"


def cuda_available() -> bool:
    """Whether Dr.Jit finds a CUDA GPU (the ``cuda_ad_*`` variants can run)."""
    try:
        import drjit as dr

        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except (ImportError, AttributeError, RuntimeError):  # no driver, or a build without CUDA
        return False


def default_variant(*, achromatic: bool, backend: str = "auto") -> str:
    """The variant a stimulus set should be rendered with.

    Parameters
    ----------
    achromatic : bool
        True when every material is grey (the Ward stimuli): monochrome is exact and the cheapest.
        False keeps spectral rendering for chromatic materials.
    backend : {"auto", "llvm", "cuda"}
        "auto": CUDA when a GPU is found (:func:`cuda_available`), else the LLVM CPU back end.

    Returns
    -------
    str
        e.g. ``"llvm_ad_mono"``.
    """
    if backend not in ("auto", "llvm", "cuda"):
        raise ValueError(f"backend={backend!r}; choose 'auto', 'llvm' or 'cuda'")
    if backend == "auto":
        backend = "cuda" if cuda_available() else "llvm"
    return f"{backend}_ad_{'mono' if achromatic else 'spectral'}"


def _fix_for(variant: str) -> str:
    if variant.startswith("cuda"):
        return ("check that an NVIDIA GPU and driver are visible (`nvidia-smi`), or render on the "
                "CPU with the matching llvm_ad_* variant")
    return _FIX


def _smoke_test() -> None:
    """Render an 8 x 8 luminance image of a Ward sphere under a constant sky (finite and > 0)."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": 30.0,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0],
                                                               up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8,
                            "pixel_format": "luminance"},
                   "sampler": {"type": "multijitter", "sample_count": 4}},
        "emitter": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "shape": {"type": "sphere", "bsdf": {"type": "ward", "rho_d": 0.3, "rho_s": 0.2,
                                              "alpha": 0.1}},
    })
    img = np.asarray(mi.render(scene))
    dr.sync_thread()
    variant = mi.variant()
    if img.shape[:2] != (8, 8) or img.size != 64:
        raise MitsubaSetupError(
            f"Mitsuba smoke-test render under {variant} gave an image of shape {img.shape} "
            "(expected 8 x 8 luminance); this Mitsuba build's film does not output luminance: "
            f"use one of {list(SUPPORTED_VARIANTS)} with mitsuba >= 3.6")
    if not np.all(np.isfinite(img)) or not img.max() > 0:
        raise MitsubaSetupError(
            f"Mitsuba smoke-test render under {variant} gave non-finite or black pixels (max "
            f"{np.nanmax(img)}; expected finite, > 0); {_fix_for(variant)}")


def use_llvm_hint(path: str | None) -> None:
    """Take the libLLVM path a client shipped, where this machine's own choice is missing.

    A worker on another machine must not depend on the client's environment: a
    ``DRJIT_LIBLLVM_PATH`` of the worker's own wins (checked, with the fix, by
    :func:`setup_mitsuba`); else ``path`` (the client's library) if it is a file here; else
    :func:`setup_mitsuba` searches this machine's library folders. Call before the first
    :func:`setup_mitsuba` of the process.
    """
    if not os.environ.get("DRJIT_LIBLLVM_PATH") and path and Path(path).is_file():
        os.environ["DRJIT_LIBLLVM_PATH"] = str(path)


def _activate(chosen: str) -> None:
    from stimuli.ward import register_ward

    register_ward()
    _state.clear()
    _state["variant"] = chosen


def _try_cuda(mi, smoke_test: bool) -> str | None:
    """With no variant named on a machine with a CUDA GPU: ``cuda_ad_mono`` (libLLVM is not
    needed), smoke-tested; None, with a message naming why, where it fails (then the caller
    falls back to the LLVM variants, which need libLLVM)."""
    import sys

    chosen = CUDA_VARIANTS[0]
    try:
        if chosen not in mi.variants():
            raise MitsubaSetupError(f"this Mitsuba build has no {chosen} (it has {mi.variants()})")
        mi.set_variant(chosen)
        _activate(chosen)
        if smoke_test:
            _smoke_test()
            _state["smoke_tested"] = True
        return chosen
    except (MitsubaSetupError, ImportError, RuntimeError, ValueError, AttributeError) as exc:  # a
        # driver that loads and then fails at the first kernel falls back as well
        _state.clear()
        print(f"stimuli: a CUDA GPU is visible but {chosen} failed ({exc}); falling back to the "
              f"CPU variants {list(LLVM_VARIANTS)} (they need libLLVM >= {MIN_LLVM_MAJOR}); "
              f"{_fix_for(chosen)}", file=sys.stderr)
        return None


def setup_mitsuba(variant: str | None = None, *, smoke_test: bool = True) -> str:
    """Select a Mitsuba LLVM variant, register the Ward BSDF, and smoke-test a tiny render.

    Idempotent within a process (a Dask worker calls it once per process) and safe to call from
    several threads at once (one set-up at a time; the others wait and reuse it).

    Parameters
    ----------
    variant : str, optional
        One of :data:`SUPPORTED_VARIANTS` (``"auto"``: :func:`default_variant` for achromatic
        stimuli); default: ``cuda_ad_mono`` where a CUDA GPU works (libLLVM is then not
        needed), else, with a message saying why, the first of :data:`LLVM_VARIANTS` that this
        Mitsuba build has.
    smoke_test : bool
        Render an 8 x 8 test image the first time (about a second).

    Returns
    -------
    str
        The variant in use; record it with every render.

    Raises
    ------
    MitsubaSetupError
        If Mitsuba is not installed, libLLVM is older than 17 or absent, the variant is not one
        the renderer supports or missing from this build, CUDA is asked for without a GPU, or the
        smoke-test render fails; the message names the fix.
    """
    with _setup_lock:
        return _setup_locked(variant, smoke_test)


def _setup_locked(variant: str | None, smoke_test: bool) -> str:
    if variant == "auto":
        variant = default_variant(achromatic=True)
    if variant is not None and variant not in SUPPORTED_VARIANTS:
        raise MitsubaSetupError(
            f"Mitsuba variant {variant!r} is not supported by the stimulus renderer (the Ward "
            f"plugin and the luminance film); use one of {list(SUPPORTED_VARIANTS)} or 'auto'")
    if _state.get("variant") and (variant is None or variant == _state["variant"]):
        import mitsuba as mi

        if mi.variant() != _state["variant"]:  # another module (the gloss fit) switched it
            mi.set_variant(_state["variant"])
        if smoke_test and not _state.get("smoke_tested"):
            _smoke_test()
            _state["smoke_tested"] = True
        return _state["variant"]
    if variant is not None and variant.startswith("cuda") and not cuda_available():
        raise MitsubaSetupError(
            f"Mitsuba variant {variant} needs a CUDA GPU and Dr.Jit finds none; "
            f"{_fix_for(variant)}")
    try:
        import mitsuba as mi
    except ImportError as exc:
        raise MitsubaSetupError(
            f"cannot import mitsuba ({exc}); install the project (`make venv`)") from exc
    if variant is None and cuda_available():
        chosen = _try_cuda(mi, smoke_test)
        if chosen is not None:
            return chosen
    wanted = [variant] if variant else list(LLVM_VARIANTS)
    if any(v.startswith("llvm") for v in wanted):
        _check_llvm_path()
    available = mi.variants()
    chosen = next((v for v in wanted if v in available), None)
    if chosen is None:
        raise MitsubaSetupError(
            f"Mitsuba {mi.__version__} has none of the variants {wanted} (it has {available}); "
            "install the PyPI `mitsuba` wheel, which ships the LLVM variants"
        )
    try:
        mi.set_variant(chosen)
    except Exception as exc:  # Dr.Jit raises a plain RuntimeError when libLLVM will not load
        raise MitsubaSetupError(
            f"Mitsuba variant {chosen} failed to load: {exc}; {_fix_for(chosen)}") from exc
    _activate(chosen)
    if smoke_test:
        try:
            _smoke_test()
        except MitsubaSetupError:
            raise
        except Exception as exc:
            raise MitsubaSetupError(
                f"Mitsuba smoke-test render under {chosen} failed: {exc}; {_fix_for(chosen)}"
            ) from exc
        _state["smoke_tested"] = True
    return chosen
