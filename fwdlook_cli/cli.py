"""The ``fwdlook`` command line: thin click commands, heavy imports inside them, no DSP here.

Exit codes (CONTRACT.md section 1): 0 success; 2 bad input, one line on stderr naming the file, key
or dataset; 1 internal fault (traceback kept).  Progress and logs go to stderr, data to stdout.
"""
from __future__ import annotations

import contextlib
import logging
import signal
import sys
from pathlib import Path

import click

from . import __version__
from .cube_source import RAW_SETTABLE, is_cube_path, reads_cube, refuse_unused_sets, scenario_note
from .errors import BadInput, Terminated
from .options import GroundMetres, check_bench_options, check_stage_options, json_option, quiet_option, set_option


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="fwdlook")
@click.option("-v", "--verbose", count=True, help="More on stderr: debug messages with their module (any command).")
@click.option("-q", "--quiet", is_flag=True, help="Only warnings and errors on stderr (any command).")
def cli(verbose, quiet):
    """Forward-looking scanning monopulse radar: simulate, correct, image, measure."""
    from .console import configure_logging

    configure_logging(verbose, quiet)


log = logging.getLogger("fwdlook_cli.cli")


def _log(quiet: bool, message: str) -> None:
    if not quiet:
        log.info(message)


overwrite_option = click.option("--overwrite", is_flag=True,
                                help="Write over an existing output that fwdlook did not write (never over an input).")


@cli.command()
@click.argument("scenario")
@click.option("-o", "--output", "output", required=True, help="Raw cube HDF5 to write.")
@set_option
@overwrite_option
@click.option("--out-of-core", "out_of_core", is_flag=True,
              help="Synthesise the echoes into unnamed scratch files beside the output instead of memory "
                   "(forward-looking scenarios): cubes larger than the machine's memory; the same file.")
@quiet_option
def simulate(scenario, output, overrides, overwrite, out_of_core, quiet):
    """Synthesise the range-compressed sum/difference echo cube of SCENARIO.yaml."""
    import time

    from .scenario.loader import load_scenario
    from .io.raw import write_raw
    from .io.outputs import prepare_file
    from .scenario.scene_image import scenario_input_files
    from .forward.simulate import simulate_scenario
    from .io.backing import SIMULATE_X_CUBE

    scn = load_scenario(scenario, overrides)
    _refuse_run_options(scn, scenario, out_of_core)
    output = prepare_file(output, inputs=[scenario, *scenario_input_files(scn)], overwrite=overwrite)
    with _out_of_core(out_of_core, output):    # the scratch files' folder: the output's own
        if scn["kind"] != "forward":
            from .isar.simulate import simulate_isar_scenario  # noqa: F401  (ISAR scenario kind)

            cube, stats = simulate_isar_scenario(scn)
        else:
            t0 = time.perf_counter()
            cube, stats = simulate_scenario(scn, in_memory_x_cube=SIMULATE_X_CUBE, source=scenario)
            _log(quiet, f"simulate: {cube.n_pulses} pulses x {cube.n_range} range samples, "
                        f"{stats.n_pairs_kept}/{stats.n_pairs} target-pulse pairs above the gain "
                        f"threshold, {time.perf_counter() - t0:.2f} s")
        write_raw(output, cube)
    _log(quiet, f"wrote {output}")


