"""Score the sim-to-real gap diagnosis on the blind generators, through the project's CLIs.

Each case of each generator (display_gen.py, observer_gen.py, render_gen.py, beside this file) is
written for every seed, effect size and data size asked, taken through the command lines a lab
would run (generate; ``calibration fit`` / ``experiment fit-observer`` / ``stimuli fit-gloss``;
``analysis gap diagnose``), and REPORT/diagnosis.json's ``verdict`` is read against the case's
truth.json (its realised effect size in the layer's tolerances, its expected names).

Verdicts (issue 43): a gap (named effects and/or ``unexplained``, written ``a + b``),
``no_gap_that_matters`` (the data exclude a gap of the tolerance) or ``inconclusive``. The old
``no_significant_gap``, if seen, counts as "not a gap, not excluded" and is flagged (``legacy``).
A command that fails (no diagnosis.json) is a ``crash``: it fails every row.

The table, per layer (issue 43's targets):

====  ===================================================================  ==========
row   cases and what passes                                                target
====  ===================================================================  ==========
R1    no-effect cases (none, clean, repeat_pass, ward), every size: not a  >= 95 %
      gap
R2    effects of >= 2x tolerance (realised), full size: a gap              >= 90 %
R2n   in-catalogue effects of >= 2x tolerance, full size: every expected   >= 85 %
      name in the verdict
R3    effects of >= 1x tolerance (realised), any size:                     <= 5 %
      ``no_gap_that_matters`` (the rate shown is of that verdict)
R3w   effects whose part the fitted simulation cannot absorb is >= 1x     <= 5 %
      tolerance: ``no_gap_that_matters``. Observer: what a person's own
      offset cannot absorb (truth.json's ``size_within_person``; issue 43:
      "a person's own offset is not a gap"); render: what a Ward material
      refitted to the fit's lights cannot (``size_beyond_fit``: the
      simulation is the fitted material). R3 counts the total size.
R4    no-effect cases at the smallest size (3 participants, a short run,   >= 90 %
      12 lights): ``no_gap_that_matters`` or ``inconclusive``
====  ===================================================================  ==========

Each row prints the count, the rate, a Wilson 95 % interval and the verdicts' breakdown; then
one line per case, effect multiple and data size: the median realised size (in tolerances,
truth.json; observer and render: also the part the fitted simulation cannot absorb,
"unabs.") beside the median misfit the diagnosis reports before its catalogue (in the layer's
units: slider units, % of luminance, % of the photos' RMS; tolerance 0.25, 1, 1), and how many
were a gap.

What runs (the plan): every case asked at the full size (20 participants, the full meter run,
48 lights); the new cases at each ``--multiples`` (default 0.5 1 2 tolerances); the no-effect
cases also at every smaller size asked (``--participants``, ``--runs``, ``--lights``);
``--all-sizes`` runs the effect cases at every size too.

Resumable and parallel-safe: each case lives in its own folder ``OUT/LAYER/CASE[-xM]-SIZE-sSEED``
(``log.txt`` holds every command and its output); a folder with REPORT/diagnosis.json is read,
not recomputed, unless ``--force``. A case is built in a temporary folder and renamed into place
when done; a lock file (``OUT/.locks``) keeps two runners (``--jobs`` threads or other
processes) off the same case: one held by a live process is skipped and reported as pending.

Seeds 0-99 are dev seeds; seeds >= 1000 are unseen, for the lead only.

Usage
-----
    python bench/blind/score.py --seeds 0-2                               # the whole plan
    python bench/blind/score.py --layers observer --cases none gloss_depth --multiples 2 \\
        --participants 20 3 --seeds 0-4 --jobs 2
    python bench/blind/score.py --seeds 1000-1019 --out out/blind-unseen --json out/unseen.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"

NONE_CASES = {"observer": ("none",), "display": ("clean", "repeat_pass"), "render": ("ward",)}
CASES = {
    "observer": ("none", "label_pull", "serial", "both", "rest_drift", "highlight_depth",
                 "slider_swap", "gloss_depth", "illum_depth"),
    "display": ("clean", "repeat_pass", "gain", "black_offset", "warmup", "uniformity",
                "gamma_tilt", "apl_loading", "offset_warmup"),
    "render": ("ward", "clearcoat", "broad_lobe", "glare", "interreflection", "lens_flare"),
}
#: Cases whose size is asked in tolerances (``--multiple``); the others draw their own.
SIZED = {"observer": ("rest_drift", "highlight_depth", "slider_swap", "gloss_depth",
                      "illum_depth"),
         "display": ("gamma_tilt", "apl_loading", "offset_warmup"),
         "render": ("interreflection", "lens_flare")}
FULL = {"observer": "n20", "display": "full", "render": "L48"}
NOT_GAP = ("no_gap_that_matters", "inconclusive", "no_significant_gap")


def parse_seeds(text: str) -> list[int]:
    """``"0-4,7"`` -> [0, 1, 2, 3, 4, 7]."""
    seeds: list[int] = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        lo, _, hi = part.partition("-")
        seeds += range(int(lo), int(hi or lo) + 1)
    return seeds


def classify(verdict: str | None) -> tuple[str, list[str]]:
    """(kind, names) of a verdict: kind one of gap, excluded, inconclusive, legacy, crash."""
    if verdict is None:
        return "crash", []
    v = verdict.strip()
    if v == "no_gap_that_matters":
        return "excluded", []
    if v == "inconclusive":
        return "inconclusive", []
    if v == "no_significant_gap":
        return "legacy", []
    v = v.removeprefix("gap:").strip()
    return "gap", [n.strip() for n in v.split("+") if n.strip()]


def reported_misfit(d: dict) -> float | None:
    """The misfit the diagnosis reports before its catalogue, in the layer's units (slider
    units, % of luminance, % of the photos' RMS), or None. Render: the plain simulation's
    misfit as the verdict sizes it (``remaining.size_before``, or ``size`` where nothing was
    chosen; net of the photos' own noise), not
    ``misfit_pct_before``, the held-out RMS with the camera's noise in it (4.0 % beside 1.2 %
    for the interreflection at 1.25x, seed 1006)."""
    rem = d.get("remaining") or {}
    for v in (d.get("misfit_before"), (d.get("misfit") or {}).get("size_pct_before"),
              rem.get("size_before"), rem.get("size"), d.get("misfit_pct_before")):
        if isinstance(v, int | float) and math.isfinite(v):
            return float(v)
    return None


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score 95 % interval of k successes in n (Wilson 1927), as fractions."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


# ---------------------------------------------------------------- running one case
def run(cmd: list[str], log: Path, timeout_s: float, cwd: Path) -> int:
    """Run one command nice'd in the repository (``python -m`` imports this checkout), its
    output appended to ``log``. Returns the exit code (124 on timeout)."""
    env = dict(os.environ)
    if Path(LLVM).exists():
        env.setdefault("DRJIT_LIBLLVM_PATH", LLVM)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    with open(log, "a") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        try:
            return subprocess.run(["nice", *cmd], check=False, cwd=cwd, env=env, stdout=fh,
                                  stderr=subprocess.STDOUT, timeout=timeout_s).returncode
        except subprocess.TimeoutExpired:
            fh.write(f"timed out after {timeout_s} s\n")
            return 124


def size_args(layer: str, size: str) -> list[str]:
    """The generator's data-size option of a size tag (n20, full/short, L48)."""
    if layer == "observer":
        return ["--participants", size[1:]]
    if layer == "display":
        return ["--run", size]
    return ["--lights", size[1:]]


