"""``fwdlook report``: figures and tables for one run or several side by side (CONTRACT.md 1, 4, 5).

Reads each run directory's ``metrics.json`` and ``image.h5`` (CONTRACT.md section 4) and writes, into
the report directory, atomically:

``report.md``
    per run: method, params, t_ref and the summary metrics; a per-target table (up to
    :data:`MAX_TARGET_ROWS` targets); the time of every stage.  Every number is read from the run's
    metrics.json and printed with :data:`SIG_DIGITS` significant digits, never typed by hand.
``images.png``
    the monopulse images side by side in dB on one colour scale (0 dB = brightest pixel of all
    runs), truth markers, axes in deg and m.
``real_beam.png``
    the first run's real-beam image (sum power against beam angle) beside its monopulse image: the
    angular-resolution gain.
``range_profiles.png``
    paper Fig. 7 style: normalised range profiles through one target (default the target nearest
    ground (x, y) = (-300, 1700) m when truth exists) for every run overlaid, interpolated x5, truth
    range marked.
``errors.png``
    range and azimuth error per detected target against ground x, one series per run.

Plotting stays at this edge (``plots.py``); this module only reads files and arranges numbers.
"""
from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BadInput
from ..io.describe import checked_axis, checked_grid, read_json_text
from ..io.h5 import atomic_write_text
from ..io.outputs import mapped_os_errors, unmake_dirs
from ..limits import shown
from .tables import SIG_DIGITS, fmt_value, is_number, md_table, summary_rows

MAX_TARGET_ROWS = 70
DEFAULT_TARGET_XY_M = (-300.0, 1700.0)      # paper Fig. 7: azimuth distance -300 m, ground range 1700 m
PROFILE_HALF_WINDOW_M = 15.0                # half the paper lattice spacing: the next row stays out
PROFILE_ANGLE_HALF_DEG = 0.25               # columns summed into the range cut (as evaluate.py does)
PROFILE_INTERP = 5                          # paper Sec. 4.1: "interpolated by five times"
TARGET_COLUMNS = ("id", "x_m", "y_m", "true_range_m", "meas_range_m", "range_error_m", "true_azimuth_deg",
                  "meas_azimuth_deg", "azimuth_error_deg", "islr_db", "pslr_db", "detected")


@dataclass
class Run:
    """One run directory: its metrics and (when it is a forward-looking image) the image arrays."""

    path: Path
    label: str
    metrics: dict
    image: dict | None          # range_m, angle_deg, image, and real_beam, range_native_m when present
    image_note: str = ""


# ----------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------
def read_metrics(run_dir: str | Path) -> dict:
    """The run's metrics.json; BadInput (one line naming the path) when missing or malformed."""
    path = Path(run_dir) / "metrics.json"
    if not Path(run_dir).is_dir():
        what = "a file, not a folder" if Path(run_dir).exists() else "no such directory"
        raise BadInput(f"{run_dir}: not a run directory ({what}); expected a folder written by "
                       f"fwdlook run or process")
    if not (path.exists() or path.is_symlink()):
        raise BadInput(f"{path}: metrics.json not found; expected a run directory written by "
                       f"fwdlook run or fwdlook process")
    metrics = read_json_text(path)
    if not isinstance(metrics, dict):
        raise BadInput(f"{path}: top level: expected a JSON object")
    for key in ("method", "summary", "timing_s"):
        if key not in metrics:
            raise BadInput(f"{path}: {key}: missing; required: method, summary, timing_s (CONTRACT.md 5)")
    _check_metrics_shape(metrics, path)
    return metrics


TARGET_NUMBERS = ("id", "x_m", "y_m", "true_range_m", "true_azimuth_deg")     # CONTRACT.md 5, always given
TARGET_NUMBERS_OR_NULL = ("meas_range_m", "meas_azimuth_deg", "range_error_m", "azimuth_error_deg",
                          "islr_db", "pslr_db")                               # null (or absent) where undetected


