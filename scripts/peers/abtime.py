#!/usr/bin/env python3
"""Interleaved whole-process timing of two commands, A B A B … (issue 19's measuring rule).

    python3 scripts/peers/abtime.py --label NAME --runs N [--warmup W] \
        --a 'OURS COMMAND' --b 'PEER COMMAND' \
        [--a-stage 'FILE::EXPR'] [--b-stage 'FILE::EXPR'] [--results FILE.jsonl]

Each command is split as a shell splits words and run without a shell, its output thrown away
(stderr kept in `<results dir>/<label>.{a,b}.log` when `--results` is given). After W warm-up
runs of each (not counted), A and B alternate N times. Per run: wall time (perf_counter around
the child), user + system CPU and the peak RSS of the child (`os.wait4`'s rusage); per pair the
ratio B ÷ A (peer ÷ ours), so a drift of the machine's speed hits both sides of a pair alike.
A stage (`--a-stage`/`--b-stage`): after each run, the JSON FILE is read and the Python
expression EXPR evaluated with `r` bound to it (seconds), e.g. our report.json's probability
stage: `OUT/report.json::sum(t["ms"] for t in r["timings"] if t["stage"] == "probability") / 1e3`.
Prints medians with [min–max], the load average before and after, and appends one JSON line to
`--results`. Uses only the Python standard library.
"""

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path


def run(cmd, log):
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log or subprocess.DEVNULL)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "rss_mb": ru.ru_maxrss / 1024,
            "rc": p.returncode}


def stage(spec):
    if not spec:
        return None
    path, expr = spec.split("::", 1)
    r = json.loads(Path(path).read_text())
    return float(eval(expr, {"r": r}))  # noqa: S307 (our own expression, from the script)


def med(xs):
    xs = [x for x in xs if x is not None]
    if not xs:
        return None
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs)}


def fmt(m, unit="s", digits=3):
    if m is None:
        return "—"
    return f"{m['median']:.{digits}f} {unit} [{m['min']:.{digits}f}–{m['max']:.{digits}f}]"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--label", required=True)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--a", required=True)
    ap.add_argument("--b", required=True)
    ap.add_argument("--a-stage")
    ap.add_argument("--b-stage")
    ap.add_argument("--results")
    a = ap.parse_args()
    cmds = {"a": shlex.split(a.a), "b": shlex.split(a.b)}
    stages = {"a": a.a_stage, "b": a.b_stage}
    logs = {}
    if a.results:
        d = Path(a.results).parent
        for k in "ab":
            logs[k] = open(d / f"{a.label}.{k}.log", "ab")
    load0 = os.getloadavg()
    for _ in range(a.warmup):
        for k in "ab":
            r = run(cmds[k], logs.get(k))
            if r["rc"] != 0:
                sys.exit(f"{a.label}: {k.upper()} exited {r['rc']}: {a.a if k == 'a' else a.b}")
    runs = {"a": [], "b": []}
    for _ in range(a.runs):
        for k in "ab":
            r = run(cmds[k], logs.get(k))
            if r["rc"] != 0:
                sys.exit(f"{a.label}: {k.upper()} exited {r['rc']}")
            r["stage"] = stage(stages[k])
            runs[k].append(r)
    load1 = os.getloadavg()
    out = {"label": a.label, "runs": a.runs, "load_before": load0[0], "load_after": load1[0],
           "a": a.a, "b": a.b}
    for k in "ab":
        for f in ("wall", "cpu", "rss_mb", "stage"):
            out[f"{k}_{f}"] = med([r[f] for r in runs[k]])
    out["ratio_wall"] = med([b["wall"] / x["wall"] for x, b in zip(runs["a"], runs["b"])])
    if stages["a"] and stages["b"]:
        out["ratio_stage"] = med([b["stage"] / x["stage"]
                                  for x, b in zip(runs["a"], runs["b"]) if x["stage"]])
    print(f"== {a.label}: {a.runs} interleaved pairs after {a.warmup} warm-up each; "
          f"load {load0[0]:.2f} → {load1[0]:.2f}")
    for k, name in (("a", "ours"), ("b", "peer")):
        print(f"   {name:5} wall {fmt(out[k + '_wall'])}  cpu {fmt(out[k + '_cpu'])}  "
              f"peak {out[k + '_rss_mb']['median']:.0f} MB"
              + (f"  stage {fmt(out[k + '_stage'])}" if out[k + "_stage"] else ""))
    print(f"   peer ÷ ours, whole process: {fmt(out['ratio_wall'], '×', 2)}"
          + (f"; stage: {fmt(out['ratio_stage'], '×', 2)}" if out.get("ratio_stage") else ""),
          flush=True)
    if a.results:
        with open(a.results, "a") as f:
            f.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