def steps(layer: str, case: str, multiple, size: str, seed: int, folder: Path) -> list[list[str]]:
    """The commands of one case: generate, fit, diagnose (REPORT under ``folder``)."""
    py = sys.executable
    gen = [py, str(HERE / f"{layer}_gen.py"), "--case", case, "--seed", str(seed),
           "--out", str(folder), *size_args(layer, size)]
    if multiple is not None:
        gen += ["--multiple", f"{multiple:g}"]
    report = str(folder / "REPORT")
    diagnose = [py, "-m", "analysis", "gap", "diagnose", "--layer", layer, "--out", report]
    if layer == "display":
        return [gen, [py, "-m", "calibration", "fit", str(folder / "calib.csv"), "--out",
                      str(folder / "CAL"), "--dac-bits", "none"],
                diagnose + ["--real", str(folder / "check.csv"), "--sim", str(folder / "CAL")]]
    if layer == "observer":
        return [gen, [py, "-m", "experiment", "fit-observer", str(folder / "pilot"), "--out",
                      str(folder / "observers.toml")],
                diagnose + ["--real", str(folder / "real" / "sessions"), "--sim",
                            str(folder / "observers.toml")]]
    half = int(size[1:]) // 2
    return [gen, [py, "-m", "stimuli", "fit-gloss", str(folder), "--lights", f"1-{half}",
                  "--out", str(folder / "FIT")],
            diagnose + ["--real", str(folder), "--lights", f"{half + 1}-{2 * half}", "--sim",
                        str(folder / "FIT")]]


