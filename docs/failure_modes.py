"""Print the failure-mode table of docs/reliability.md: every row is a real call and the answer it gets.

Run:  python docs/failure_modes.py
"""

import numpy as np, warnings, tempfile, os, h5py
from sympredict import *
from sympredict.kernels import IMQ
from sympredict.systems.pendulum import Pendulum, flow_map_data
from sympredict.systems.wave import WaveFOM
from sympredict.reduction import complex_svd_basis, SymplecticROM
from sympredict.functionals import HBFunctionals
from sympredict.greedy import greedy_interpolation
from sympredict.kernels import ProductKernel
d = flow_map_data(Pendulum(), mus=(0.7, 0.8), dts=(0.04, 0.06), n_grid=8)
m = SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=40).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
x = np.array([[0.1, 0.2]])
tmp = tempfile.mkdtemp()
def show(label, call):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        try:
            call(); msg = "(no error)"
        except Exception as e:
            msg = f"{type(e).__name__}: {e}"
        if w: msg = (msg + " | " if msg != "(no error)" else "") + f"{w[0].category.__name__}: {w[0].message}"
    print(f"| {label} | `{msg.replace(chr(124), '/')}` |")
show("state of wrong size", lambda: m.step(np.ones((2, 3)), mu=0.75, dt=0.05))
show("NaN state", lambda: m.step([[np.nan, 0.0]], mu=0.75, dt=0.05))
show("dt <= 0", lambda: m.step(x, mu=0.75, dt=0.0))
show("dt missing", lambda: m.step(x, mu=0.75))
show("mu missing", lambda: m.step(x, dt=0.05))
show("mu of wrong dimension", lambda: m.step(x, mu=np.ones((1, 2)), dt=0.05))
show("mu of wrong length", lambda: m.step(x, mu=[0.7, 0.8, 0.75], dt=0.05))
show("non-numeric mu", lambda: m.step(x, mu="a", dt=0.05))
show("negative n_steps", lambda: m.rollout(x, -1, mu=0.75, dt=0.05))
show("x0/x1 length mismatch", lambda: SymplecticKernelPredictor(IMQ(1.0), IMQ(1.0), IMQ(1.0)).fit(d.x0, d.x1[:-1], mu=d.mu, dt=d.dt))
show("empty data", lambda: SymplecticKernelPredictor(IMQ(1.0)).fit(np.zeros((0, 2)), np.zeros((0, 2)), dt=0.1))
show("duplicated samples", lambda: SymplecticKernelPredictor(IMQ(1.0)).fit(np.vstack([d.x0[:2], d.x0[:1]]), np.vstack([d.x1[:2], d.x1[:1]]), dt=0.04))
show("mu given to a parameter-free model", lambda: SymplecticKernelPredictor(IMQ(1.0), dt_kernel=IMQ(1.0)).fit(d.x0, d.x1, mu=d.mu, dt=d.dt))
show("several dt without dt_kernel", lambda: SymplecticKernelPredictor(IMQ(1.0), IMQ(1.0)).fit(d.x0, d.x1, mu=d.mu, dt=d.dt))
show("max_centers = 0", lambda: SymplecticKernelPredictor(IMQ(1.0), max_centers=0).fit(d.x0[:5], d.x1[:5], dt=0.04))
show("kernel shape out of range", lambda: IMQ(0.0))
show("kernel shape too large", lambda: IMQ(1e60))
show("unfitted model", lambda: SymplecticKernelPredictor(IMQ(1.0)).step(x, dt=0.1))
strict = SymplecticKernelPredictor.__new__(SymplecticKernelPredictor); strict.__dict__.update(m.__dict__); strict.newton_max_iter = 1
show("Newton does not converge", lambda: strict.rollout(x, 3, mu=0.75, dt=0.05))
rng = np.random.default_rng(3); P = Pendulum()
x0 = np.column_stack([rng.uniform(-1, 1, 80), rng.uniform(-2, 2, 80)])
big = SymplecticKernelPredictor(IMQ(0.3), max_centers=120).fit(x0, P.flow(x0, 0.75, 1.2), dt=1.2)
show("dT * L_S >= 1, checked before the rollout", lambda: big.rollout(x0[:10], 3, check_solvability=True))
show("mu outside the training box", lambda: m.step(x, mu=0.9, dt=0.05))
show("dt outside the training box", lambda: m.step(x, mu=0.75, dt=0.1))
show("state outside the training box", lambda: m.step([[0.0, 30.0]], mu=0.75, dt=0.05))
xi = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.5]])
res = greedy_interpolation(HBFunctionals(ProductKernel(IMQ(1.0)), xi, np.zeros((3, 0)), np.full(3, 0.1)), np.array([1.0, 0.0, 2.0, 0.5, -1.0, 0.3]), max_centers=6, tol=0.0)
print(f"| duplicate candidates with contradictory data | greedy stops, history_.stop_reason = {res.history.stop_reason!r}, {len(res.selected)} centres, finite coefficients |")
show("Newton basis larger than memory", lambda: SymplecticKernelPredictor(IMQ(1.0), IMQ(1.0), IMQ(1.0), max_centers=1000, memory_limit=1e5).fit(d.x0, d.x1, mu=d.mu, dt=d.dt))
show("load: missing file", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "none.h5")))
open(os.path.join(tmp, "t.h5"), "w").write("text")
show("load: not HDF5", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "t.h5")))
with h5py.File(os.path.join(tmp, "f.h5"), "w") as f: f["x"] = 1
show("load: foreign HDF5", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "f.h5")))
p = os.path.join(tmp, "m.h5"); m.save(p)
with h5py.File(p, "r+") as f: f["arrays/coef"][0] += 1
show("load: corrupted arrays", lambda: SymplecticKernelPredictor.load(p))
m.save(p)
with h5py.File(p, "r+") as f: f.attrs["schema_version"] = 99
show("load: newer schema", lambda: SymplecticKernelPredictor.load(p))
m.save(p); open(os.path.join(tmp, "tr.h5"), "wb").write(open(p, "rb").read()[:2000])
show("load: truncated file", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "tr.h5")))
fom = WaveFOM(60)
snap = fom.trajectory(fom.low_frequency_states(3, 2, 0.09, 1.0), 0.09, 0.1, 5).reshape(-1, fom.dim)
show("basis: n above the snapshot rank", lambda: complex_svd_basis(snap, n=4))
b = complex_svd_basis(snap, n=2)
show("non-symplectic basis", lambda: SymplecticROM(fom, type(b)(V=1.1 * b.V, singular_values=b.singular_values, n=2)))
show("basis of another dimension", lambda: SymplecticROM(WaveFOM(30), b))
show("wave parameter outside the declared range", lambda: fom.trajectory(snap[:1], 0.5, 0.1, 1))
