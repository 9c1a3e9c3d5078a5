"""Edited copies of model files with a valid checksum, as anyone can write them (the hostile-file tests)."""

from sympredict.container import read_container, write_container
from sympredict.estimators.predictor import MODEL_FORMAT


def _rewrite(src, dst, settings=None, arrays=None):
    """A copy of the model file ``src`` with edited settings / arrays and a valid checksum."""
    s, a = read_container(src, MODEL_FORMAT)
    if settings is not None:
        settings(s)
    if arrays is not None:
        arrays(a)
    write_container(dst, MODEL_FORMAT, s, a)
    return dst


def _param(name, value):
    def edit(s):
        s["params"][name] = value

    return edit