def _check_metrics_shape(metrics: dict, path: Path) -> None:
    """The parts of metrics.json the report reads, of the kind CONTRACT.md section 5 gives them: a file
    edited by hand or damaged is one line naming the key, not a traceback in a figure."""
    for key in ("summary", "timing_s", "params"):
        if key in metrics and not isinstance(metrics[key], dict):
            raise BadInput(f"{path}: {key} = {shown(metrics[key])}: expected a JSON object")
    bad = [k for k, v in metrics["timing_s"].items() if v is not None and not is_number(v)]
    if bad:
        raise BadInput(f"{path}: timing_s.{bad[0]} = {shown(metrics['timing_s'][bad[0]])}: expected seconds")
    targets = metrics.get("targets", [])
    if not isinstance(targets, list):
        raise BadInput(f"{path}: targets = {shown(targets)}: expected a list of target objects")
    for i, target in enumerate(targets):
        if not isinstance(target, dict):
            raise BadInput(f"{path}: targets[{i}] = {shown(target)}: expected a target object")
        for key in TARGET_NUMBERS:
            if not is_number(target.get(key)):
                raise BadInput(f"{path}: targets[{i}].{key} = {shown(target.get(key))}: expected a number "
                               f"(CONTRACT.md 5)")
        for key in TARGET_NUMBERS_OR_NULL:
            if target.get(key) is not None and not is_number(target[key]):
                raise BadInput(f"{path}: targets[{i}].{key} = {shown(target[key])}: expected a number or null")


def read_image(run_dir: str | Path) -> tuple[dict | None, str]:
    """(arrays of image.h5, note): None and a note when the run has no forward-looking image."""
    import h5py

    path = Path(run_dir) / "image.h5"
    if not path.exists():
        raise BadInput(f"{path}: image.h5 not found; expected a run directory written by fwdlook run "
                       f"or fwdlook process")
    try:
        with h5py.File(path, "r") as f:
            if not all(isinstance(f.get(k), h5py.Dataset) for k in ("image", "range_m", "angle_deg")):
                return None, f"{path}: no /image, /range_m, /angle_deg datasets; image figures skipped"
            out = {"range_m": checked_axis(f, path, "range_m"), "angle_deg": checked_axis(f, path, "angle_deg")}
            out["image"] = checked_grid(f, path, "image", "range_m", "angle_deg")
            if all(isinstance(f.get(k), h5py.Dataset) for k in ("real_beam", "range_native_m")):
                out["range_native_m"] = checked_axis(f, path, "range_native_m")
                out["real_beam"] = checked_grid(f, path, "real_beam", "range_native_m", "angle_deg")
    except OSError:
        raise BadInput(f"{path}: not a readable HDF5 file (truncated or not HDF5)") from None
    return out, ""


def run_labels(paths: list[Path]) -> list[str]:
    """Short unique labels: the directory name, or more of the path where names repeat."""
    paths = [Path(p).resolve() for p in paths]
    for depth in range(1, 8):
        labels = ["/".join(p.parts[-depth:]) for p in paths]
        if len(set(labels)) == len(labels):
            return labels
    return [str(p) for p in paths]


def load_runs(run_dirs) -> list[Run]:
    """Every run directory, validated before anything is written."""
    paths = [Path(d) for d in run_dirs]
    if not paths:
        raise BadInput("report: give at least one RUN_DIR")
    runs = []
    for path, label in zip(paths, run_labels(paths)):
        metrics = read_metrics(path)
        if not (path / "scenario.yaml").exists():     # written last (io/pending.py): a run that did not finish
            logging.getLogger(__name__).warning(
                f"{path}: no scenario.yaml: the run did not finish (stopped while its outputs were put in place, "
                f"or older than that file): its metrics.json and image.h5 may be from two runs; run it again")
        image, note = read_image(path)
        runs.append(Run(path, label, metrics, image, note))
    return runs


def target_columns(metrics: dict) -> tuple[str, ...]:
    """TARGET_COLUMNS, plus ``resolved`` when the run's metrics flag it."""
    targets = metrics.get("targets") or []
    return TARGET_COLUMNS + (("resolved",) if any("resolved" in t for t in targets) else ())


