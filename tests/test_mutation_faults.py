"""The mutation check's faults (tools/mutation_check.py) still apply: each snippet stands exactly once in its file
and each test module it names exists, so a change of the code cannot silently turn a fault into an error."""

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _faults():
    spec = importlib.util.spec_from_file_location("sympredict_mutation_check", ROOT / "tools" / "mutation_check.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module.FAULTS


def test_every_fault_applies_to_the_current_code():
    faults = _faults()
    assert len(faults) >= 70
    stale = [
        (f.id, f.file, (ROOT / f.file).read_text().count(f.snippet))
        for f in faults
        if (ROOT / f.file).read_text().count(f.snippet) != 1
    ]
    assert not stale, f"faults whose snippet does not stand exactly once in its file: {stale}"
    missing = [(f.id, t) for f in faults for t in f.tests if not (ROOT / t.split("::")[0]).exists()]
    assert not missing, f"faults naming test modules that do not exist: {missing}"
