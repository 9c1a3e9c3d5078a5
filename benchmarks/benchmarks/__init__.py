"""The asv benchmark suite of sympredict (``benchmarks/asv.conf.json``).

Timings (``time_*``), peak memory (``peakmem_*``) and accuracy (``track_*``) of the
library's main paths on small, fixed problems, so that ``asv continuous`` can compare
two revisions.  Threads are set deliberately (one BLAS thread, see :mod:`._common`).
The studies that are experiments rather than timings live in the paper's package
(``sympredict_paper/studies/``).
"""