def case_name(case: str, multiple, size: str, seed: int) -> str:
    return f"{case}{'' if multiple is None else f'-x{multiple:g}'}-{size}-s{seed}"


def read_result(layer, case, multiple, size, seed, folder: Path, status: str) -> dict:
    """The scored record of a finished case folder."""
    diag, truth = folder / "REPORT" / "diagnosis.json", folder / "truth.json"
    verdict, extra = None, {}
    if diag.is_file():
        d = json.loads(diag.read_text())
        verdict = d.get("verdict")
        extra = {k: d[k] for k in ("detectable", "to_decide", "misfit_unit") if k in d}
        extra["misfit_before"] = reported_misfit(d)
    elif status == "ok":
        status = "crash (no diagnosis.json)"
    t = json.loads(truth.read_text()) if truth.is_file() else {}
    expected = t.get("expected", [])
    if isinstance(expected, str):
        expected = [] if expected in ("none", "unexplained") else \
            [n.strip() for n in expected.split("+")]
    kind, names = classify(verdict)
    return {"layer": layer, "case": case, "multiple": multiple, "size": size, "seed": seed,
            "full": size == FULL[layer], "no_effect": case in NONE_CASES[layer],
            "in_catalogue": bool(t.get("in_catalogue")) and case not in NONE_CASES[layer],
            "expected": [n for n in expected if n != "unexplained"],
            "size_in_tolerances": t.get("size_in_tolerances"),
            "size_unabsorbed_in_tolerances": t.get("size_within_person_in_tolerances",
                                                   t.get("size_beyond_fit_in_tolerances")),
            "status": status,
            "verdict": verdict, "kind": kind, "names": names, "folder": str(folder), **extra}


class Lock:
    """An exclusive lock file (pid@host); a stale one (its pid gone, same host) is taken over."""

    def __init__(self, path: Path):
        self.path, self.held = path, False

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        me = f"{os.getpid()}@{socket.gethostname()}"
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
                os.write(fd, me.encode())
                os.close(fd)
                self.held = True
                return self
            except FileExistsError:
                owner = self.path.read_text(errors="replace").strip()
                pid, _, host = owner.partition("@")
                if host == socket.gethostname() and pid.isdigit() and not _alive(int(pid)):
                    self.path.unlink(missing_ok=True)
                    continue
                return self
        return self

    def __exit__(self, *exc):
        if self.held:
            self.path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def score_one(layer, case, multiple, size, seed, root: Path, *, timeout_s, force) -> dict:
    """Run (or read) one case; the record ``read_result`` gives."""
    name = case_name(case, multiple, size, seed)
    folder = root / layer / name
    if not force and (folder / "REPORT" / "diagnosis.json").is_file():
        return {**read_result(layer, case, multiple, size, seed, folder, "ok"), "wall_s": 0.0,
                "reused": True}
    lock_path = root / ".locks" / f"{layer}-{name}.lock"
    with Lock(lock_path) as lock:
        if not lock.held:
            return {**read_result(layer, case, multiple, size, seed, folder, "pending"),
                    "status": "pending (another runner holds it)", "kind": "pending"}
        tmp = root / layer / f".{name}.tmp-{os.getpid()}-{threading.get_ident()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        t0, status = time.monotonic(), "ok"
        for cmd in steps(layer, case, multiple, size, seed, tmp):
            rc = run(cmd, tmp / "log.txt", timeout_s, REPO)
            if rc != 0:
                status = f"crash (rc {rc}, {Path(cmd[1]).name if cmd[1] != '-m' else cmd[2]})"
                break
        # Paths inside the outputs name the temporary folder; the log says which.
        with open(tmp / "log.txt", "a") as fh:
            fh.write(f"# built in {tmp.name}, renamed to {name}\n")
        if folder.exists():
            trash = root / layer / f".{name}.old-{os.getpid()}-{threading.get_ident()}"
            os.replace(folder, trash)
            shutil.rmtree(trash, ignore_errors=True)
        os.replace(tmp, folder)
        wall = time.monotonic() - t0
    return {**read_result(layer, case, multiple, size, seed, folder, status), "wall_s": wall,
            "reused": False}


