"""The three-way comparison of a run: the paper's Tables 1-3 for one drive, as CSV and Markdown."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from featmap.io.atomic import atomic_write_text
from featmap.io.jsonfile import read_json

COLUMNS = ["method", "count", "count_ratio", "precision", "precision_any", "recall", "redundancy", "offset_cm",
           "corner_err_cm", "seconds"]
TITLES = {"proposed": "Proposed (three criteria)", "meanshift": "Competing 1: mean shift",
          "density": "Competing 2: density clustering"}


def comparison_rows(metrics: dict) -> list[dict]:
    """One row per method: count (Table 1), quality metrics, vertex error sums (Table 2), time (Table 3)."""
    rows = []
    labels = sorted({lab for m in metrics["methods"].values() for lab in (m.get("vertex_error_sum_m") or {})})
    for name, m in metrics["methods"].items():
        row = {c: m.get(c) for c in COLUMNS if c not in ("method",)}
        row["method"] = name
        for lab in labels:
            row[f"vertex_{lab}_m"] = (m.get("vertex_error_sum_m") or {}).get(lab)
        rows.append(row)
    return rows


def _fmt(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4f}" if abs(value) < 10 else f"{value:.1f}"
    return str(value)


def comparison_markdown(metrics: dict, rows: list[dict]) -> str:
    keys = list(rows[0]) if rows else COLUMNS
    keys = ["method"] + [k for k in keys if k != "method"]
    out = [f"# Comparison: {metrics.get('drive', '?')} ({metrics.get('scans_processed', '?')} scans, "
           f"{metrics.get('segments', '?')} extracted segments)", ""]
    out.append("| " + " | ".join(keys) + " |")
    out.append("|" + "---|" * len(keys))
    for row in rows:
        out.append("| " + " | ".join(_fmt(row.get(k)) for k in keys) + " |")
    out.append("")
    out.append("count = fused features (Table 1); vertex_*_m = sum of distances from a labelled building vertex to the "
               "nearest endpoints of the fused features on its two walls (Table 2); seconds = fusion time incl. corner "
               "optimisation (Table 3). Metrics as defined in EVALUATION.md (TOL 0.30 m, ANG 10 deg).")
    return "\n".join(out) + "\n"


def write_comparison(run_dir: str | Path) -> tuple[list[dict], str]:
    """Read ``run_dir/metrics.json``; write ``comparison.csv`` and ``comparison.md`` next to it."""
    run_dir = Path(run_dir)
    metrics = read_json(run_dir / "metrics.json", "not found: is this a featmap run folder?")
    rows = comparison_rows(metrics)
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    atomic_write_text(run_dir / "comparison.csv", buf.getvalue())
    md = comparison_markdown(metrics, rows)
    atomic_write_text(run_dir / "comparison.md", md)
    return rows, md
