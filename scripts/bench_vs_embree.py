#!/usr/bin/env python3
"""Runs the Embree anchor benchmark and isin's tracer benchmark back to back and
prints one Markdown table (called by scripts/bench-vs-embree.sh, which installs
Embree and builds both). isin's figures come from the JSON its benchmark writes;
Embree's from its text output (it has no other)."""

import argparse
import json
import os
import re
import subprocess
import sys
import time

# name -> (mesh file under ../shared/meshes, embree_bench extra arguments)
CASES = {
    "bunny": ("bunny/stanford-bunny.obj", []),
    "dragon_100k": ("dragon/dragon_100k.obj", []),
    "sponza": ("sponza_dabrovic/sponza.obj", ["-cam", "-14", "3", "0", "10", "5", "0"]),
    "dragon_1.6M": ("dragon/dragon_100k.obj", ["-s", "2"]),
}

# embree_bench line label -> our metric name (MEDIUM = default-quality BVH only)
EMBREE_TRACE = {
    "primary rtcIntersect1 (coherent ctx)": "primary",
    "primary rtcIntersect8 (4x2 tiles)": "primary8",
    "incoherent rtcIntersect1": "incoherent",
    "shadow rtcOccluded1 (area light)": "shadow",
}
TRACE_RE = re.compile(r"^\s+(.*?)\s+thr=(\d+)\s+rays=\s*(\d+)\s+wall best\s+([\d.]+) Mrays/s"
                      r".*per CPU-s\s+([\d.]+) Mrays")
BUILD_RE = re.compile(r"^build MEDIUM\(default\)\s+threads=(\d+):\s+([\d.]+) ms")


def run_measured(cmd, log, env=None):
    """Runs cmd, tees stdout to `log`, returns (exit code, peak RSS of the process in MB)."""
    with open(log, "w") as f:
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env)
        for line in p.stdout:
            f.write(line)
            sys.stderr.write("  | " + line)
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
    return p.returncode, usage.ru_maxrss / 1024.0


def parse_embree(text):
    """{("build", T): ms, (metric, T): Mrays/s} from the MEDIUM-quality section."""
    out, section = {}, None
    for line in text.splitlines():
        m = BUILD_RE.match(line)
        if m:
            out[("build", int(m.group(1)))] = float(m.group(2))
            continue
        if line.startswith("== tracing, BVH quality"):
            section = line.split()[-1]
            continue
        m = TRACE_RE.match(line)
        if m and section == "MEDIUM(default)" and m.group(1) in EMBREE_TRACE:
            out[(EMBREE_TRACE[m.group(1)], int(m.group(2)))] = float(m.group(4))
            out[(EMBREE_TRACE[m.group(1)] + "/cpu", int(m.group(2)))] = float(m.group(5))
    return out


def bench_executable(root):
    """Path of the compiled tracer bench binary (cargo's JSON messages)."""
    msgs = subprocess.run(
        ["cargo", "bench", "-p", "isin-tracer", "--bench", "tracer", "--no-run", "--message-format=json"],
        cwd=root, capture_output=True, text=True, check=True).stdout
    for line in msgs.splitlines():
        try:
            m = json.loads(line)
        except json.JSONDecodeError:
            continue
        if m.get("reason") == "compiler-artifact" and m.get("target", {}).get("name") == "tracer" \
                and m.get("executable"):
            return m["executable"]
    sys.exit("could not find the tracer bench executable")


def isin_rows(path):
    """{(mesh, metric, T): row} from isin's tracer.json, plus the document."""
    doc = json.load(open(path))
    rows = {}
    for r in doc["rows"]:
        parts = r["case"].split()  # e.g. "bunny primary 1T"
        mesh, metric, threads = parts[0], parts[1], int(parts[2].rstrip("T"))
        rows[(mesh, metric, threads)] = r
    return rows, doc


def fmt(v, nd=2):
    return "–" if v is None else f"{v:.{nd}f}"


def ratio(a, b):
    return None if a is None or b is None or b == 0 else a / b


# (isin metric, table label, Embree metric)
METRICS = [("primary", "primary, single ray (Mrays/s)", "primary"),
           ("primary8", "primary, 8-ray packets, isin vs Embree (Mrays/s)", "primary8"),
           ("incoherent", "incoherent (Mrays/s)", "incoherent"),
           ("shadow", "shadow, area light (Mrays/s)", "shadow"),
           ("build", "BVH build (ms; ratio = isin time / Embree time)", "build")]


