"""The paper's code, beside the library (as pyMOR keeps ``pymordemos``): scenarios as functions returning results
(numbers and arrays, no figures), the report and its figures, the runner and the studies.

The library ``sympredict`` never imports this package (an import-linter contract).  Its command is
``sympredict-paper`` (:mod:`sympredict_paper.cli`): ``sympredict-paper run pendulum --quick --out DIR`` runs a
scenario, ``sympredict-paper study NAME`` a study; each scenario module has its own ``main``
(``python -m sympredict_paper.pendulum --quick --out DIR``).
"""
