"""fwdlook: forward-looking scanning monopulse radar imaging from accelerating platforms.

``import fwdlook_cli as fw`` gives the Python API (scenario loader, simulator, stages, metrics on
arrays; see :mod:`fwdlook_cli.api`), each name imported on first use so that the CLI starts fast.
"""

__version__ = "0.4.2"


def __getattr__(name):
    from .api import EXPORTS

    if name in EXPORTS:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    from .api import EXPORTS

    return sorted(set(globals()) | set(EXPORTS))