def _scenario_and_cube(source, raw, config, overrides, quiet, before_cube=None):
    """(resolved scenario, cube): simulate a scenario, or load RAW (given, or as the source).

    ``before_cube(scn)`` runs once the scenario is resolved, before a cube is simulated or read
    (where the outputs are prepared, so that a refused output costs no work).
    """
    from .scenario.readers import read_scenario_raw
    from .io.raw import read_raw
    from .scenario.overlay import resolve_with_config
    from .dsp.xp import require_backend

    src = Path(source)
    if is_cube_path(src):
        if raw:
            raise BadInput(f"{source}: give either a raw cube or --raw, not both")
        refuse_unused_sets(source, overrides)
        raw, raw_scn, name = source, {}, src.stem
        cube = read_raw(raw)          # read first: its channels decide the scenario kind
        if cube.diff is None or cube.attrs.get("scenario_kind") == "isar":
            raw_scn = {"kind": "isar"}
            if cube.diff is not None:              # (it had been dropped without a word)
                log.warning(f"{source}: processed as ISAR (/ attribute scenario_kind = isar): /echo/diff is not read")
    else:
        if raw:
            refuse_unused_sets(raw, overrides, RAW_SETTABLE)
        raw_scn, name = read_scenario_raw(source), None   # the one scenario reader (readers.py)
    if raw_scn is not None and not isinstance(raw_scn, dict):
        raise BadInput(f"{source}: top level: expected a mapping of scenario sections")
    if name is not None:
        raw_scn = {**raw_scn, "name": name}
    scn = resolve_with_config(raw_scn, source, config, overrides, check_pulses=not (raw or name))
    require_backend(scn, source)              # a GPU asked for and absent: refused before any work
    if before_cube is not None:
        before_cube(scn)
    if raw and name is None:          # (a named source is the cube itself, already read)
        cube = read_raw(raw)
    elif name is None:
        if scn["kind"] != "forward":
            from .isar.simulate import simulate_isar_scenario

            cube, _ = simulate_isar_scenario(scn)
        else:
            from .forward.simulate import refuse_an_all_zero_cube, simulate_scenario
            from .io.backing import IN_MEMORY_X_CUBE

            cube, stats = simulate_scenario(scn, in_memory_x_cube=IN_MEMORY_X_CUBE, doing="simulating and processing",
                                            source=source)
            _log(quiet, f"simulate: {cube.n_pulses} x {cube.n_range}, {stats.n_pairs_kept}/{stats.n_pairs} "
                        f"target-pulse pairs above the gain threshold")
            refuse_an_all_zero_cube(scn, stats, source)             # as process refuses such a RAW.h5
    return scn, cube


def _default_run_dir(scn, output):
    return Path(output) if output else Path("runs") / scn["name"]


def _process(scn, cube, run_dir, force, from_stage, quiet, source="raw cube", keep_stages="all",
             out_of_core=False, from_file=False, note="", raw_staged=False):
    if scn["kind"] == "isar":
        from .isar.process import process_isar_cube

        _refuse_run_options(scn, source, out_of_core, keep_stages)
        try:
            return process_isar_cube(cube, scn, run_dir, force=force, from_stage=from_stage, quiet=quiet,
                                     scenario_note=note, raw_staged=raw_staged)
        except BadInput as exc:         # a stage's refusal of a setting (e.g. processing.n0_pulses): the file too
            if str(exc).startswith("processing."):
                raise BadInput(f"{source}: {exc}") from None
            raise
    from .forward.calibration import check_antenna_against_data
    from .forward.process import process_cube

    if from_file:
        check_antenna_against_data(scn, cube, source)
    return process_cube(cube, scn, run_dir, force=force, from_stage=from_stage, quiet=quiet, source=source,
                        keep_stages=keep_stages, release_cube=True, scenario_note=note, raw_staged=raw_staged)


def _print_summary(metrics, run_dir, quiet):
    if not quiet:
        from .console import summary_table
        log.info(summary_table(metrics, run_dir))


config_option = click.option("-c", "--config", "config", default=None, metavar="CONFIG.yaml",
                             help="Processing preset merged over the scenario's processing section.")
raw_option = click.option("--raw", "raw", default=None, metavar="RAW.h5", help="Process this cube instead of simulating.")
keep_stages_option = click.option(
    "--keep-stages", "keep_stages", type=click.Choice(["all", "last", "none"]), default="all", show_default=True,
    help="Stage files written: all (resumable), last (the image stage, and what its profile metrics read: "
         "the Doppler spectra with CPI imaging, the range-curvature output with dwell imaging of a cube with "
         "truth), none (fastest; a rerun recomputes everything).")
output_dir_option = click.option("-o", "--output", "output", default=None, metavar="RUN_DIR",
                                 help="Run directory (default runs/<scenario name>).")
