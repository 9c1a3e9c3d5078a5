"""Print the failure-mode table of docs/reference/errors.md: every row is a real call and the answer it gets.

Run:  python sympredict_paper/figures/failure_modes.py
"""

import numpy as np, warnings, tempfile, os, h5py, errno, stat
from sympredict import SymplecticKernelPredictor
from sympredict.kernels import IMQ
from sympredict.systems.pendulum import Pendulum, flow_map_data
from sympredict.systems.wave import WaveFOM
from sympredict.mor.basis import complex_svd_basis, SymplecticROM
from sympredict.interpolation.functionals import HBFunctionals
from sympredict.interpolation.greedy import ExactGreedy, greedy_interpolation
from sympredict.kernels import ProductKernel

d = flow_map_data(Pendulum(), mus=(0.7, 0.8), dts=(0.04, 0.06), n_grid=8)
m = SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=40).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
x = np.array([[0.1, 0.2]])
tmp = tempfile.mkdtemp()


def show(label, call):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        try:
            call()
            msg = "(no error)"
        except Exception as e:
            msg = f"{type(e).__name__}: {e}"
        if w:
            msg = (msg + " | " if msg != "(no error)" else "") + f"{w[0].category.__name__}: {w[0].message}"
    print(f"| {label} | `{msg.replace(chr(124), '/').replace(tmp, '/tmp/…')}` |")


show("state of wrong size", lambda: m.step(np.ones((2, 3)), mu=0.75, dt=0.05))
show("NaN state", lambda: m.step([[np.nan, 0.0]], mu=0.75, dt=0.05))
show("dt <= 0", lambda: m.step(x, mu=0.75, dt=0.0))
show("dt missing", lambda: m.step(x, mu=0.75))
show("mu missing", lambda: m.step(x, dt=0.05))
show("mu of wrong dimension", lambda: m.step(x, mu=np.ones((1, 2)), dt=0.05))
show("mu of wrong length", lambda: m.step(x, mu=[0.7, 0.8, 0.75], dt=0.05))
show("non-numeric mu", lambda: m.step(x, mu="a", dt=0.05))
show("negative n_steps", lambda: m.rollout(x, -1, mu=0.75, dt=0.05))
show(
    "x0/x1 length mismatch",
    lambda: SymplecticKernelPredictor(IMQ(1.0), IMQ(1.0), IMQ(1.0)).fit(d.x0, d.x1[:-1], mu=d.mu, dt=d.dt),
)
show("empty data", lambda: SymplecticKernelPredictor(IMQ(1.0)).fit(np.zeros((0, 2)), np.zeros((0, 2)), dt=0.1))
show(
    "duplicated samples",
    lambda: SymplecticKernelPredictor(IMQ(1.0)).fit(
        np.vstack([d.x0[:2], d.x0[:1]]), np.vstack([d.x1[:2], d.x1[:1]]), dt=0.04
    ),
)
show(
    "mu given to a parameter-free model",
    lambda: SymplecticKernelPredictor(IMQ(1.0), dt_kernel=IMQ(1.0)).fit(d.x0, d.x1, mu=d.mu, dt=d.dt),
)
show(
    "several dt without dt_kernel",
    lambda: SymplecticKernelPredictor(IMQ(1.0), IMQ(1.0)).fit(d.x0, d.x1, mu=d.mu, dt=d.dt),
)
show("max_centers = 0", lambda: SymplecticKernelPredictor(IMQ(1.0), max_centers=0).fit(d.x0[:5], d.x1[:5], dt=0.04))
show("kernel shape out of range", lambda: IMQ(0.0))
show("kernel shape too large", lambda: IMQ(1e60))
show("unfitted model", lambda: SymplecticKernelPredictor(IMQ(1.0)).step(x, dt=0.1))
strict = SymplecticKernelPredictor.__new__(SymplecticKernelPredictor)
strict.__dict__.update(m.__dict__)
strict.set_params(solver__max_iter=1)
show("Newton does not converge", lambda: strict.rollout(x, 3, mu=0.75, dt=0.05))
rng = np.random.default_rng(3)
P = Pendulum()
x0 = np.column_stack([rng.uniform(-1, 1, 80), rng.uniform(-2, 2, 80)])
big = SymplecticKernelPredictor(IMQ(0.3), max_centers=120).fit(x0, P.flow(x0, 0.75, 1.2), dt=1.2)
show("dT * L_S >= 1, checked before the rollout", lambda: big.rollout(x0[:10], 3, check_solvability=True))
show("mu outside the training box", lambda: m.step(x, mu=0.9, dt=0.05))
show("dt outside the training box", lambda: m.step(x, mu=0.75, dt=0.1))
show("state outside the training box", lambda: m.step([[0.0, 30.0]], mu=0.75, dt=0.05))
xi = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.5]])
res = greedy_interpolation(
    HBFunctionals(ProductKernel(IMQ(1.0)), xi, np.zeros((3, 0)), np.full(3, 0.1)),
    np.array([1.0, 0.0, 2.0, 0.5, -1.0, 0.3]),
    max_centers=6,
    tol=0.0,
)
print(
    f"| duplicate candidates with contradictory data | greedy stops, history_.stop_reason = {res.history.stop_reason!r}, {len(res.selected)} centres, finite coefficients |"
)
show(
    "Newton basis larger than memory",
    lambda: SymplecticKernelPredictor(
        IMQ(1.0), IMQ(1.0), IMQ(1.0), max_centers=1000, trainer=ExactGreedy(memory_limit=1e5)
    ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt),
)
show("load: missing file", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "none.h5")))
open(os.path.join(tmp, "t.h5"), "w").write("text")
show("load: not HDF5", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "t.h5")))
with h5py.File(os.path.join(tmp, "f.h5"), "w") as f:
    f["x"] = 1