def target_rows(metrics: dict) -> list[list[str]]:
    cols = target_columns(metrics)
    return [[fmt_value(t.get(c)) for c in cols] for t in metrics.get("targets") or []]


def timing_table(runs: list[Run]) -> str:
    stages = []
    for run in runs:
        for k in run.metrics["timing_s"]:
            if k not in stages and k != "total":
                stages.append(k)
    stages.append("total")
    rows = [[s] + [fmt_value(run.metrics["timing_s"].get(s)) for run in runs] for s in stages]
    return md_table(["stage"] + [f"`{run.label}`" for run in runs], rows)


# ----------------------------------------------------------------------------------------------
# Image geometry helpers (shared with reproduce.py)
# ----------------------------------------------------------------------------------------------
def truth_markers(metrics: dict):
    targets = metrics.get("targets") or []
    if not targets:
        return None
    return (np.array([t["true_azimuth_deg"] for t in targets]), np.array([t["true_range_m"] for t in targets]))


def crop_image(image: dict, metrics: dict, *, key="image", range_key="range_m", margin_m=30.0,
               margin_deg=4.0):
    """(power, angle_deg, range_m) cropped to the truth extent plus margins, or to the lit pixels."""
    power, angle, rng = image[key], image["angle_deg"], image[range_key]
    markers = truth_markers(metrics)
    if markers is not None:
        r0, r1 = markers[1].min() - margin_m, markers[1].max() + margin_m
        a0, a1 = markers[0].min() - margin_deg, markers[0].max() + margin_deg
    else:
        lit_r = np.nonzero(np.any(power > 0, axis=1))[0]
        lit_a = np.nonzero(np.any(power > 0, axis=0))[0]
        if len(lit_r) == 0 or len(lit_a) == 0:
            return power, angle, rng
        r0, r1 = rng[lit_r[0]] - margin_m, rng[lit_r[-1]] + margin_m
        a0, a1 = angle[lit_a[0]], angle[lit_a[-1]]
    ri = (rng >= r0) & (rng <= r1)
    ai = (angle >= a0) & (angle <= a1)
    if not ri.any() or not ai.any():
        return power, angle, rng
    return power[np.ix_(ri, ai)], angle[ai], rng[ri]


def fill_beam_gaps(real_beam):
    """The real-beam image holds one column per CPI beam angle (a CPI step is several angle bins):
    fill the empty bins between them with a running maximum over one CPI step, for display only."""
    from ..dsp.neighbours import running_max

    lit = np.nonzero(np.any(real_beam > 0, axis=0))[0]
    if len(lit) < 2:
        return real_beam
    gaps = np.diff(lit)
    n_groups = 1 + int(np.count_nonzero(gaps > 1))     # one group of adjacent bins per CPI beam angle
    if n_groups < 2:
        return real_beam
    step = int(np.ceil((lit[-1] - lit[0]) / (n_groups - 1))) + 1
    return running_max(real_beam, step, axis=1) if step > 1 else real_beam


def nearest_target(metrics: dict, xy_m) -> dict | None:
    targets = metrics.get("targets") or []
    if not targets:
        return None
    d = [math.hypot(t["x_m"] - xy_m[0], t["y_m"] - xy_m[1]) for t in targets]
    return targets[int(np.argmin(d))]


def range_profile(image: dict, *, centre_range_m: float, azimuth_deg: float,
                  half_window_m: float = PROFILE_HALF_WINDOW_M, angle_half_deg: float = PROFILE_ANGLE_HALF_DEG,
                  interp: int = PROFILE_INTERP):
    """Range profile through (centre_range_m, azimuth_deg) of a (range, angle) power image.

    The power of the columns within +-``angle_half_deg`` is summed (as evaluate.py's range cut),
    the amplitude (square root) taken over +-``half_window_m`` and interpolated ``interp`` times by a
    cubic spline on the image's range sampling.  Returns (range_m, amplitude), amplitude >= 0.
    """
    from scipy.interpolate import CubicSpline

    rng, ang, power = image["range_m"], image["angle_deg"], image["image"]
    cols = np.abs(ang - azimuth_deg) <= max(angle_half_deg, 0.5 * abs(float(ang[1] - ang[0])))
    rows = np.abs(rng - centre_range_m) <= half_window_m
    if cols.sum() == 0 or rows.sum() < 4:
        return np.array([]), np.array([])
    cut = power[np.ix_(rows, cols)].sum(axis=1).astype(np.float64)
    r = rng[rows]
    amp = np.sqrt(np.maximum(cut, 0.0))
    fine = np.linspace(r[0], r[-1], (len(r) - 1) * interp + 1)
    return fine, np.maximum(CubicSpline(r, amp)(fine), 0.0)