def bars(embree, rows, cases):
    """Issue 6's bars of one round, in table order: per mesh, metric and thread count, isin's row,
    Embree's figure, isin's figure compared (best run; builds: median), the ratio and whether the
    bar is met (throughput ≥ Embree's; build ≤ 2× Embree's time)."""
    out = []
    for c in cases:
        for metric, label, emetric in METRICS:
            for t in (1, 2):
                r = rows.get((c, metric, t))
                if r is None and metric == "primary8":
                    # A bench without isin's packet row: its single rays against Embree's packets.
                    r = rows.get((c, "primary", t))
                if r is None:
                    continue
                ev = embree[c].get((emetric, t))
                if metric == "build":
                    best = r["isin"]
                    vs = ratio(r["isin"], ev)
                    met = vs is not None and vs <= 2.0
                else:
                    best = r.get("isin_best")
                    vs = ratio(best, ev)
                    met = vs is not None and vs >= 1.0
                out.append({"mesh": c, "label": label, "threads": t, "row": r, "embree": ev, "best": best,
                            "emetric": emetric, "ratio": vs, "met": met})
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--embree", required=True)
    ap.add_argument("--meshes", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--rounds", type=int, default=1,
                    help="measure Embree and isin this many times, alternating, and say in how many "
                         "rounds each bar held (bars near 1 flip with the machine's load)")
    a = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cases = [c for c in a.cases if c in CASES and os.path.exists(os.path.join(a.meshes, CASES[c][0]))]
    for c in a.cases:
        if c not in cases:
            print(f"skipping {c}: unknown case or mesh absent", file=sys.stderr)
    exe = bench_executable(root)  # before the long Embree runs: later edits do not rebuild it
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    load_before = open("/proc/loadavg").read().split()[:3]

    # EMBREE_ISA (see bench-vs-embree.sh): the wrapper that passes it to Embree
    # is preloaded into embree_bench only.
    isa = os.environ.get("EMBREE_ISA", "")
    embree_env = dict(os.environ)
    if isa and os.environ.get("EMBREE_PRELOAD"):
        embree_env["LD_PRELOAD"] = os.environ["EMBREE_PRELOAD"]
    elif isa:
        sys.exit("EMBREE_ISA needs the wrapper that scripts/bench-vs-embree.sh builds")

    rounds = []  # per round: (Embree figures per mesh, isin rows, isin document)
    embree_rss = {}
    for n in range(max(1, a.rounds)):
        tag = "" if n == 0 else f"-r{n + 1}"
        embree = {}
        for c in cases:
            mesh, extra = CASES[c]
            print(f"== Embree: {c}" + (f" (round {n + 1})" if a.rounds > 1 else ""), file=sys.stderr)
            log = os.path.join(a.out, f"embree-{c}{tag}.txt")
            code, rss = run_measured([a.embree, os.path.join(a.meshes, mesh), "-reps", str(a.reps)] + extra,
                                     log, embree_env)
            if code != 0:
                sys.exit(f"embree_bench failed on {c} (exit {code}); see {log}")
            embree[c] = parse_embree(open(log).read())
            embree_rss[c] = rss

        print("== isin, bvh, obvhs: " + " ".join(cases), file=sys.stderr)
        code, _ = run_measured([exe, "--bench", f"json=tracer{tag}.json"] + cases,
                               os.path.join(a.out, f"tracer{tag}.txt"))
        if code != 0:
            sys.exit(f"tracer bench failed (exit {code})")
        rows, doc = isin_rows(os.path.join(a.out, f"tracer{tag}.json"))
        rounds.append((embree, rows, doc))
    rss_isin = None
    if "dragon_1.6M" in cases:
        # Peak RSS of a process that, like embree_bench, holds only one library's
        # structure for the mesh and the ray sets.
        print("== isin alone on dragon_1.6M (peak RSS)", file=sys.stderr)
        code, rss = run_measured([exe, "--bench", "isin-only", "json=tracer-1.6M.json", "dragon_1.6M"],
                                 os.path.join(a.out, "tracer-1.6M.txt"))
        if code == 0:
            rss_isin = rss
    load_after = open("/proc/loadavg").read().split()[:3]

    print(f"\n## isin vs Embree {started} — {doc['machine']}")
    print(f"load average before {' '.join(load_before)}, after {' '.join(load_after)}; "
          f"Embree: best of {a.reps} (build: best of 3); isin: best and median of {doc['reps']} "
          f"(build: median of 3); bvh/obvhs: median.")
    print(f"Embree's kernels: {isa.upper() + ' (forced with EMBREE_ISA)' if isa else 'the best ISA the CPU has'}.\n")
    print("| mesh | case | threads | Embree | isin best | isin median | bvh | obvhs "
          "| isin/Embree | isin/bvh | isin/obvhs | Embree per CPU-s | isin per CPU-s | ratio per CPU-s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    summary = []
    for b in bars(embree, rows, cases):
        r, ev, best, emetric = b["row"], b["embree"], b["best"], b["emetric"]
        if emetric == "primary8":
            bvh_v = obvhs_v = r_bvh = r_obvhs = None
        else:
            bvh_v, obvhs_v = r.get("bvh"), r.get("obvhs")
            r_bvh, r_obvhs = r.get("isin_over_bvh"), r.get("isin_over_obvhs")
        e_cpu, i_cpu = embree[b["mesh"]].get((emetric + "/cpu", b["threads"])), r.get("isin_per_cpu")
        print(f"| {b['mesh']} | {b['label']} | {b['threads']} | {fmt(ev)} | {fmt(best)} | {fmt(r['isin'])} "
              f"| {fmt(bvh_v)} | {fmt(obvhs_v)} | {fmt(b['ratio'])}{'' if b['met'] else ' ✗'} | {fmt(r_bvh)} "
              f"| {fmt(r_obvhs)} | {fmt(e_cpu)} | {fmt(i_cpu)} | {fmt(ratio(i_cpu, e_cpu))} |")
        summary.append(b["met"])
    print("\nisin/bvh and isin/obvhs: how many times faster isin is (median vs median; builds: time ratio).")
    print("Per CPU-s: rays per CPU-second of the process (Embree: of its tracing threads), which other "
          "load on the machine disturbs far less than wall time.")
    print("✗ marks a miss of issue 6's bar (throughput ≥ Embree's; build ≤ 2× Embree's time).")
    print("\n| mesh | triangles | isin BVH + triangle data, bytes/triangle |")
    print("|---|---|---|")
    for name, tris, bpt in [(m["mesh"], m["triangles"], m["bytes_per_triangle"]) for m in doc["meshes"]]:
        print(f"| {name} | {tris} | {bpt:.1f} |")
    if "dragon_1.6M" in cases:
        print(f"\nPeak RSS, dragon 1.6M (mesh + BVH + the ray sets, whole process): "
              f"isin {fmt(rss_isin, 0)} MB, Embree {fmt(embree_rss.get('dragon_1.6M'), 0)} MB.")
    print(f"\nbars met: {sum(summary)} of {len(summary)}")
    if len(rounds) > 1:
        per_round = [bars(e, r, cases) for e, r, _ in rounds]
        print(f"\n### The bars in each of {len(rounds)} rounds (Embree, then isin, alternating; the table "
              f"above is the last round)\n")
        print("| mesh | case | threads | isin/Embree per round | met in |")
        print("|---|---|---|---|---|")
        always = 0
        for k, b in enumerate(per_round[-1]):
            ratios = [rb[k]["ratio"] for rb in per_round]
            met = sum(rb[k]["met"] for rb in per_round)
            always += met == len(rounds)
            print(f"| {b['mesh']} | {b['label']} | {b['threads']} | {', '.join(fmt(x) for x in ratios)} "
                  f"| {met} of {len(rounds)} |")
        some = sum(any(rb[k]["met"] for rb in per_round) for k in range(len(per_round[-1])))
        print(f"\nbars met in every round: {always} of {len(per_round[-1])}; in at least one: {some}")
    strided = [n for n in doc["notes"] if "every" in n]
    if strided:
        print(f"\n{len(strided)} library/case pairs traced an evenly strided subset to stay within the time "
              f"budget (the load makes this common); the list is in {os.path.join(a.out, f'tracer{tag}.json')}.")


if __name__ == "__main__":
    main()