show("load: foreign HDF5", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "f.h5")))
p = os.path.join(tmp, "m.h5")
m.save(p)
with h5py.File(p, "r+") as f:
    f["arrays/coef"][0] += 1
show("load: corrupted arrays", lambda: SymplecticKernelPredictor.load(p))
m.save(p)
with h5py.File(p, "r+") as f:
    f.attrs["schema_version"] = 99
show("load: newer schema", lambda: SymplecticKernelPredictor.load(p))
m.save(p)
open(os.path.join(tmp, "tr.h5"), "wb").write(open(p, "rb").read()[:2000])
show("load: truncated file", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "tr.h5")))
fom = WaveFOM(60)
snap = fom.trajectory(fom.low_frequency_states(3, 2, 0.09, 1.0), 0.09, 0.1, 5).reshape(-1, fom.dim)
show("basis: n above the snapshot rank", lambda: complex_svd_basis(snap, n=4, layout="rows"))
b = complex_svd_basis(snap, n=2, layout="rows")
show("non-symplectic basis", lambda: SymplecticROM(fom, type(b)(V=1.1 * b.V, singular_values=b.singular_values, n=2)))
show("basis of another dimension", lambda: SymplecticROM(WaveFOM(30), b))
show("wave parameter outside the declared range", lambda: fom.trajectory(snap[:1], 0.5, 0.1, 1))

# --- issue 16: files are hostile input, saving never damages what is there, no silent numerics
from sympredict.container import write_container
from sympredict.io import save_dataset, load_dataset
import sympredict.container as container
from sympredict.cli import main as cli_main
from sympredict_paper.cli import main as paper_main
from sympredict.systems.pendulum import random_flow_map_data


def hostile(label, attack):
    path = os.path.join(tmp, "h.h5")
    m.save(path)
    with h5py.File(path, "r+") as f:
        attack(f)
    show(f"load: {label}", lambda: SymplecticKernelPredictor.load(path))


fifo = os.path.join(tmp, "fifo")
os.mkfifo(fifo)
hostile("external link to a FIFO", lambda f: f["arrays"].__setitem__("x", h5py.ExternalLink(fifo, "/a")))
hostile(
    "external link to /etc/passwd (the whole group)",
    lambda f: (f.__delitem__("arrays"), f.__setitem__("arrays", h5py.ExternalLink("/etc/passwd", "/"))),
)
hostile("soft link", lambda f: f["arrays"].__setitem__("y", h5py.SoftLink("/arrays/coef")))
src = os.path.join(tmp, "src.h5")
with h5py.File(src, "w") as f:
    f["d"] = np.arange(4.0)


def vds(f):
    layout = h5py.VirtualLayout(shape=(4,), dtype="f8")
    layout[:] = h5py.VirtualSource(src, "d", shape=(4,))
    f["arrays"].create_virtual_dataset("v", layout)


hostile("virtual dataset", vds)
hostile(
    "external storage (/etc/passwd)",
    lambda f: f["arrays"].create_dataset("e", shape=(16,), dtype="f8", external=[("/etc/passwd", 0, 128)]),
)
hostile(
    "compressed dataset (80 MB of zeros)",
    lambda f: f["arrays"].create_dataset("z", data=np.zeros(10**7), compression="gzip", chunks=(10**6,)),
)
hostile("huge declared dataset (8 TB)", lambda f: f["arrays"].create_dataset("big", shape=(10**12,), dtype="f8"))
hostile("object the writer never writes", lambda f: f.create_group("extra"))
hostile("attribute the writer never writes", lambda f: f["arrays/coef"].attrs.__setitem__("note", 1))
hostile(
    "changed settings, checksum unchanged",
    lambda f: f.attrs.__setitem__(
        "settings", np.bytes_(f.attrs["settings"].decode().replace('"max_centers": 40', '"max_centers": 41'))
    ),
)
for v in (0, -3, 1.7, "1"):
    hostile(f"schema version {v!r}", lambda f, v=v: f.attrs.__setitem__("schema_version", v))
