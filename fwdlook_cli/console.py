"""What the CLI shows on stderr: logging configuration and the closing summary table of a run.

The library logs with ``logging.getLogger(__name__)`` (loggers under ``fwdlook_cli``) and configures
nothing; the ``fwdlook`` command calls :func:`configure_logging` once per invocation: INFO (progress)
by default, WARNING with ``-q``, DEBUG (with the logger's name) with ``-v``.  Messages go to whatever
``sys.stderr`` is at the time of the message, so pytest's capture and redirections see them.
"""
from __future__ import annotations

import logging
import math
import sys

LOGGER = "fwdlook_cli"


class _StderrHandler(logging.Handler):
    def emit(self, record):
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


def configure_logging(verbose: int = 0, quiet: bool = False) -> logging.Logger:
    """Level from ``-v`` (count) and ``-q``: WARNING if quiet, DEBUG if verbose, else INFO."""
    logger = logging.getLogger(LOGGER)
    for h in list(logger.handlers):
        if isinstance(h, _StderrHandler):
            logger.removeHandler(h)
    handler = _StderrHandler()
    fmt = "%(levelname)s %(name)s: %(message)s" if verbose else "%(message)s"
    handler.setFormatter(logging.Formatter(fmt))
    logger.addHandler(handler)
    logger.propagate = False
    logger.setLevel(logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO))
    return logger


def set_quiet() -> None:
    """A command's own ``-q`` (kept for compatibility): progress off, warnings still shown."""
    logging.getLogger(LOGGER).setLevel(logging.WARNING)


def _num(value, digits=3) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}" if math.isfinite(value) else "nan"
    return str(value)


# (label, key over all targets, key over the resolved ones, digits)
FORWARD_ROWS = (
    ("max |range error| (m)", "max_abs_range_error_m", "max_abs_range_error_resolved_m", 2),
    ("median |range error| (m)", "median_abs_range_error_m", "median_abs_range_error_resolved_m", 2),
    ("rms azimuth error (deg)", "rms_azimuth_error_deg", "rms_azimuth_error_resolved_deg", 3),
    ("max |azimuth error| (deg)", "max_abs_azimuth_error_deg", "max_abs_azimuth_error_resolved_deg", 3),
    ("median ISLR (dB)", "median_islr_db", None, 1),
    ("median peak loss (dB)", "median_peak_loss_db", None, 1),
)
ISAR_ROWS = (
    ("migration span (range cells)", "migration_span_cells", 2),
    ("integration gain (dB)", "integration_gain_db", 2),
    ("range 3 dB width (m)", "range_width_3db_m", 3),
    ("cross-range 3 dB width (m)", "cross_range_width_3db_m", 3),
    ("ISLR range / azimuth (dB)", ("islr_db", "azimuth_islr_db"), 1),
    ("n0 used (pulses)", "n0_used_pulses", 1),
)


def summary_table(metrics: dict, run_dir) -> str:
    """A short table of a run's metrics.json: a headline and one line per figure of merit."""
    s = metrics.get("summary") or {}
    t = (metrics.get("timing_s") or {}).get("total")
    p = metrics.get("params") or {}
    head = f"{run_dir}: {metrics.get('scenario', '?')}, {metrics.get('method', '?')}"
    if "t_ref" in p:
        head += f", t_ref = {p['t_ref']}"
    lines = [head]
    if "migration_span_cells" in s:        # ISAR
        lines.append(f"  {'detected':<30s} {str(s.get('detected', 0)) + '/' + str(s.get('n_targets', 0)):>10s}")
        for label, key, nd in ISAR_ROWS:
            value = " / ".join(_num(s.get(k), nd) for k in key) if isinstance(key, tuple) else _num(s.get(key), nd)
            lines.append(f"  {label:<30s} {value:>10s}")
    else:
        # (a resolved column only where some targets are not: with every one resolved it is the same)
        has_res = s.get("detected_resolved") is not None and s.get("n_resolved") != s.get("n_targets")
        lines.append(f"  {'':<30s} {'all':>10s}" + (f" {'resolved':>10s}" if has_res else ""))
        det = f"{s.get('detected', 0)}/{s.get('n_targets', 0)}"
        lines.append(f"  {'detected':<30s} {det:>10s}"
                     + (f" {str(s.get('detected_resolved')) + '/' + str(s.get('n_resolved')):>10s}" if has_res else ""))
        for label, key, key_res, nd in FORWARD_ROWS:
            if s.get(key) is None and not (has_res and key_res and s.get(key_res) is not None):
                continue
            line = f"  {label:<30s} {_num(s.get(key), nd):>10s}"
            if has_res and key_res:
                line += f" {_num(s.get(key_res), nd):>10s}"
            lines.append(line)
    if t is not None:
        lines.append(f"  {'time (s)':<30s} {_num(float(t), 2):>10s}")
    return "\n".join(lines)
