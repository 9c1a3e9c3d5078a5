"""The paper's code, apart from the library: scenarios as functions returning results (numbers and arrays,
no figures), the report and its figures.

Nothing in the library imports this package; ``sympredict run`` and ``sympredict report``
(:mod:`sympredict.cli`) do, when they run.
"""