out_of_core_option = click.option(
    "--out-of-core", "out_of_core", is_flag=True,
    help="Hold the raw cube's echoes and every stage's arrays in unnamed scratch files beside the run "
         "directory instead of in memory (forward chain, CPU): cubes larger than the machine's memory; "
         "the same results.")


def _refuse_run_options(scn, source, out_of_core: bool, keep_stages: str = "all") -> None:
    """The options a scenario cannot take (ISAR: out of core, some stages kept; whole arrays out of core)."""
    if keep_stages != "all" and scn["kind"] == "isar":
        raise BadInput(f"{source}: --keep-stages {keep_stages}: the ISAR chain keeps every stage; allowed: all")
    if out_of_core and scn["kind"] == "isar":
        raise BadInput(f"{source}: --out-of-core: the ISAR chain runs in memory; --out-of-core is for the "
                       f"forward-looking chain (scenario kind forward)")
    if out_of_core:
        from .forward.process import refuse_out_of_core_settings

        refuse_out_of_core_settings(scn.get("processing") or {}, source)


def _out_of_core(enabled: bool, output):
    """The context of ``--out-of-core`` (io/backing.py): scratch files in the run directory's parent."""
    import contextlib

    if not enabled:
        return contextlib.nullcontext()
    from .io.backing import file_backed

    return file_backed(Path(output).absolute().parent if output else Path("runs"))


@cli.command()
@click.argument("source")
@output_dir_option
@config_option
@raw_option
@set_option
@click.option("--from-stage", "from_stage", default=None, metavar="STAGE",
              help="Recompute from this stage on (forward: range_fft, decimate, keystone, regroup, range_curvature, "
                   "doppler_spectra, monopulse_image or dwell_image; ISAR: range_fft, rcmc, range_ifft, "
                   "azimuth_compress).")
@click.option("--force", is_flag=True, help="Recompute every stage.")
@overwrite_option
@keep_stages_option
@out_of_core_option
@quiet_option
def process(source, output, config, raw, overrides, from_stage, force, overwrite, keep_stages, out_of_core, quiet):
    """Run the chain stage by stage on SCENARIO.yaml (simulated or --raw) or on RAW.h5."""
    from .io.outputs import folder_lock, prepare_run_dir
    from .scenario.scene_image import scenario_input_files

    check_stage_options(from_stage, force, None)        # first thing; the stage's name once the kind is known
    held = contextlib.ExitStack()        # the run directory's lock, until the command ends

    def prepare(scn):
        check_stage_options(from_stage, False, scn["kind"])          # before any work (a simulation)
        _refuse_run_options(scn, raw or source, out_of_core, keep_stages)
        d = prepare_run_dir(_default_run_dir(scn, output), inputs=[source, raw, config, *scenario_input_files(scn)],
                            overwrite=overwrite)
        held.enter_context(folder_lock(d))
        _start_fit_spawner(scn)

    from .io.quicklook import painting

    with held, painting(), _out_of_core(out_of_core, output):   # the PNG's matplotlib in a child (io/painter.py)
        scn, cube = _scenario_and_cube(source, raw, config, overrides, quiet, before_cube=prepare)
        run_dir = _default_run_dir(scn, output)
        metrics = _process(scn, cube, run_dir, force, from_stage, quiet, raw or source, keep_stages, out_of_core,
                           from_file=reads_cube(source, raw), note=scenario_note(source, raw))
    _print_summary(metrics, run_dir, quiet)


