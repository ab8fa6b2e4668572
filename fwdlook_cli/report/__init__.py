"""Reports and experiments: figures (``plots``), ``fwdlook report`` (``report``), sweeps (``sweep``), the
reproduction (``experiments`` as data, ``render`` for tables and figures, ``reproduce`` to run them), the
ISAR tables (``isar_tables``) and ``fwdlook bench`` (``bench``)."""
