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
