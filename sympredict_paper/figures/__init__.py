"""The scripts that make the documentation's generated pages and figures from runs (``python
sympredict_paper/figures/NAME.py``; each docstring gives its command)."""
