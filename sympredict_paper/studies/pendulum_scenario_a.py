"""Benchmark: pendulum scenario A, the paper's protocol, with time and peak memory.

Run (not part of the test suite; the 'paper' preset needs ~10 GiB and minutes):

    python sympredict_paper/studies/pendulum_scenario_a.py --preset paper --threads 2 --out benchmarks/results

Writes ``<out>/pendulum_scenario_a_<preset>.json`` (with the record of ``sympredict_paper/studies/_protocol.py``)
and prints a table.  ``--threads`` / ``--blas-threads``: BLAS threads (default 1).  Run it in
a fresh process: the peak memory is the process's maximum resident set size.
"""

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from pymor.core.logger import set_log_levels

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict_paper.pendulum import PRESETS, run_scenario_a  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--preset", choices=sorted(PRESETS), default="quick")
_protocol.add_arguments(parser, json_option=False, blas_alias="--threads")
parser.add_argument("--seed", type=int, default=0)
parser.add_argument("--out", default="benchmarks/results")
args = parser.parse_args()

set_log_levels({"sympredict": "INFO"})
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)
t0 = time.perf_counter()
with _protocol.limits(args.blas_threads):
    protocol = _protocol.record_options(args, repeats=1, statistic="one run")
    blas = [
        {k: p.get(k) for k in ("internal_api", "num_threads", "version")} for p in protocol["machine"]["threadpools"]
    ]
    results = run_scenario_a(PRESETS[args.preset], seed=args.seed)
summary = results["summary"]
summary["wall_total_s"] = time.perf_counter() - t0
summary["machine"] = {"cpus": os.cpu_count(), "platform": platform.platform(), "numpy": np.__version__, "blas": blas}
path = out / f"pendulum_scenario_a_{args.preset}.json"
_protocol.write_json(path, summary, protocol, indent=2)

print(f"\npendulum scenario A, preset {args.preset}, {args.blas_threads} BLAS threads")
print(
    f"  {summary['n_functionals']} functionals -> {summary['n_centers']} centres ({summary['stop_reason']}), "
    f"E_train {summary['E_train']:.2e}, E_val {summary['E_val']:.2e}"
)
print(
    f"  data {summary['time_data_s']:.1f} s, training {summary['time_fit_s']:.1f} s, peak RSS {summary['peak_rss_gib']:.2f} GiB"
)
print(
    f"  {'dT':>8} {'kernel med':>11} {'kernel max':>11} {'IM med':>9} {'IM max':>9} {'ratio':>7} {'kernel s':>9} {'IM s':>6}"
)
for r in summary["per_dt"]:
    print(
        f"  {r['dt']:>8} {r['kernel_median_err']:>11.2e} {r['kernel_max_err']:>11.2e} {r['im_median_err']:>9.2e} "
        f"{r['im_max_err']:>9.2e} {r['ratio_median']:>7.0f} {r['time_kernel_s']:>9.2f} {r['time_im_s']:>6.2f}"
    )
print(f"written to {path}")
