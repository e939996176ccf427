"""The application: the jobs that fit, validate, compare and write files and reports, above the
library they use (issue 28 item 2: a library that returns results, an application that writes them).

- ``fit``: ``fit_job(spec, out)``, the fit (``coartic.fit.runner.run``, which returns its result),
  the ``[choose]`` choice and the held-out validation (``coartic.evaluation``), the result saved
  after every channel, the validation's folders and the HTML report (``coartic.report``);
- ``fit_cli``: ``coartic fit``, which runs ``fit_job`` in an output directory and prints;
- ``compare``: several specs each fitted and validated by ``fit_job``, side by side
  (``coartic.evaluation.compare``'s rows and table); ``compare_cli``: ``coartic compare``.

Layers (tests/python/test_import_graph.py): jobs → evaluation, fit, report; evaluation → fit;
fit → estimation; none of them imports this package. The submodules are imported by name.
"""