def profile_through_target(run: Run, xy_m):
    """(range, amplitude, target row or None) of a run's range profile through the target nearest xy_m;
    without truth, through the image's brightest pixel."""
    target = nearest_target(run.metrics, xy_m)
    if target is not None:
        az = target["meas_azimuth_deg"] if target.get("meas_azimuth_deg") is not None else target["true_azimuth_deg"]
        r, a = range_profile(run.image, centre_range_m=target["true_range_m"], azimuth_deg=az)
        return r, a, target
    i, j = np.unravel_index(np.argmax(run.image["image"]), run.image["image"].shape)
    r, a = range_profile(run.image, centre_range_m=float(run.image["range_m"][i]),
                         azimuth_deg=float(run.image["angle_deg"][j]))
    return r, a, None


# ----------------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------------
def _run_title(run: Run) -> str:
    p = run.metrics.get("params") or {}
    bits = [run.metrics["method"]]
    if run.metrics["method"] == "decimation":
        bits.append(f"Q={p.get('q')}")
    if "range_curvature" in p:
        bits.append("curv. on" if p["range_curvature"] else "curv. off")
    if "t_ref" in p:
        bits.append(f"t_ref={p['t_ref']}")
    return f"{run.label}\n{', '.join(str(b) for b in bits)}"


def write_figures(runs: list[Run], out: Path, *, target_xy=DEFAULT_TARGET_XY_M) -> tuple[dict, list[str]]:
    """Write the report's PNGs; returns ({name: caption}, notes)."""
    from .plots import error_scatter, image_panels, range_profile_panels

    figures, notes = {}, [r.image_note for r in runs if r.image_note]
    imaged = [r for r in runs if r.image is not None]
    if imaged:
        panels = []
        for run in imaged:
            power, ang, rng = crop_image(run.image, run.metrics)
            panels.append({"power": power, "x": ang, "y": rng, "title": _run_title(run),
                           "markers": truth_markers(run.metrics)})
        image_panels(out / "images.png", panels, ncols=min(len(panels), 3),
                     suptitle="monopulse images (truth: open circles)")
        figures["images.png"] = ("monopulse images side by side, dB on one colour scale (0 dB = brightest "
                                 "pixel of all runs), truth at t_ref as open circles")
        first = imaged[0]
        if "real_beam" in first.image:
            rb, rb_ang, rb_rng = crop_image(first.image, first.metrics, key="real_beam", range_key="range_native_m")
            rb = fill_beam_gaps(rb)
            mp, mp_ang, mp_rng = crop_image(first.image, first.metrics)
            mk = truth_markers(first.metrics)
            image_panels(out / "real_beam.png", [
                {"power": rb, "x": rb_ang, "y": rb_rng, "markers": mk,
                 "title": f"{first.label}: real beam (sum power vs beam angle)"},
                {"power": mp, "x": mp_ang, "y": mp_rng, "markers": mk,
                 "title": f"{first.label}: monopulse image"}], reference="each",
                suptitle="angular resolution: real beam against monopulse")
            figures["real_beam.png"] = (f"real-beam image of `{first.label}` beside its monopulse image "
                                        f"(each normalised to its own peak)")
        else:
            notes.append(f"{first.path}/image.h5: no /real_beam; real_beam.png skipped")
        curves, truths, chosen = [], [], None
        for run in imaged:
            r, a, target = profile_through_target(run, target_xy)
            if len(r) == 0:
                notes.append(f"{run.label}: the range profile window is outside the image; not drawn")
                continue
            curves.append({"x": r, "amplitude": a, "label": run.label, "target": target})
            if target is not None:
                truths.append(target["true_range_m"])
                chosen = target
        if curves:
            relative = len(truths) == len(curves) and np.ptp(truths) > 1e-6
            if relative:      # different t_ref: plot the offset from each run's own truth
                for c in curves:
                    c["x"] = c["x"] - c["target"]["true_range_m"]
                truth_lines, xlabel = [0.0], "slant range minus true range at t_ref (m)"
            else:
                truth_lines, xlabel = (truths[:1] if truths else []), "slant range at t_ref (m)"
            where = (f"target {chosen['id']} at ground (x, y) = ({chosen['x_m']:g}, {chosen['y_m']:g}) m"
                     if chosen is not None else "the brightest pixel of each image (no truth)")
            range_profile_panels(out / "range_profiles.png",
                                 [{"title": f"range profiles through {where}", "curves": curves,
                                   "truth": truth_lines}], xlabel=xlabel)
            figures["range_profiles.png"] = (f"normalised range profiles through {where}, every run overlaid, "
                                             f"interpolated x{PROFILE_INTERP} (cubic), truth dashed")
    series = []
    for run in runs:
        det = [t for t in run.metrics.get("targets") or [] if t.get("detected") and t.get("range_error_m") is not None
               and t.get("azimuth_error_deg") is not None]
        if det:
            series.append({"label": run.label, "x_m": [t["x_m"] for t in det],
                           "range_error_m": [t["range_error_m"] for t in det],
                           "azimuth_error_deg": [t["azimuth_error_deg"] for t in det]})
    if series:
        error_scatter(out / "errors.png", series, title="per-target errors against truth at t_ref (detected)")
        figures["errors.png"] = "range and azimuth error of every detected target against its ground x"
    else:
        notes.append("no run has detected targets with truth: errors.png skipped")
    return figures, notes


