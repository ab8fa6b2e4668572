"""Options shared by several commands (rasterio-style: one module, reused decorators)."""
from __future__ import annotations

import click

set_option = click.option(
    "--set", "overrides", multiple=True, metavar="KEY.PATH=VALUE",
    help="Override one scenario key by its dotted path; value parsed as YAML. Repeatable.")
quiet_option = click.option("-q", "--quiet", is_flag=True, help="No progress on stderr.")
json_option = click.option("--json", "as_json", is_flag=True, help="Print JSON on stdout.")
