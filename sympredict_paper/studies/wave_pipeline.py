"""Benchmark: the wave MOR pipeline at reduced dimensions 2n = 4, 10, 20.

Run (not part of the tests):

    python sympredict_paper/studies/wave_pipeline.py --preset quick --n 2 --n 5 --n 10 --out benchmarks/results

For each ``n`` the snapshot initial states excite ``n`` sine modes (richer
states for larger ``n``).  Reports basis construction time and symplecticity,
data / selection / training times, time-averaged errors of the kernel
predictor and implicit midpoint per ``(dT, c_test)``, and the online wall
time of ROM + kernel against the FOM micro-step reference over the same
horizon, all measured in one process.  ``--threads`` / ``--blas-threads``: BLAS
threads (default 1, ``sympredict_paper/studies/_protocol.py``; its record is in the JSON, whose
rows are under ``"rows"``).
"""

import argparse
import sys
from pathlib import Path

import numpy as np
from pymor.core.logger import set_log_levels

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict_paper.wave import PRESETS, run_wave  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--preset", choices=sorted(PRESETS), default="quick")
parser.add_argument("--n", type=int, action="append", help="complex modes n (repeatable; default 2)")
_protocol.add_arguments(parser, json_option=False, blas_alias="--threads")
parser.add_argument("--seed", type=int, default=0)
parser.add_argument("--out", default="benchmarks/results")
args = parser.parse_args()

set_log_levels(
    {
        "sympredict": "INFO",
        "sympredict.interpolation.greedy": "WARNING",
        "sympredict.estimators.selection": "WARNING",
        "pymor": "WARN",
    }
)
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)
rows = []
for n in args.n or [2]:
    with _protocol.limits(args.blas_threads):
        summary = run_wave(PRESETS[args.preset], seed=args.seed, n_reduced=n, n_modes=n)["summary"]
    rows.append(summary)
    b = summary["basis"]
    print(
        f"\n2n = {2 * n}: basis {b['time_basis_s']:.2f} s (snapshots {b['time_snapshots_s']:.2f} s), "
        f"symplecticity {b['symplecticity']:.1e}, orthonormality {b['orthonormality']:.1e}"
    )
    print(
        f"  {'dT':>6} {'kernel':>26} {'centres':>8} {'select s':>8} {'fit s':>6} {'kernel err':>10} {'IM err':>9} "
        f"{'min ratio':>9} {'t kernel':>9} {'t FOM':>7} {'speed-up':>8}"
    )
    for r in summary["per_dt"]:
        k = np.array([c["mean_kernel_red"] for c in r["cases"]])
        im = np.array([c["mean_im_red"] for c in r["cases"]])
        tk = np.median([c["time_kernel_s"] for c in r["cases"]])
        tf = np.median([c["time_fom_ref_s"] for c in r["cases"]])
        print(
            f"  {r['dt']:>6} {r['kernel']['state'] + ' x ' + r['kernel']['mu']:>26} {r['n_centers']:>8} "
            f"{r['time_selection_s']:>8.1f} {r['time_fit_s']:>6.1f} {k.max():>10.2e} {im.min():>9.2e} {(im / k).min():>9.0f} "
            f"{tk:>9.3f} {tf:>7.2f} {tf / tk:>7.0f}x"
        )
path = out / f"wave_pipeline_{args.preset}.json"
with _protocol.limits(args.blas_threads):
    _protocol.write_json(path, {"rows": rows}, _protocol.record_options(args, repeats=1), indent=2)
print(f"written to {path}")
