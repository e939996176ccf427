"""Reports of fits: figures (plots.py) and one HTML page (html.py)."""
