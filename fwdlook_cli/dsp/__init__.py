"""Signal processing shared by both radar systems: arrays in, arrays out, no I/O and no scenario dicts.

Keystone family (``keystone``, ``keystone_czt``, ``keystone_common``), compressed pulse and range axis
(``pulse``), monopulse antenna patterns (``antenna``), platform/target geometry (``geometry``), peak
interpolation and point-target metrics (``peaks``, ``profile``)."""
