"""Score the sim-to-real gap diagnosis on the blind generators, through the project's CLIs.

Each case of each generator (display_gen.py, observer_gen.py, render_gen.py, beside this file) is
written for every seed asked, taken through the command lines a lab would run, and the verdict of
REPORT/diagnosis.json is scored against the case's truth:

=========  ===========================  ===============================================
layer      case                         passes when the verdict ...
=========  ===========================  ===============================================
display    clean, repeat_pass           is a no-gap verdict
display    gain, black_offset, warmup,  names the expected effect first (top-1)
           uniformity
observer   none                         is a no-gap verdict
observer   label_pull, serial           names the expected effect
observer   both                         names both label_rounding and serial_dependence
render     ward                         is a no-gap verdict
render     clearcoat, broad_lobe,       names the expected effect first (top-1)
           glare
=========  ===========================  ===============================================

No-gap verdicts: ``no_significant_gap`` and ``no_gap_that_matters``. Named effects appear in the
verdict as ``a + b``. A command that fails (non-zero exit, no diagnosis.json) is a failure,
shown as ``crash``.

Seeds 0-99 are dev seeds; seeds >= 1000 are unseen, for the lead only.

Usage
-----
    python bench/blind/score.py --seeds 0-2                       # every layer and case
    python bench/blind/score.py --layers display --cases clean repeat_pass --seeds 0-19
    python bench/blind/score.py --seeds 1000-1019 --out out/blind-unseen --json out/unseen.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
NO_GAP = ("no_significant_gap", "no_gap_that_matters")
LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"

CASES = {
    "display": {"clean": ("nogap",), "repeat_pass": ("nogap",),
                "gain": ("top1", "gain_change"), "black_offset": ("top1", "black_offset"),
                "warmup": ("top1", "warmup_drift"), "uniformity": ("top1", "nonuniformity")},
    "observer": {"none": ("nogap",), "label_pull": ("named", "label_rounding"),
                 "serial": ("named", "serial_dependence"),
                 "both": ("named", "label_rounding", "serial_dependence")},
    "render": {"ward": ("nogap",), "clearcoat": ("top1", "clearcoat"),
               "broad_lobe": ("top1", "broad_lobe"), "glare": ("top1", "veiling_glare")},
}


def parse_seeds(text: str) -> list[int]:
    """``"0-4,7"`` -> [0, 1, 2, 3, 4, 7]."""
    seeds: list[int] = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        lo, _, hi = part.partition("-")
        seeds += range(int(lo), int(hi or lo) + 1)
    return seeds


def run(cmd: list[str], log: Path, timeout_s: float) -> int:
    """Run one command in the repository (``python -m`` imports this checkout), nice'd; its
    output appended to ``log``. Returns the exit code (124 on timeout)."""
    env = dict(os.environ)
    if Path(LLVM).exists():
        env.setdefault("DRJIT_LIBLLVM_PATH", LLVM)
    with open(log, "a") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        try:
            return subprocess.run(["nice", *cmd], check=False, cwd=REPO, env=env, stdout=fh,
                                  stderr=subprocess.STDOUT, timeout=timeout_s).returncode
        except subprocess.TimeoutExpired:
            fh.write(f"timed out after {timeout_s} s\n")
            return 124


def steps(layer: str, case: str, seed: int, folder: Path) -> list[list[str]]:
    """The commands of one case: generate, fit, diagnose (REPORT under ``folder``)."""
    py = sys.executable
    gen = [py, str(HERE / f"{layer}_gen.py"), "--case", case, "--seed", str(seed),
           "--out", str(folder)]
    report = str(folder / "REPORT")
    if layer == "display":
        return [gen,
                [py, "-m", "calibration", "fit", str(folder / "calib.csv"), "--out",
                 str(folder / "CAL"), "--dac-bits", "none"],
                [py, "-m", "analysis", "gap", "diagnose", "--layer", "display", "--real",
                 str(folder / "check.csv"), "--sim", str(folder / "CAL"), "--out", report]]
    if layer == "observer":
        return [gen,
                [py, "-m", "experiment", "fit-observer", str(folder / "pilot"), "--out",
                 str(folder / "observers.toml")],
                [py, "-m", "analysis", "gap", "diagnose", "--layer", "observer", "--real",
                 str(folder / "real" / "sessions"), "--sim", str(folder / "observers.toml"),
                 "--out", report]]
    return [gen,
            [py, "-m", "stimuli", "fit-gloss", str(folder), "--lights", "1-12", "--out",
             str(folder / "FIT")],
            [py, "-m", "analysis", "gap", "diagnose", "--layer", "render", "--real",
             str(folder), "--lights", "13-24", "--sim", str(folder / "FIT"), "--out", report]]


def judge(rule: tuple, verdict: str | None) -> bool:
    """Whether ``verdict`` passes the case's rule (see the module docstring)."""
    if verdict is None:
        return False
    if rule[0] == "nogap":
        return verdict in NO_GAP
    names = [n.strip() for n in verdict.split("+")]
    if rule[0] == "top1":
        return names[0] == rule[1]
    return all(n in names for n in rule[1:])


