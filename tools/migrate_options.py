"""Rewrite calls that pass sympredict 0.1's flat estimator options into the composed parts.

Usage::

    python tools/migrate_options.py FILE.py [FILE.py ...]      # rewrites in place, prints what it could not

``SymplecticKernelPredictor(IMQ(0.3), tol=1e-8, backend='numba', periodic=(0,))`` becomes
``SymplecticKernelPredictor(Periodic(IMQ(0.3), coordinates=(0,)), trainer=ExactGreedy(tol=1e-8),
solver=NewtonSolver(backend='numba'))`` and the imports it needs are added after the file's last
``sympredict`` import.  Calls it cannot rewrite (``**kwargs``, a trainer given as a variable) are listed
with their line numbers and left alone; their options keep working with a FutureWarning.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ESTIMATORS = {"SymplecticKernelPredictor", "DirectKernelPredictor"}
TRAINER = {"tol": "tol", "criterion": "criterion", "power_tol": "power_tol", "memory_limit": "memory_limit",
           "regularization": "regularization"}
SOLVER = {"backend": "backend", "newton_max_iter": "max_iter", "newton_warm_start": "warm_start"}
KERNEL = {"state_scaling", "periodic", "period", "symmetry"}
NEUTRAL_FOR_ACTIVE_SET = {"criterion": "'f'", "regularization": "0.0"}
IMPORTS = {"ExactGreedy": "sympredict.interpolation.greedy", "NewtonSolver": "sympredict.symplectic.solvers", "Scaled": "sympredict.kernels.transforms",
           "Periodic": "sympredict.kernels.transforms", "Symmetric": "sympredict.kernels.transforms"}


def _name(func) -> str:
    return func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""


def _rewrite_call(src: str, call: ast.Call, lines: list, needed: set, problems: list):
    """The replacement text of ``call``, or ``None``."""
    kws = {k.arg: k for k in call.keywords if k.arg is not None}
    moved = [k for k in kws if k in TRAINER or k in SOLVER or k in KERNEL]
    if not moved:
        return None
    if any(k.arg is None for k in call.keywords):
        problems.append((call.lineno, "**kwargs in the call"))
        return None
    seg = lambda node: ast.get_source_segment(src, node)  # noqa: E731
    args = [seg(a) for a in call.args]
    keep = [(k.arg, seg(k.value)) for k in call.keywords if k.arg not in moved]
    trainer_opts = [(TRAINER[k], seg(kws[k].value)) for k in moved if k in TRAINER]
    solver_opts = [(SOLVER[k], seg(kws[k].value)) for k in moved if k in SOLVER]
    kernel_opts = {k: seg(kws[k].value) for k in moved if k in KERNEL}
    if trainer_opts:
        given = dict(keep).get("trainer")
        if given is None or given == "None":
            keep = [(k, v) for k, v in keep if k != "trainer"]
            keep.append(("trainer", "ExactGreedy(" + ", ".join(f"{k}={v}" for k, v in trainer_opts) + ")"))
            needed.add("ExactGreedy")
        else:
            node = kws["trainer"].value
            if not isinstance(node, ast.Call):
                problems.append((call.lineno, f"trainer={given} is not a call: fold {trainer_opts} by hand"))
                return None
            if _name(node.func) == "ActiveSetGreedy":
                trainer_opts = [(k, v) for k, v in trainer_opts if NEUTRAL_FOR_ACTIVE_SET.get(k) not in (v,)
                                and not (k in NEUTRAL_FOR_ACTIVE_SET and v in ('"f"', "0", "0.0"))]
            inner = [seg(a) for a in node.args] + [f"{k.arg}={seg(k.value)}" for k in node.keywords]
            inner += [f"{k}={v}" for k, v in trainer_opts]
            keep = [(k, (f"{seg(node.func)}(" + ", ".join(inner) + ")") if k == "trainer" else v) for k, v in keep]
    if solver_opts:
        keep.append(("solver", "NewtonSolver(" + ", ".join(f"{k}={v}" for k, v in solver_opts) + ")"))
        needed.add("NewtonSolver")
    if kernel_opts:
        if args:
            state = args[0]
        else:
            state = dict(keep).get("state_kernel", "None")
            keep = [(k, v) for k, v in keep if k != "state_kernel"]
        if "state_scaling" in kernel_opts and kernel_opts["state_scaling"] != "None":
            state = f"Scaled({state}, factors={kernel_opts['state_scaling']})"
            needed.add("Scaled")
        if "periodic" in kernel_opts and kernel_opts["periodic"] != "None":
            period = f", period={kernel_opts['period']}" if "period" in kernel_opts else ""
            state = f"Periodic({state}, coordinates={kernel_opts['periodic']}{period})"
            needed.add("Periodic")
        elif "period" in kernel_opts:
            problems.append((call.lineno, "period= without periodic=: dropped"))
        if "symmetry" in kernel_opts and kernel_opts["symmetry"] != "None":
            state = f"Symmetric({state}, group={kernel_opts['symmetry']})"
            needed.add("Symmetric")
        if args:
            args[0] = state
        else:
            args = [state]
    parts = args + [f"{k}={v}" for k, v in keep]
    head = f"{seg(call.func)}("
    text = head + ", ".join(parts) + ")"
    if call.col_offset + len(text) <= 115:
        return text
    # wrap: as many arguments per line as fit, continuation lines under the first argument
    indent = " " * (call.col_offset + len(head))
    out, line = [], head
    for i, part in enumerate(parts):
        piece = part + ("," if i < len(parts) - 1 else ")")
        if line.strip() and len(line) + 1 + len(piece) + (call.col_offset if not out else 0) > 115 and line != head:
            out.append(line.rstrip())
            line = indent + piece
        else:
            line = line + ("" if line == head else " ") + piece
    out.append(line)
    return "\n".join(out)


def migrate(path: Path) -> list:
    src = path.read_text()
    tree = ast.parse(src)
    lines = src.splitlines(keepends=True)
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line))
    edits, needed, problems = [], set(), []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and _name(node.func) in ESTIMATORS:
            text = _rewrite_call(src, node, lines, needed, problems)
            if text is not None:
                start = offsets[node.lineno - 1] + len(lines[node.lineno - 1][:node.col_offset].encode()) * 0 + node.col_offset
                end = offsets[node.end_lineno - 1] + node.end_col_offset
                edits.append((start, end, text))
    # nested estimator calls are rare; apply outermost edits only
    edits.sort()
    kept = []
    for e in edits:
        if kept and e[0] < kept[-1][1]:
            continue
        kept.append(e)
    for start, end, text in reversed(kept):
        src = src[:start] + text + src[end:]
    if needed:
        tree = ast.parse(src)
        have = {a.asname or a.name for n in ast.walk(tree) if isinstance(n, (ast.ImportFrom, ast.Import)) for a in n.names}
        missing = sorted(needed - have)
        if missing:
            by_module: dict = {}
            for name in missing:
                by_module.setdefault(IMPORTS[name], []).append(name)
            new = "".join(f"from {m} import {', '.join(sorted(ns))}\n" for m, ns in sorted(by_module.items()))
            top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
            sp = [n for n in top if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("sympredict")]
            anchor = (sp or top)[-1] if (sp or top) else None
            src_lines = src.splitlines(keepends=True)
            at = anchor.end_lineno if anchor is not None else 0
            src = "".join(src_lines[:at]) + new + "".join(src_lines[at:])
    path.write_text(src)
    return [(path, line, why) for line, why in problems] + ([(path, 0, f"rewrote {len(kept)} call(s)")] if kept else [])


if __name__ == "__main__":
    for p in sys.argv[1:]:
        for path, line, why in migrate(Path(p)):
            print(f"{path}:{line}: {why}")