@cli.command()
@click.argument("scenario")
@output_dir_option
@config_option
@raw_option
@set_option
@click.option("--force", is_flag=True, help="Recompute every stage.")
@overwrite_option
@keep_stages_option
@out_of_core_option
@quiet_option
def run(scenario, output, config, raw, overrides, force, overwrite, keep_stages, out_of_core, quiet):
    """The main job: simulate (or load --raw), process and report into RUN_DIR."""
    from .io.raw import write_raw
    from .io.outputs import folder_lock, prepare_run_dir
    from .io.pending import discarded_on_failure, staged
    from .scenario.scene_image import scenario_input_files

    writes_raw = not reads_cube(scenario, raw)
    held = contextlib.ExitStack()        # the run directory's lock, until the command ends

    def prepare(scn):
        _refuse_run_options(scn, raw or scenario, out_of_core, keep_stages)
        d = prepare_run_dir(_default_run_dir(scn, output), inputs=[scenario, raw, config, *scenario_input_files(scn)],
                            overwrite=overwrite, writes_raw=writes_raw)
        held.enter_context(folder_lock(d))
        _start_fit_spawner(scn)

    from .io.quicklook import painting

    with held, painting(), _out_of_core(out_of_core, output):   # the PNG's matplotlib in a child (io/painter.py)
        scn, cube = _scenario_and_cube(scenario, raw, config, overrides, quiet, before_cube=prepare)
        run_dir = _default_run_dir(scn, output)
        # the new cube staged, put in place with the new outputs once all are written: a rerun refused or
        # failing on the way leaves the earlier run whole, its cube with it (io/pending.py)
        with discarded_on_failure(run_dir, raw=writes_raw):
            if writes_raw:
                write_raw(staged(run_dir, "raw.h5"), cube)
            metrics = _process(scn, cube, run_dir, force, None, quiet, raw or scenario, keep_stages, out_of_core,
                               from_file=not writes_raw, note=scenario_note(scenario, raw), raw_staged=writes_raw)
    _print_summary(metrics, run_dir, quiet)
    click.echo(str(run_dir / "metrics.json"))


@cli.command()
@click.argument("scenario")
@set_option
@json_option
def plan(scenario, overrides, as_json):
    """The migration budget of a scene (SCENARIO.yaml, or RAW.h5: its INS track): which corrections it needs and why."""
    from .scenario.loader import load_scenario
    from .forward.plan import format_plan, plan_for_cube, plan_for_scenario, plan_json

    cube = None
    if is_cube_path(scenario):    # a recorded cube's own track and radar (it had been refused as a scenario)
        scn, cube = _scenario_and_cube(scenario, None, None, overrides, quiet=True)
    else:
        scn = load_scenario(scenario, overrides)
    if scn["kind"] != "forward":
        raise BadInput(f"{scenario}: kind = {scn['kind']}: plan covers forward-looking scenes; allowed: forward")
    if cube is not None and scn["processing"]["cpi"] > cube.n_pulses:     # as process refuses it
        raise BadInput(f"{scenario}: processing.cpi = {scn['processing']['cpi']}: longer than the cube's "
                       f"{cube.n_pulses} pulses")
    result = plan_for_cube(cube, scn["processing"]) if cube is not None else plan_for_scenario(scn)
    click.echo(plan_json(result) if as_json else format_plan(result, scn["name"]))


@cli.command()
@click.argument("sweep_file")
@click.option("-o", "--output", "output", default=None, metavar="DIR", help="Output folder (default runs/sweep-<name>).")
@click.option("--workers", type=click.IntRange(1, 64), default=1, show_default=True, help="Parallel processes.")
@click.option("--scheduler", default="local", show_default=True, metavar="local|tcp://HOST:PORT",
              help="Where points run: 'local' (this process, or a pool of --workers processes) or the "
                   "address of a dask.distributed scheduler (pip install -e .[dask]).")
@overwrite_option
@quiet_option
def sweep(sweep_file, output, workers, scheduler, overwrite, quiet):
    """Grids of runs: summary table, speed-accuracy chart, stability map.

    Finished points (same scenario hash) are skipped on a rerun; a failed point is recorded in the
    summary and the others go on (exit 1 at the end if any failed)."""
    from .report.sweep import load_sweep, run_sweep

    spec = load_sweep(sweep_file)
    out = Path(output) if output else Path("runs") / f"sweep-{spec['name']}"
    rows = run_sweep(sweep_file, out, workers=workers, quiet=quiet, scheduler=scheduler, overwrite=overwrite)
    click.echo(str(out / "summary.md"))
    failed = [r for r in rows if r.get("status") == "failed"]
    if failed:
        click.echo(f"fwdlook: error: sweep: {len(failed)} of {len(rows)} points failed; their errors are in "
                   f"{out / 'summary.md'}", err=True)
        sys.exit(1)


