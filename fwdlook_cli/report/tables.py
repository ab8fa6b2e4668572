"""Numbers and markdown tables of reports: one formatting of a metrics.json value, and its inverse."""
from __future__ import annotations

import math
import re

SIG_DIGITS = 6


def fmt_value(value) -> str:
    """A metrics.json value as printed in report.md (numbers to SIG_DIGITS significant digits)."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if not math.isfinite(value) else f"{value:.{SIG_DIGITS}g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(fmt_value(v) for v in value) + "]"
    return str(value).replace("|", "\\|")          # markdown's escaped bar: the text reads as metrics.json's


def parse_value(text: str):
    """Inverse of :func:`fmt_value` for scalars (what a reader or a test gets back from report.md)."""
    text = text.strip()
    if text == "-":
        return None
    if text in ("yes", "no"):
        return text == "yes"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text.replace("\\|", "|")


def md_table(heads, rows) -> str:
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def parse_md_table(lines: list[str]) -> list[list[str]]:
    """Cells of a markdown table's body rows (header and rule skipped)."""
    rows = [[c.strip() for c in re.split(r"(?<!\\)\|", ln.strip().strip("|"))]     # not at an escaped bar
            for ln in lines if ln.strip().startswith("|")]
    return rows[2:]


def summary_rows(metrics: dict) -> list[tuple[str, str]]:
    """(key, printed value) for method, scenario, params.*, t_ref_s and summary.* of one run."""
    rows = [("scenario", fmt_value(metrics.get("scenario"))), ("method", fmt_value(metrics["method"]))]
    params = metrics.get("params") or {}
    rows += [(f"params.{k}", fmt_value(v)) for k, v in params.items()]
    rows.append(("t_ref_s", fmt_value(metrics.get("t_ref_s"))))
    rows += [(f"summary.{k}", fmt_value(v)) for k, v in metrics["summary"].items()]
    return rows


def is_number(value) -> bool:
    """A JSON number (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)