def score_one(layer: str, case: str, seed: int, root: Path, timeout_s: float) -> dict:
    folder = root / layer / f"{case}-{seed}"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    log = folder / "log.txt"
    t0 = time.monotonic()
    status, verdict, extra = "ok", None, {}
    for cmd in steps(layer, case, seed, folder):
        rc = run(cmd, log, timeout_s)
        if rc != 0:
            status = f"crash (rc {rc}, {Path(cmd[1]).name if cmd[1] != '-m' else cmd[2]})"
            break
    diag = folder / "REPORT" / "diagnosis.json"
    if diag.is_file():
        d = json.loads(diag.read_text())
        verdict = d.get("verdict")
        extra = {k: d.get(k) for k in ("misfit_pct_before", "misfit_pct_after",
                                        "unexplained_remains") if k in d}
    elif status == "ok":
        status = "crash (no diagnosis.json)"
    rule = CASES[layer][case]
    return {"layer": layer, "case": case, "seed": seed, "status": status, "verdict": verdict,
            "pass": judge(rule, verdict), "rule": list(rule), "wall_s": time.monotonic() - t0,
            "folder": str(folder), **extra}


def table(results: list[dict]) -> str:
    groups = defaultdict(list)
    for r in results:
        groups[(r["layer"], r["case"])].append(r)
    lines = [f"{'layer':9s} {'case':13s} {'rule':42s} {'pass':>9s}  verdicts (count)"]
    for (layer, case), rs in groups.items():
        rule = rs[0]["rule"]
        rule_s = rule[0] + (": " + " + ".join(rule[1:]) if len(rule) > 1 else "")
        n_pass = sum(r["pass"] for r in rs)
        counts = Counter(r["verdict"] if r["verdict"] is not None else r["status"] for r in rs)
        verdicts = ", ".join(f"{v} ({c})" for v, c in counts.most_common())
        lines.append(f"{layer:9s} {case:13s} {rule_s:42s} {n_pass:3d}/{len(rs):<3d}  "
                     f"{100.0 * n_pass / len(rs):5.1f} %  {verdicts}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", required=True, help="e.g. 0-4 or 0,3,7 (dev: 0-99)")
    ap.add_argument("--layers", nargs="+", choices=list(CASES), default=list(CASES))
    ap.add_argument("--cases", nargs="+", help="only these cases (default: all of each layer)")
    ap.add_argument("--out", default=str(REPO / "out" / "blind"), help="work folder")
    ap.add_argument("--json", help="also write every result to this JSON file")
    ap.add_argument("--timeout-s", type=float, default=1800.0, help="per command")
    args = ap.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    root = Path(args.out).resolve()
    results = []
    for layer in args.layers:
        for case in CASES[layer]:
            if args.cases and case not in args.cases:
                continue
            for seed in seeds:
                r = score_one(layer, case, seed, root, args.timeout_s)
                results.append(r)
                print(f"{layer} {case} seed {seed}: {r['verdict']} [{r['status']}] "
                      f"{'PASS' if r['pass'] else 'fail'} ({r['wall_s']:.0f} s)", flush=True)
    if not results:
        print("no case matched --layers/--cases", file=sys.stderr)
        return 2
    print()
    print(f"seeds {args.seeds}")
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