# ---------------------------------------------------------------- the plan and the table
def plan(args) -> list[tuple]:
    """(layer, case, multiple, size, seed) of every case to score."""
    sizes = {"observer": [f"n{n}" for n in args.participants],
             "display": list(args.runs), "render": [f"L{n}" for n in args.lights]}
    jobs = []
    for layer in args.layers:
        for case in CASES[layer]:
            if args.cases and case not in args.cases:
                continue
            multiples = args.multiples if case in SIZED[layer] else [None]
            none = case in NONE_CASES[layer]
            for size in sizes[layer]:
                if size != FULL[layer] and not (none or args.all_sizes):
                    continue
                jobs += [(layer, case, m, size, s) for m in multiples for s in args.seeds]
    return jobs


def smallest(layer: str, results: list[dict]) -> str | None:
    sizes = {r["size"] for r in results if r["layer"] == layer}
    order = {"observer": lambda s: int(s[1:]), "render": lambda s: int(s[1:]),
             "display": lambda s: 0 if s == "short" else 1}[layer]
    return min(sizes, key=order) if sizes else None


def rows(layer: str, rs: list[dict]) -> list[tuple]:
    """(row id, description, target, passing records, all records) of one layer."""
    def big(r, m):
        return r["size_in_tolerances"] is not None and r["size_in_tolerances"] >= m * 0.98

    def big_unabsorbed(r, m):
        w = r.get("size_unabsorbed_in_tolerances")
        return w is not None and w >= m * 0.98

    small = smallest(layer, rs)
    effect = [r for r in rs if not r["no_effect"]]
    out = [
        ("R1", "no effect, every size -> not a gap", ">= 95 %",
         lambda r: r["kind"] in ("excluded", "inconclusive", "legacy"),
         [r for r in rs if r["no_effect"]]),
        ("R2", "effect >= 2x tol, full size -> a gap", ">= 90 %", lambda r: r["kind"] == "gap",
         [r for r in effect if r["full"] and big(r, 2)]),
        ("R2n", "in catalogue >= 2x tol, full -> named", ">= 85 %",
         lambda r: r["kind"] == "gap" and all(n in r["names"] for n in r["expected"]),
         [r for r in effect if r["full"] and big(r, 2) and r["in_catalogue"]]),
        ("R3", "effect >= 1x tol -> no_gap_that_matters", "<= 5 %",
         lambda r: r["kind"] == "excluded", [r for r in effect if big(r, 1)]),
        ("R3w", "unabsorbed >= 1x tol -> no_gap_that_matters", "<= 5 %",
         lambda r: r["kind"] == "excluded", [r for r in effect if big_unabsorbed(r, 1)]),
        ("R4", f"no effect, smallest ({small}) -> excl./inconcl.", ">= 90 %",
         lambda r: r["kind"] in ("excluded", "inconclusive", "legacy"),
         [r for r in rs if r["no_effect"] and r["size"] == small]),
    ]
    return [(rid, desc, target, [r for r in recs if ok(r)], recs)
            for rid, desc, target, ok, recs in out]


def median(values: list[float]) -> str:
    return f"{sorted(values)[len(values) // 2]:7.2f}" if values else "      -"


def breakdown(recs: list[dict]) -> str:
    counts = Counter(r["verdict"] if r["verdict"] is not None else r["status"] for r in recs)
    return ", ".join(f"{v} ({c})" for v, c in counts.most_common())


