"""pbdgrasp: probabilistic grasping strategies from one human demonstration (paper section VIII).

The top floor of the package stack ``assets <- retarget <- inference <- planning <- pbdgrasp``: the
command line (:mod:`pbdgrasp.cli`, one module per subcommand) and the experiments: the strategy
pipeline demonstration -> retargeting -> variation model with its cache keys (:mod:`pbdgrasp.strategy`,
:mod:`pbdgrasp.cache`), the Table I trials on Dask (:mod:`pbdgrasp.table1`), the results database
(:mod:`pbdgrasp.results_db`), the report (:mod:`pbdgrasp.report`), the bench (:mod:`pbdgrasp.bench`) and
the paper's own figures (:mod:`pbdgrasp.paper`). ``python -m pbdgrasp`` is the ``pbdgrasp`` command.
"""

__all__: list[str] = []
