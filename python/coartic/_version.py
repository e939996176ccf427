"""The package's version, in a module of its own at the bottom of the import graph: the modules
that record it (a table's metadata, an output's run marker, ``coartic --version``) import it from
here, not from the package, which sits at the top of the graph (it names the estimator)."""

__version__ = "0.1.0"
