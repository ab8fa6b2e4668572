"""Options shared by several commands (rasterio-style: one module, reused decorators)."""
from __future__ import annotations

import click

set_option = click.option(
    "--set", "overrides", multiple=True, metavar="KEY.PATH=VALUE",
    help="Override one scenario key by its dotted path; value parsed as YAML. Repeatable.")
def _quiet(ctx, param, value):
    if value:                       # same as the group's -q, kept on the commands for compatibility
        from .console import set_quiet

        set_quiet()
    return value


quiet_option = click.option("-q", "--quiet", is_flag=True, callback=_quiet,
                            help="No progress on stderr (as `fwdlook -q COMMAND`).")
json_option = click.option("--json", "as_json", is_flag=True, help="Print JSON on stdout.")


class GroundMetres(click.ParamType):
    """A finite ground coordinate in metres (|value| <= 1e7 m: click's FloatRange lets NaN through)."""

    name = "metres"

    def convert(self, value, param, ctx):
        import math

        try:
            number = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(number) or abs(number) > 1e7:
            self.fail(f"{value!r}: allowed: a finite number of metres, |value| <= 1e7", param, ctx)
        return number