# ----------------------------------------------------------------------------------------------
# The report
# ----------------------------------------------------------------------------------------------
def report_markdown(runs: list[Run], figures: dict, notes: list[str]) -> str:
    out = ["# fwdlook report", "",
           f"Generated by `fwdlook report` from {len(runs)} run director{'y' if len(runs) == 1 else 'ies'}. "
           f"Every number below is read from the run's `metrics.json` (CONTRACT.md section 5), printed to "
           f"{SIG_DIGITS} significant digits; none is typed by hand.", "",
           "## Runs", "",
           md_table(["run", "directory", "scenario", "method", "t_ref", "t_ref_s"],
                    [[f"`{r.label}`", f"`{r.path}`", fmt_value(r.metrics.get("scenario")),
                      fmt_value(r.metrics["method"]), fmt_value((r.metrics.get("params") or {}).get("t_ref")),
                      fmt_value(r.metrics.get("t_ref_s"))] for r in runs])]
    if figures:
        out += ["## Figures", ""]
        out += [f"- [{name}]({name}): {caption}" for name, caption in figures.items()]
        out += [""] + [f"![{name}]({name})" for name in figures] + [""]
    for run in runs:
        out += [f"## Run `{run.label}`", "", "### Summary", "",
                md_table(["key", "value"], summary_rows(run.metrics))]
        targets = run.metrics.get("targets") or []
        if targets and len(targets) <= MAX_TARGET_ROWS:
            out += ["### Targets", "", "Errors are measured minus true, at t_ref (m, deg); ISLR and PSLR in dB.",
                    "", md_table(target_columns(run.metrics), target_rows(run.metrics))]
        elif targets:
            out += ["### Targets", "", f"{len(targets)} targets (over {MAX_TARGET_ROWS}): see "
                    f"`{run.path / 'metrics.json'}`.", ""]
    out += ["## Timing per stage (s)", "", timing_table(runs)]
    if notes:
        out += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    return "\n".join(out).rstrip("\n") + "\n"


def default_report_dir(run_dirs) -> Path:
    run_dirs = list(run_dirs)
    return Path(run_dirs[0]) / "report" if len(run_dirs) == 1 else Path("reports") / "compare"


