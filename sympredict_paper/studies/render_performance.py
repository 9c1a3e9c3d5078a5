"""Render docs/explanation/performance.md from suite runs (the first is the full run; the others repeat sections).

    python sympredict_paper/studies/render_performance.py benchmarks/results/suite.json [more suite.json ...]

Fills the placeholders of ``sympredict_paper/studies/performance_doc_template.md``: the
measured table of the first run, medians over all runs of the repeated key
numbers, the targets with pass/fail, and the fitted scaling exponents.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from suite import markdown  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def get(d, *keys):
    for k in keys:
        if d is None or k not in d:
            return None
        d = d[k]
    return d


def median_over(runs, *keys):
    vals = [v for v in (get(r, *keys) for r in runs) if v is not None]
    return (float(np.median(vals)), vals) if vals else (None, [])


def main(paths):
    runs = [json.loads(Path(p).read_text()) for p in paths]
    full = runs[0]
    table = markdown(full).split("\n", 2)[2].strip()  # without the title line
    env = full["environment"]

    rows = ["| repeated measurement | runs | median |", "|---|---|---|"]
    keys = [
        ("rollout numba, batch 1000, traj-steps/s", ("rollout", "numba", "traj_steps_per_s"), "{:,.0f}"),
        ("rollout NumPy, batch 1000, traj-steps/s", ("rollout", "numpy", "traj_steps_per_s"), "{:,.0f}"),
        ("numba / NumPy throughput", ("rollout", "speedup_batch"), "{:.1f}x"),
        ("latency numba, ms per step in a rollout", ("rollout", "numba", "latency_ms_per_step_in_rollout"), "{:.3f}"),
        ("latency numba, ms per step() call", ("rollout", "numba", "latency_ms_per_step_call"), "{:.3f}"),
        ("latency NumPy, ms per step in a rollout", ("rollout", "numpy", "latency_ms_per_step_in_rollout"), "{:.3f}"),
        ("greedy (mid-size) / in-run matvec bound", ("greedy", "bandwidth", "ratio_total"), "{:.2f}"),
    ]
    med = {}
    for label, k, fmt in keys:
        m, vals = median_over(runs, *k)
        med[k] = m
        if m is not None:
            rows.append(f"| {label} | {', '.join(fmt.format(v) for v in vals)} | {fmt.format(m)} |")
    repeated = "\n".join(rows)

    a = full.get("scenario_a", {})
    ex, fa = a.get("exact", {}), a.get("fast", {})
    targets = ["| target | measured | |", "|---|---|---|"]

    def row(name, value, ok):
        targets.append(f"| {name} | {value} | {'pass' if ok else ('FAIL' if ok is not None else 'not measured')} |")

    if "bandwidth" in ex:
        r = ex["bandwidth"]["ratio_total"]
        row(
            "exact f-greedy, scenario A: time per centre <= 1.2x the in-run bandwidth bound",
            f"{r:.2f}x ({ex['time_train_s']:.0f} s against {ex['bandwidth']['matvec_bound_s']:.0f} s of matrix-vector products)",
            r <= 1.2,
        )
    else:
        m = med[("greedy", "bandwidth", "ratio_total")]
        row(
            "exact f-greedy: time per centre <= 1.2x the in-run bandwidth bound (mid-size set)",
            f"{m:.2f}x" if m else "-",
            None if m is None else m <= 1.2,
        )
    if "time_train_s" in fa:
        row(
            "fast path, scenario A: max residual over all 688,464 functionals <= 1e-5",
            f"{fa['E_train_direct']:.2e} (direct evaluation), {fa['n_centers']} centres",
            fa["E_train_direct"] <= 1e-5,
        )
        row("fast path: under 30 s", f"{fa['time_train_s']:.1f} s", fa["time_train_s"] < 30)
        row(
            "fast path: at most 12 GiB peak",
            f"{fa['peak_rss_bytes'] / 2**30:.2f} GiB",
            fa["peak_rss_bytes"] <= 12 * 2**30,
        )
        ratios = a.get("error_ratio_fast_over_exact")
        if ratios:
            row(
                "fast path: trajectory errors within 2x of the exact path (median over time, per test dT)",
                ", ".join(f"{x:.2f}" for x in ratios),
                max(ratios) <= 2,
            )
    t = med[("rollout", "numba", "traj_steps_per_s")]
    row(
        "rollout >= 20,000 trajectory-steps/s at 1500 centres, batch 1000",
        f"{t:,.0f}" if t else "-",
        None if t is None else t >= 20000,
    )
    lat, lat_call = (
        med[("rollout", "numba", "latency_ms_per_step_in_rollout")],
        med[("rollout", "numba", "latency_ms_per_step_call")],
    )
    if lat is not None:
        row(
            "latency < 0.2 ms per step, one trajectory",
            f"{lat:.3f} ms per step in a rollout, {lat_call:.3f} ms per step() call",
            max(lat, lat_call) < 0.2,
        )
    d = get(full, "rollout", "numba_vs_numpy_max_diff")
    if d is not None:
        s = get(full, "rollout", "numpy_batch_vs_single_max_diff")
        row(
            "trajectories equal to the NumPy reference to 1e-12",
            f"1e-13 on a well-conditioned model (tests); {d:.1e} on the 1500-centre model, where NumPy differs from itself by {s:.1e}",
            d <= 1e-12,
        )
    targets = "\n".join(targets)

    s = full.get("scaling", {})
    lines = []
    if "rollout_vs_centers" in s:
        lines.append(
            f"- rollout time per trajectory-step against centres: exponent {s['rollout_vs_centers']['exponent']:.2f} "
            "(linear in `m` once the per-step overhead is amortised)"
        )
        lines.append(
            f"- rollout total time against batch size: exponent {s['rollout_vs_batch']['exponent_total_time']:.2f}"
        )
        dd = s["newton_vs_dim"]
        lines.append(
            f"- against state dimension `2n` = 2..40: compiled implicit step {dd['exponent_numba_step']:.2f}, "
            f"compiled gradient {dd['exponent_numba_gradient']:.2f}, NumPy gradient + Hessian block "
            f"{dd['exponent_numpy_newton_terms']:.2f} (the Hessian block is `O(n^2)` per centre)"
        )
    if "greedy_step_vs_N" in s:
        lines.append(
            f"- greedy step against candidates `N` (m = 300): exponent {s['greedy_step_vs_N']['exponent']:.2f}"
        )
        lines.append(
            f"- greedy step against centres `m`: exponent {s['greedy_step_vs_m']['exponent']:.2f} "
            "(tends to 1 as the matrix-vector product dominates the `O(N)` per-step work)"
        )
    scaling = "\n".join(lines)

    noise = (
        f"{len(runs)} run(s) of the repeated sections, "
        f"with {env['blas_threads_requested']} BLAS threads and {get(env, 'numba', 'threads')} numba threads "
        f"({get(env, 'numba', 'threading_layer')} layer)."
    )
    text = (Path(__file__).resolve().parent / "performance_doc_template.md").read_text()
    text = (
        text.replace("@@TABLE@@", table + "\n\n" + repeated)
        .replace("@@TARGETS@@", targets)
        .replace("@@SCALING@@", scaling)
        .replace("@@NOISE@@", noise)
    )
    (ROOT / "docs" / "explanation" / "performance.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main(sys.argv[1:])
