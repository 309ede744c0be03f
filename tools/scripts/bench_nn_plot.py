#!/usr/bin/env python3
"""Plot bench_nn results (tools/results/bench_nn_results.csv) like the paper's Fig. 5/6:
NN time per iteration, end-to-end wall time and peak RSS against the number of
reference points, DSM-ICP (grid NN through a 64 MB chunk cache) vs k-d tree ICP.

Usage: python3 tools/scripts/bench_nn_plot.py [results.csv] [out.png]   (needs matplotlib)
"""
import csv
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    out = []
    for r in rows:
        v = {k: (float(x) if k != "kd_failed" and x not in ("", "NaN", "nan") else x)
             for k, x in r.items()}
        for k, x in v.items():
            if k != "kd_failed" and isinstance(x, str):
                v[k] = math.nan
        out.append(v)
    return out


def label(v):
    return f"{v:,.0f}" if v >= 100 else f"{v:.3g}"


def main():
    src = sys.argv[1] if len(sys.argv) > 1 else "tools/results/bench_nn_results.csv"
    dst = sys.argv[2] if len(sys.argv) > 2 else "tools/results/bench_nn_results.png"
    rows = read(src)
    pts = [r["points_m"] for r in rows]
    panels = [
        ("NN time per ICP iteration (warm)", "ms", "dsm_nn_ms", "kd_nn_ms"),
        ("End-to-end wall time (k-d: load + build + ICP)", "s", "dsm_total_s", "kd_total_s"),
        ("Peak RSS (VmHWM, own process)", "MB", "dsm_rss_mb", "kd_rss_mb"),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    for ax, (title, unit, dk, kk) in zip(axes, panels):
        d = [r[dk] for r in rows]
        k = [r[kk] for r in rows]
        ax.plot(pts, d, "o-", color="tab:blue", label="DSM-ICP grid NN (--cache-mb 64)")
        kp = [(p, v) for p, v in zip(pts, k) if not math.isnan(v)]
        if kp:
            ax.plot([p for p, _ in kp], [v for _, v in kp], "s--", color="tab:red",
                    label="k-d tree ICP (kiddo)")
        for r in rows:
            if r["kd_failed"]:
                ax.annotate("k-d tree failed", (r["points_m"], ax.get_ylim()[1]),
                            color="tab:red", fontsize=8, ha="center", va="top")
        for p, v in zip(pts, d):
            ax.annotate(label(v), (p, v), textcoords="offset points", xytext=(0, 6),
                        ha="center", fontsize=8, color="tab:blue")
        for p, v in kp:
            ax.annotate(label(v), (p, v), textcoords="offset points", xytext=(0, -12),
                        ha="center", fontsize=8, color="tab:red")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("reference points (millions)")
        ax.set_ylabel(unit)
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    rss = axes[2]
    rss.axhline(100, color="gray", ls=":", lw=1)
    rss.annotate("target 100 MB", (pts[0], 100), textcoords="offset points", xytext=(2, 3),
                 fontsize=8, color="gray")
    # The paper's measurement at 305 M points (Xu & Qin 2024): 133 MB vs 17,200 MB.
    rss.plot([305, 305], [133, 17200], "x", color="gray", label="paper, 305 M")
    rss.legend(fontsize=8, loc="upper left")
    axes[0].legend(fontsize=8, loc="upper left")
    fig.suptitle("bench_nn: same query set (50k samples), same point-to-point ICP, 2 shared cores")
    fig.tight_layout()
    fig.savefig(dst, dpi=110)
    print(f"wrote {dst}")


if __name__ == "__main__":
    main()
