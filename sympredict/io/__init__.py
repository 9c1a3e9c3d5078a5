"""Files of trained models and data sets.

:mod:`~sympredict.io.formats` names the two formats, ``'sympredict-model'`` and
``'sympredict-dataset'``, and maps them to objects; the container they are
written in (layout, checksum, atomic save, checked load) is
:mod:`sympredict.container`, which the estimators use to save themselves.
:func:`~sympredict.io.read_trajectories` reads the user's own
trajectories or flow-map pairs from ``.npz``, HDF5 or ``.csv`` files.
"""

from sympredict.io.formats import SCHEMA_VERSION, load_dataset, load_model, save_dataset, save_model
from sympredict.io.trajectories import read_states, read_trajectories, write_trajectories

__all__ = [
    "SCHEMA_VERSION",
    "save_model",
    "load_model",
    "save_dataset",
    "load_dataset",
    "read_trajectories",
    "write_trajectories",
    "read_states",
]
