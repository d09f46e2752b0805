#!/usr/bin/python3
"""Markdown tables for docs/RESULTS.md from a scripts/bench.sh output folder (OUT/{main,big}).

    /usr/bin/python3 bench/charts/tables.py OUT > OUT/results_tables.md

Per scene: the paper-style row (vertex fates and reprojection overhead of rp, share of eye paths
traced by skip), then for the trimmed and the full relative MSE: each mode's (and Cycles') final
error and time, and the CPU seconds it needs to reach plain path tracing's error at P = T, as a
ratio to path tracing's own CPU seconds at round T. Two readings of "reach", because the error
curves are noisy (a firefly raises the full metric for a while):
  first  the first round at or below the target (optimistic for a noisy curve),
  stays  the round from which on every later round stays at or below it (pessimistic);
both interpolated log-log between rounds. "-" = not reached within the run.

Every metric comes twice when the run had an independent Cycles reference (the *_cy columns): against
eprfarm's own converged reference and against Cycles'. Then, per scene, the error of every curve at
equal CPU time (path tracing's CPU seconds at P = T, and skip's CPU seconds at its last round; each curve interpolated log-log between its
rounds or renders; "-" where the curve does not span that time), with skip's ratio to Cycles (plain
and adaptive), and at the end the same ratios for all scenes in one table, and skip against pt in all scenes: at
equal samples (P paths per pixel traced or skipped) and at equal CPU time (CPU seconds to reach pt's
error at P, as a ratio to pt's).
"""
import csv
import json
import math
import os
import sys

MODES = ["pt", "rp", "skip", "exact", "cycles", "cycles_adaptive"]
METRICS = (("rel_mse_trim", "trimmed relative MSE"), ("rel_mse", "full relative MSE (fireflies included)"),
           ("rel_mse_trim_cy", "trimmed relative MSE, Cycles reference"),
           ("rel_mse_cy", "full relative MSE (fireflies included), Cycles reference"))
SHORT = {"rel_mse_trim": "trimmed", "rel_mse": "full", "rel_mse_trim_cy": "trimmed, Cycles ref.",
         "rel_mse_cy": "full, Cycles ref."}


def read_csv(path):
    with open(path, newline="") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def interp(r0, r1, target, key, tcol):
    e0, e1, t0, t1 = r0[key], r1[key], r0[tcol], r1[tcol]
    if not (e0 > 0 and e1 > 0 and t0 > 0) or e0 == e1:
        return t1
    f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
    return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))


def first_time(rows, target, key, tcol="cpu_s"):
    for i, r in enumerate(rows):
        if r[key] <= target:
            return r[tcol] if i == 0 else interp(rows[i - 1], r, target, key, tcol)
    return None


def stays_time(rows, target, key, tcol="cpu_s"):
    if not rows or not rows[-1][key] <= target:
        return None
    i = len(rows) - 1
    while i > 0 and rows[i - 1][key] <= target:
        i -= 1
    return rows[i][tcol] if i == 0 else interp(rows[i - 1], rows[i], target, key, tcol)


def at_spp(rows, t):
    """pt's row at exactly t paths per pixel: the round ending there, or log-log between the two
    rounds around it (the growing round schedule need not end a round at t)."""
    for i, r in enumerate(rows):
        if r["spp"] == t:
            return r
        if r["spp"] > t:
            if i == 0:
                return None
            a = rows[i - 1]
            f = (math.log(t) - math.log(a["spp"])) / (math.log(r["spp"]) - math.log(a["spp"]))
            lerp = lambda x, y: (math.exp(math.log(x) + f * (math.log(y) - math.log(x)))
                                 if x > 0 and y > 0 else x + f * (y - x))
            return {k: lerp(a[k], r[k]) for k in r}
    return None


def at_time(rows, t, key, tcol="cpu_s"):
    """A curve's error at time t, log-log between the two rounds around it; None outside the curve."""
    rows = sorted(rows, key=lambda r: r[tcol])
    for i in range(1, len(rows)):
        a, b = rows[i - 1], rows[i]
        if a[tcol] <= t <= b[tcol] and a[tcol] > 0 and b[key] > 0 and a[key] > 0:
            if b[tcol] == a[tcol]:
                return b[key]
            f = (math.log(t) - math.log(a[tcol])) / (math.log(b[tcol]) - math.log(a[tcol]))
            return math.exp(math.log(a[key]) + f * (math.log(b[key]) - math.log(a[key])))
    return None


def has_metric(rows, key):
    return key in rows[0] and any(r[key] == r[key] for r in rows)


def f3(x):
    return "-" if x is None else ("%.3g" % x)


def ratio(x, base):
    return "-" if x is None or not base else "%.2f" % (x / base)


def equal_time(tag, curves, keys, targets, out, goal):
    times = []
    for t in targets:
        b = at_spp(curves["pt"], t)
        if b is not None:
            times.append(("pt@%d" % t, b["cpu_s"]))
    if "skip" in curves:
        times.append(("skip's end", curves["skip"][-1]["cpu_s"]))
    for label, tc in times:
        out.append("| at %s, %.3g CPU-s | %s |" % (label, tc, " | ".join(SHORT[k] for k in keys)))
        out.append("|---|" + "---|" * len(keys))
        vals = {m: {k: at_time(rows, tc, k) for k in keys} for m, rows in curves.items()}
        for m in curves:
            out.append("| %s | %s |" % (m, " | ".join(f3(vals[m][k]) for k in keys)))
        for c in ("cycles", "cycles_adaptive"):
            if "skip" in vals and c in vals:
                r = [vals["skip"][k] / vals[c][k] if vals["skip"][k] and vals[c][k] else None for k in keys]
                out.append("| **skip / %s** | %s |" % (c, " | ".join("-" if x is None else "**%.2f**" % x for x in r)))
                goal.append((tag, label, tc, c, dict(zip(keys, r))))
        out.append("")


