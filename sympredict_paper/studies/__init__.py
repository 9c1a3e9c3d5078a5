"""The paper's studies: each script measures one question in depth and writes the JSON under ``docs/data/`` that the
documentation renders its numbers from.  Run one as ``sympredict-paper study NAME [ARGS]`` or
``python sympredict_paper/studies/NAME.py [ARGS]`` (the script's folder on ``sys.path``: the helpers ``_protocol``,
``_coordinate_search`` and ``_sine_gordon_data`` are imported by name)."""