def table(results: list[dict]) -> tuple[str, list[dict]]:
    """The per-layer table (text) and its rows (JSON-ready)."""
    lines, out = [], []
    head = f"{'layer':9s} {'row':4s} {'cases':44s} {'target':>8s} {'count':>8s} {'rate':>7s}  " \
           f"{'95 % CI':15s} verdicts"
    lines.append(head)
    for layer in CASES:
        rs = [r for r in results if r["layer"] == layer and r["kind"] != "pending"]
        if not rs:
            continue
        for rid, desc, target, ok, recs in rows(layer, rs):
            n, k = len(recs), len(ok)
            if rid == "R3w" and not n:
                continue  # no unabsorbed size in this layer's truth.json
            lo, hi = wilson(k, n)
            rate = f"{100.0 * k / n:5.1f} %" if n else "    -  "
            ci = f"[{100 * lo:4.1f}, {100 * hi:5.1f}]" if n else ""
            lines.append(f"{layer:9s} {rid:4s} {desc:44s} {target:>8s} {k:3d}/{n:<4d} {rate}  "
                         f"{ci:15s} {breakdown(recs)}")
            out.append({"layer": layer, "row": rid, "cases": desc, "target": target, "pass": k,
                        "n": n, "ci95": [lo, hi], "verdicts": breakdown(recs)})
    lines += ["", (f"{'layer':9s} {'case':16s} {'x tol':>6s} {'size':6s} {'real. x':>7s} "
                   f"{'unabs.':>7s} {'misfit':>7s} {'gap':>7s}  verdicts")]
    groups = defaultdict(list)
    for r in results:
        groups[(r["layer"], r["case"], r["multiple"], r["size"])].append(r)
    for (layer, case, m, size), recs in groups.items():
        real = [r["size_in_tolerances"] for r in recs if r["size_in_tolerances"] is not None]
        said = [r["misfit_before"] for r in recs if r.get("misfit_before") is not None]
        within = [r["size_unabsorbed_in_tolerances"] for r in recs
                  if r.get("size_unabsorbed_in_tolerances") is not None]
        gaps = sum(r["kind"] == "gap" for r in recs)
        lines.append(f"{layer:9s} {case:16s} {'-' if m is None else f'{m:g}':>6s} {size:6s} "
                     f"{median(real)} {median(within)} {median(said)} {gaps:3d}/{len(recs):<3d}  "
                     f"{breakdown(recs)}")
    legacy = sum(r["kind"] == "legacy" for r in results)
    if legacy:
        lines.append(f"\nFLAG: {legacy} verdict(s) 'no_significant_gap' (removed by issue 43): "
                     "counted as not a gap, not excluded")
    pending = [r for r in results if r["kind"] == "pending"]
    if pending:
        lines.append(f"\n{len(pending)} case(s) pending (another runner holds them): rerun to "
                     "collect them")
    return "\n".join(lines), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Seeds 0-99: dev; >= 1000: unseen (the lead only).")
    ap.add_argument("--seeds", required=True, type=parse_seeds, help="e.g. 0-4 or 0,3,7")
    ap.add_argument("--layers", nargs="+", choices=list(CASES), default=list(CASES))
    ap.add_argument("--cases", nargs="+", help="only these cases (default: all of each layer)")
    ap.add_argument("--multiples", nargs="+", type=float, default=[0.5, 1.0, 2.0],
                    help="sizes of the sized cases, in tolerances (default 0.5 1 2)")
    ap.add_argument("--participants", nargs="+", type=int, default=[20, 3],
                    help="observer data sizes (20 is the full size; default 20 3)")
    ap.add_argument("--runs", nargs="+", choices=("full", "short"), default=["full", "short"],
                    help="display check runs (default full short)")
    ap.add_argument("--lights", nargs="+", type=int, default=[48, 12],
                    help="render lights in all, half fitted (48 is the full size; default 48 12)")
    ap.add_argument("--all-sizes", action="store_true",
                    help="run the effect cases at every size too (default: full size only)")
    ap.add_argument("--out", default=str(REPO / "out" / "blind"), help="work folder")
    ap.add_argument("--json", help="also write every result and row to this JSON file")
    ap.add_argument("--jobs", type=int, default=1, help="cases run at once (default 1)")
    ap.add_argument("--force", action="store_true", help="recompute cases already diagnosed")
    ap.add_argument("--timeout-s", type=float, default=1800.0, help="per command")
    args = ap.parse_args(argv)
    root = Path(args.out).resolve()
    jobs = plan(args)
    if not jobs:
        print("no case matched --layers/--cases/sizes", file=sys.stderr)
        return 2
    print(f"{len(jobs)} cases", flush=True)

    def one(job):
        r = score_one(*job, root, timeout_s=args.timeout_s, force=args.force)
        took = "reused" if r.get("reused") else f"{r.get('wall_s', 0.0):.0f} s"
        print(f"{r['layer']} {case_name(r['case'], r['multiple'], r['size'], r['seed'])}: "
              f"{r['verdict']} [{r['status']}] size {r['size_in_tolerances']} tol ({took})",
              flush=True)
        return r

    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(one, jobs))
    text, table_rows = table(results)
    print(f"\nseeds {min(args.seeds)}-{max(args.seeds)} ({len(args.seeds)})\n{text}")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": table_rows, "results": results},
                                              indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
