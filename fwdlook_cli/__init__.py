"""fwdlook: forward-looking scanning monopulse radar imaging from accelerating platforms."""

__version__ = "0.1.0"
