"""Files at the edges: the raw cube and its HDF5 layout (``cube``, ``raw``), stage files (``stagefile``),
atomic writes and datasets with units (``h5``), quick-look PNGs (``quicklook``), listings (``describe``)."""
