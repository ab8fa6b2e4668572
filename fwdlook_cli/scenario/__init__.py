"""Scenario files: strict YAML (``yamlio``), leaf validators (``fields``), one schema per kind beside its
defaults and checks (``forward``, ``isar``), resolution, ``--set`` and hashing (``loader``), processing
presets (``overlay``)."""