@cli.command()
@click.argument("run_dirs", nargs=-1, required=True, metavar="RUN_DIR...")
@click.option("-o", "--output", "output", default=None, metavar="REPORT_DIR",
              help="Report folder (default RUN_DIR/report for one run, reports/compare for several).")
@click.option("--target", "target", nargs=2, type=GroundMetres(), default=None, metavar="X_M Y_M",
              help="Ground (x, y) of the target whose range profile is drawn (default: nearest -300 1700).")
@overwrite_option
@quiet_option
def report(run_dirs, output, target, overwrite, quiet):
    """Figures and tables for one run or several side by side (report.md, PNGs, index.html).

    A sweep output folder may be given too: its table, stability map and chart go into index.html."""
    from .report.report import DEFAULT_TARGET_XY_M, make_report

    path = make_report(run_dirs, output, target_xy=tuple(target) if target else DEFAULT_TARGET_XY_M,
                       overwrite=overwrite)
    _log(quiet, f"wrote {path.parent}/ (report.md, figures, and index.html: one self-contained file)")
    click.echo(str(path))


@cli.command()
@click.argument("path")
def info(path):
    """Describe a raw cube, a stage file or an image (FILE.h5)."""
    from .report.info import describe

    click.echo(describe(path))


@cli.command()
@click.argument("path")
@set_option
def validate(path, overrides):
    """Check a scenario (YAML) or a raw cube (HDF5); exit 0 if valid, 2 if not."""
    from .scenario.loader import load_scenario, scenario_hash
    from .io.backing import read_without_holding
    from .io.raw import read_raw
    from .forward.process import check_cube_overrides

    p = Path(path)
    if is_cube_path(p):
        refuse_unused_sets(path, overrides)
        with read_without_holding():             # any size of cube: checked block by block, not held
            cube = read_raw(p)
        check_cube_overrides(path, cube, overrides)        # a --set checked as process checks it
        click.echo(f"{path}: valid raw cube, {cube.n_pulses} pulses x {cube.n_range} range samples")
    else:
        scn = load_scenario(p, overrides)
        click.echo(f"{path}: valid {scn['kind']} scenario '{scn['name']}', sha256 {scenario_hash(scn)[:16]}")


@cli.command()
@json_option
@click.option("--scaling", is_flag=True, help="The scaling series instead: pulses 1250-20000, range bins "
              "256-4096, fitted exponents per stage and a log-log plot (minutes).")
@click.option("--plot", "plot_path", default="runs/bench/scaling.png", show_default=True, metavar="PNG",
              help="Where --scaling draws its plot.")
@click.option("--repeats", type=click.IntRange(1, 50), default=3, show_default=True,
              help="Chain runs per measurement (medians).")
@click.option("--write-cube", "write_cube", default=None, metavar="RAW.h5",
              help="Only write a cheap cube of --shape (three points, the paper's radar) for memory runs.")
@click.option("--shape", nargs=2, type=click.IntRange(32, 1 << 20), default=(16384, 4096), show_default=True,
              metavar="PULSES RANGE", help="Shape of --write-cube.")
@click.option("--scene", "scene", is_flag=True,
              help="Also time the scene simulator at 1e3..1e6 scatterers (minutes; scene_sim_* keys).")
@click.option("--backend", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True,
              help="gpu: time the GPU stages (keystone, Doppler, image cells) against one fft2 on the device.")