def skip_vs_pt(tag, curves, targets, rows):
    if "skip" not in curves:
        return
    pt, sk = curves["pt"], curves["skip"]
    for t in targets:
        a, b = at_spp(pt, t), at_spp(sk, t)
        if a is None or b is None:
            continue
        r = [tag, "%d" % t]
        for key in ("rel_mse_trim", "rel_mse"):
            r.append("%.2f" % (b[key] / a[key]) if a[key] > 0 else "-")
        for key in ("rel_mse_trim", "rel_mse"):
            r.append(ratio(first_time(sk, a[key], key), a["cpu_s"]))
        rows.append(r)


def scene_tables(part_dir, js, targets, out, goal, svp):
    tag = js["tag"]
    curves = {}
    for m in MODES:
        p = os.path.join(part_dir, "csv", "%s_%s.csv" % (tag, m))
        if os.path.isfile(p):
            curves[m] = read_csv(p)
    pt = curves["pt"]
    size = int(tag.split("_")[-1].split("x")[0])
    spp = int(round(max(r["spp"] for r in pt)))
    out.append("#### %s (%d triangles)\n" % (tag, js["triangles"]))
    if "fates" in js:
        fa = js["fates"]
        skip = js["modes"].get("skip")
        share = "%.1f %%" % (100.0 * skip["paths_traced"] / (spp * size * size)) if skip else "-"
        out.append("| accepted | occluded | culled | reprojection overhead (rp, GL) | eye paths traced (skip, P = %d) |" % spp)
        out.append("|---|---|---|---|---|")
        out.append("| %.1f %% | %.1f %% | %.1f %% | %.1f %% | %s |\n"
                   % (fa["accepted"], fa["occluded"], fa["culled"], fa["overhead"], share))
    keys = [k for k, _ in METRICS if has_metric(pt, k)]
    for key, label in METRICS:
        if key not in keys:
            continue
        head = "| %s | final | CPU-s | wall s |" % label
        sep = "|---|---|---|---|"
        for t in targets:
            head += " to pt@%d: CPU-s first / stays | x pt first / stays |" % t
            sep += "---|---|"
        out.append(head)
        out.append(sep)
        base = {t: at_spp(pt, t) for t in targets}
        for m, rows in curves.items():
            last = rows[-1]
            line = "| %s | %.3g | %.1f | %.1f |" % (m, last[key], last["cpu_s"], last["wall_s"])
            for t in targets:
                b = base[t]
                if b is None:
                    line += " - | - |"
                    continue
                fi, st = first_time(rows, b[key], key), stays_time(rows, b[key], key)
                line += " %s / %s | %s / %s |" % (f3(fi), f3(st), ratio(fi, b["cpu_s"]), ratio(st, b["cpu_s"]))
            out.append(line)
        out.append("")
    equal_time(tag, curves, keys, targets, out, goal)
    skip_vs_pt(tag, curves, targets, svp)
    out.append("")


def main():
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    root = sys.argv[1]
    out, goal, svp = [], [], []
    for part, targets in (("main", [64, 256]), ("big", None)):
        d = os.path.join(root, part)
        if not os.path.isfile(os.path.join(d, "summary.json")):
            continue
        summary = json.load(open(os.path.join(d, "summary.json")))
        tg = targets or [summary["spp"]]
        wall, cpu = summary.get("wall_s"), summary.get("cpu_s")
        out.append("### %s: %dx%d, P = %d, reference %d spp; load average %.1f at the start, %.1f at the end%s%s\n"
                   % (part, summary["size"], summary["size"], summary["spp"], summary["ref_spp"],
                      summary["load_start"], summary.get("load_end", float("nan")),
                      "; %.0f s wall" % wall if wall else "", "; %.0f CPU-s" % cpu if cpu else ""))
        for js in summary["scenes"]:
            scene_tables(d, js, tg, out, goal, svp)
    if goal:
        keys = [k for k, _ in METRICS if any(k in g[4] for g in goal)]
        out.append("### Equal CPU time: skip's error / Cycles' error (below 1: skip is ahead)\n")
        out.append("| scene | at | against | %s |" % " | ".join(SHORT[k] for k in keys))
        out.append("|---|---|---|" + "---|" * len(keys))
        for tag, t, tc, c, r in goal:
            out.append("| %s | %s, %.3g CPU-s | %s | %s |" % (tag, t, tc, c, " | ".join(
                "-" if r.get(k) is None else "%.2f" % r[k] for k in keys)))
        out.append("")
    if svp:
        out.append("### skip against pt: error ratio at equal samples, CPU-time ratio to reach pt's error\n")
        out.append("| scene | P | error skip / pt, trimmed | full | time to pt@P's error (x pt, first), trimmed | full |")
        out.append("|---|---|---|---|---|---|")
        out.extend("| " + " | ".join(r) + " |" for r in svp)
        out.append("")
    print("\n".join(out))


if __name__ == "__main__":
    main()
