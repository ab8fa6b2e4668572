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


BENCH_FLAGS = {"--json": "as_json", "--scaling": "scaling", "--plot": "plot_path", "--repeats": "repeats",
               "--write-cube": "write_cube", "--shape": "shape", "--scene": "scene", "--backend": "backend",
               "--overwrite": "overwrite"}          # fwdlook bench's options and their parameters' names
BENCH_MODE_FLAGS = {"--write-cube": ("--shape", "--overwrite"),      # writes a cube, measures nothing
                    "--scaling": ("--plot", "--repeats", "--json", "--overwrite")}   # the CPU chains only


def check_bench_options(ctx, *, write_cube, scaling, backend) -> None:
    """``fwdlook bench``'s options that do not go together, refused in one line (exit 2) before any
    timing: an option given on the command line that its mode ignores, and ``--backend gpu`` on a
    machine without CuPy or a CUDA device (naming the option, not ``processing.backend``)."""
    from .errors import BadInput

    given = {flag for flag, name in BENCH_FLAGS.items()
             if ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE}
    if backend != "gpu":
        given.discard("--backend")                  # --backend cpu: what every mode does
    for flag, needs, present in (("--shape", "--write-cube", write_cube), ("--plot", "--scaling", scaling),
                                 ("--overwrite", "--write-cube or --scaling", write_cube or scaling)):
        if flag in given and not present:
            raise BadInput(f"{flag}: applies only with {needs}; allowed: {flag} together with {needs}")
    for mode, present in (("--write-cube", write_cube), ("--scaling", scaling)):
        extra = sorted(given - {mode, *BENCH_MODE_FLAGS[mode]})
        if present and extra:
            raise BadInput(f"{extra[0]}: does not apply with {mode}; allowed with {mode}: "
                           f"{', '.join(BENCH_MODE_FLAGS[mode])}")
    if backend == "gpu":
        from .dsp.xp import get_xp

        get_xp("gpu", key="--backend")


def check_stage_options(from_stage, force: bool, kind: str | None) -> None:
    """``process``'s ``--from-stage`` and ``--force``, refused in one line before any work: both given
    (first thing), or, once the scenario's ``kind`` is known, a stage that no chain of that kind has (the
    chain's own list is checked once it is built: ``runner.run_stages``)."""
    from .errors import BadInput
    from .limits import shown

    if force and from_stage:
        raise BadInput(f"--force with --from-stage {shown(from_stage)}: --force recomputes every stage, "
                       f"--from-stage the stages from {shown(from_stage)} on; allowed: one of them")
    if from_stage is not None and kind is not None:
        if kind == "isar":
            from .isar.chain import STAGE_NAMES
        else:
            from .forward.chain import STAGE_NAMES
        if from_stage not in STAGE_NAMES:
            raise BadInput(f"--from-stage {shown(from_stage)}: no {kind} chain has this stage; allowed: "
                           f"{', '.join(STAGE_NAMES)}")