def make_report(run_dirs, out_dir=None, *, target_xy=DEFAULT_TARGET_XY_M, overwrite=False) -> Path:
    """Write the report of ``run_dirs`` into ``out_dir`` (default :func:`default_report_dir`); returns
    the path of report.md.  Raises BadInput before writing anything when a run directory is bad, or
    when ``out_dir`` holds report files fwdlook did not write (unless ``overwrite``)."""
    from ..io.outputs import OVERWRITE_HINT, is_fwdlook_report, prepare_report_dir

    from .htmlreport import extra_figures, is_sweep_dir, read_sweep_summary, write_html

    sweep_dirs = [d for d in run_dirs if is_sweep_dir(d)]          # sweeps: shown in index.html only
    plain = [d for d in run_dirs if d not in sweep_dirs]
    runs = load_runs(plain) if plain or not sweep_dirs else []
    summaries = {d: read_sweep_summary(d) for d in sweep_dirs}     # every input read before anything is written
    out = Path(out_dir) if out_dir else default_report_dir(run_dirs)
    inputs = [Path(d) / n for d in plain for n in ("metrics.json", "image.h5")]
    final = prepare_report_dir(out, inputs=inputs, overwrite=overwrite)
    # every file is written into a folder of its own inside the report folder, and moved into place once
    # all are written (index.html last): a report that fails (a full disk, SIGTERM) leaves none of its
    # files, where it had left figures and a report.md that looked complete without their index.html
    _remove_dead_stagings(final)
    try:
        staging = Path(tempfile.mkdtemp(dir=final, prefix=f"{STAGING_PREFIX}{os.getpid()}-"))
    except OSError as exc:
        raise BadInput(f"cannot write {final}: {exc.strerror or exc}") from None
    try:
        figures, notes = write_figures(runs, staging, target_xy=target_xy) if runs else ({}, [])
        more, more_notes = extra_figures(runs, staging)            # ground plane, ISAR echoes and image
        figures.update(more)
        notes += more_notes
        text = report_markdown(runs, figures, notes) if runs else "# fwdlook report\n"
        if sweep_dirs:
            text += ("\nSweeps (their tables, stability maps and speed-accuracy charts are in `index.html`): "
                     + ", ".join(f"`{d}`" for d in sweep_dirs) + ".\n")
        atomic_write_text(staging / "report.md", text)
        write_html(staging / "index.html", runs, figures, notes, sweep_dirs, summaries)   # one self-contained file
        with mapped_os_errors(final):
            if not overwrite and not is_fwdlook_report(final):   # the figures named after the runs and
                # sweeps too (ground_<run>.png, sweep_<name>_*.png), not only REPORT_FILES: a user's file
                # of such a name had been replaced (an independent review)
                taken = sorted(q.name for q in staging.iterdir()
                               if (final / q.name).exists() or (final / q.name).is_symlink())
                if taken:
                    raise BadInput(f"{final / taken[0]}: exists and was not written by fwdlook report; refusing "
                                   f"to overwrite it; {OVERWRITE_HINT}")
            for q in sorted(staging.iterdir(), key=lambda q: q.name == "index.html"):
                os.replace(q, final / q.name)
    except BadInput as exc:          # (named where the file goes, not the folder it is written in first)
        shutil.rmtree(staging, ignore_errors=True)
        unmake_dirs(final)
        raise BadInput(str(exc).replace(str(staging), str(final))) from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        unmake_dirs(final)           # a report folder this command made, left empty: removed
        raise
    shutil.rmtree(staging, ignore_errors=True)
    return final / "report.md"


STAGING_PREFIX = ".fwdlook-report-"


def _remove_dead_stagings(folder: Path) -> None:
    """The staging folders of reports that were killed (SIGKILL runs no cleanup): those whose process,
    named in the folder's name, is gone. A report running beside this one keeps its own."""
    for q in folder.glob(f"{STAGING_PREFIX}*"):
        pid = q.name[len(STAGING_PREFIX):].split("-", 1)[0]
        if not pid.isdigit() or not q.is_dir() or q.is_symlink():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(q, ignore_errors=True)
        except (PermissionError, OverflowError):
            pass