@overwrite_option
def bench(as_json, scaling, plot_path, repeats, write_cube, shape, scene, backend, overwrite):
    """Timings measured in one process on the paper cube (ratios to one plain 2-D FFT)."""
    from .report.bench import print_bench

    check_bench_options(click.get_current_context(), write_cube=write_cube, scaling=scaling, backend=backend)
    if write_cube:
        from .io.outputs import prepare_file
        from .limits import check_cube_bytes
        from .report.benchtools import write_scaling_cube

        check_cube_bytes(str(write_cube), f"--shape {shape[0]} {shape[1]}", shape[1], shape[0], channels=2)
        target = prepare_file(write_cube, overwrite=overwrite)    # never over a file fwdlook did not write
        write_scaling_cube(target, *shape)
        click.echo(write_cube)
        return

    if scaling:
        from .io.extra_outputs import bench_png_path

        plot_path = bench_png_path(plot_path, overwrite=overwrite)     # checked before the series (minutes)
    print_bench(as_json, scaling=scaling, plot_path=plot_path, repeats=repeats, scene=scene, backend=backend)


QUICKLOOK_COMMANDS = ("process", "run")        # the commands that end with image.png
QUICKLOOK_WARM_UP = "fwdlook_cli.io.quicklook:warm_up"   # io.quicklook.WARM_UP (not imported here: numpy)


def _start_fit_spawner(scn):
    """The joint fit's spawner (``forward.process.start_fit_spawner``) forked before the cube is read."""
    from .forward.process import start_fit_spawner

    start_fit_spawner(scn.get("processing") or {})


def _command_of(args) -> str | None:
    """The subcommand named by ``args`` (the first word after the group's options); None: help, version."""
    for arg in args:
        if arg in ("-h", "--help", "--version"):
            return None
        if not arg.startswith("-"):
            return arg
    return None


def main(argv=None):
    """Console entry point: maps BadInput and click usage errors to one line and exit 2."""
    from .io import signals     # (light: os, signal, threading; numpy is not imported yet)

    # the handlers first: a Ctrl-C or SIGTERM in a command's first half second (the painter's fork, scipy's
    # import) had given a traceback, or no word at all; only the interpreter's own start is Python's
    restore = signals.install(Terminated)  # SIGTERM cleanly, as Ctrl-C; neither inside HDF5's calls (io/signals.py)
    try:
        _main(argv)
    finally:
        restore()


def _early(argv) -> None:
    """The process's set-up before a command: the BLAS on one thread, the quick look's painter forked
    (both before numpy is imported), scipy.fft's workers, one allocator arena."""
    from .dsp.blas import fft_workers_on_usable_cores, one_blas_thread_for_the_process, share_one_allocator_arena
    from .io import painter

    one_blas_thread_for_the_process()   # before numpy, here and in the painter: no idle BLAS thread spinning
    args = sys.argv[1:] if argv is None else list(argv)
    runs = _command_of(args) if not {"-h", "--help"} & set(args) else None
    if runs in QUICKLOOK_COMMANDS:
        painter.fork_early(QUICKLOOK_WARM_UP)    # before numpy is imported (io/painter.py)
    if runs:
        fft_workers_on_usable_cores()           # scipy.fft's workers=-1 on this process's cores (dsp/blas.py)
    share_one_allocator_arena()          # the stages' thread pools: one allocator arena (dsp/blas.py)


def _run(argv):
    from .io import signals

    # a signal's exception turned into a library's own, or kept past the end, is the signal's
    return signals.as_signalled(cli.main, args=argv, prog_name="fwdlook", standalone_mode=False)


def _main(argv):
    from .io import painter

    try:
        _early(argv)
        rv = _run(argv)
    except BadInput as exc:     # (a lone surrogate, a file name's undecodable byte, written as its escape
        # whatever stream stderr is: a caller's strict one had turned the one line into a UnicodeEncodeError)
        click.echo(f"fwdlook: error: {exc}".encode("utf-8", "backslashreplace").decode("utf-8"), err=True)
        sys.exit(2)
    except Terminated:
        click.echo("fwdlook: terminated (SIGTERM)", err=True)
        sys.exit(128 + signal.SIGTERM)
    except (click.exceptions.Abort, KeyboardInterrupt):
        click.echo("fwdlook: aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        msg = " ".join(exc.format_message().split())
        click.echo(f"fwdlook: error: {msg}", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    finally:
        painter.close_early()
    sys.exit(rv if isinstance(rv, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    main()