show("load: a FIFO as the path (no hang)", lambda: SymplecticKernelPredictor.load(fifo))
show("load: /dev/null", lambda: SymplecticKernelPredictor.load(os.devnull))
p = os.path.join(tmp, "m.h5")
m.save(p)
b = bytearray(open(p, "rb").read())
i = b.find(b"HEAP")
b[i : i + 4] = b"\0\0\0\0"  # the group's name heap
open(os.path.join(tmp, "dmg.h5"), "wb").write(bytes(b))
show("load: damaged HDF5 structure", lambda: SymplecticKernelPredictor.load(os.path.join(tmp, "dmg.h5")))
dp = os.path.join(tmp, "d.h5")
write_container(
    dp,
    "sympredict-dataset",
    {"metadata": {}},
    {"x0": np.ones((4, 2)), "x1": np.ones((3, 2)), "mu": np.ones((4, 1)), "dt": np.ones(4)},
)
show("load_dataset: x0 and x1 of different shapes", lambda: load_dataset(dp))
write_container(
    dp,
    "sympredict-dataset",
    {"metadata": {}},
    {"x0": np.ones((4, 2)), "x1": np.ones((4, 2)), "mu": np.ones((4, 1)), "dt": -np.ones(4)},
)
show("load_dataset: dt <= 0", lambda: load_dataset(dp))
show("save: to a FIFO", lambda: m.save(fifo))
show("save: to /dev/null", lambda: m.save(os.devnull))
link = os.path.join(tmp, "link.h5")
os.symlink(p, link)
m.save(link)
print(
    f"| save: to a symlink | written through: the link is still a link ({os.path.islink(link)}), its target a regular file ({os.path.isfile(p)}) |"
)
old = os.umask(0o022)
q = os.path.join(tmp, "new.h5")
m.save(q)
os.umask(old)
os.chmod(p, 0o640)
m.save(p)
print(
    f"| save: new file under umask 022; overwrite of a 0640 file | modes {oct(stat.S_IMODE(os.stat(q).st_mode))} and {oct(stat.S_IMODE(os.stat(p).st_mode))} |"
)
before = open(p, "rb").read()
real_write = os.write


def full(fd, data):
    raise OSError(errno.ENOSPC, "No space left on device")


container.os.write = full
show("save: disk full (os.write raises ENOSPC)", lambda: m.save(p))
container.os.write = real_write
print(
    f"| ... after the failed save | previous file intact: {open(p, 'rb').read() == before}; temporary files left: {len([n for n in os.listdir(tmp) if n.endswith('.tmp')])} |"
)
a, b2 = os.path.join(tmp, "a.h5"), os.path.join(tmp, "b.h5")
import time as _time

m.save(a)
_time.sleep(1.1)
m.save(b2)
print(f"| save the same model twice, 1.1 s apart | identical bytes: {open(a, 'rb').read() == open(b2, 'rb').read()} |")


def cli(argv, main=cli_main):
    import contextlib, io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as e:
            code = e.code
    return f"exit {code}: {err.getvalue().strip()}".replace(tmp, "/tmp/…")


save_dataset(d, dp)
print(f"| `sympredict train d.h5 --out d.h5` | `{cli(['train', dp, '--out', dp])}` |")
print(
    f"| `sympredict-paper run pendulum --threads 0` | `{cli(['run', 'pendulum', '--out', os.path.join(tmp, 'r'), '--threads', '0'], paper_main)}` |"
)
print(
    f"| `sympredict-paper run` with `--out` an existing file | `{cli(['run', 'pendulum', '--out', p], paper_main)}` |"
)
print(f"| `sympredict report` of a hostile file | `{cli(['report', os.path.join(tmp, 'h.h5')])}` |")
show("Pendulum(g=nan)", lambda: Pendulum(g=np.nan))
show("reference flow with h_max <= 0", lambda: Pendulum().flow(x, 0.75, 0.05, h_max=0.0))
show("wave FOM, negative time step", lambda: fom.exact_trajectory(snap[:1], 0.05, -0.1, 3))
show("complex snapshots", lambda: complex_svd_basis(snap * (1 + 1j), n=2))
show(
    "sampler that can never accept (mass 1e12: H < 2g only for /q/ < 2e-6)",
    lambda: random_flow_map_data(Pendulum(mass=1e12), 50),
)
