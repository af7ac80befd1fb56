"""The three-way comparison of a run: the paper's Tables 1-3 for one drive, as CSV and Markdown.

Table 1 is the fused feature count, Table 2 the vertex error sums (simulated drives with labelled
vertices), Table 3 the fusion time; the quality metrics of the run's primary evaluator sit beside them.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from featmap.io.atomic import atomic_write_text
from featmap.io.markdown import markdown_table
from featmap.io.run_metrics import RunMetrics
from featmap.outputs.base import OutputConfig, RunProducts

QUALITY = ["count_ratio", "precision", "precision_any", "recall", "redundancy", "offset_cm", "corner_err_cm"]


def comparison_rows(metrics: RunMetrics) -> list[dict]:
    """One row per method: count (Table 1), quality metrics, vertex error sums (Table 2), time (Table 3)."""
    scores = {name: metrics.primary_scores(name) for name in metrics.methods}
    columns = [c for c in QUALITY if any(c in s for s in scores.values())]
    extra = sorted({k for s in scores.values() for k, v in s.items()
                    if k not in QUALITY and k != "count" and not isinstance(v, dict)} - {"observable_walls", "corners_evaluated"})
    labels = sorted({lab for s in scores.values() for lab in (s.get("vertex_error_sum_m") or {})})
    rows = []
    for name, record in metrics.methods.items():
        row = {"method": name, "count": record.count}
        row.update({c: scores[name].get(c) for c in columns + extra})
        for lab in labels:
            row[f"vertex_{lab}_m"] = (scores[name].get("vertex_error_sum_m") or {}).get(lab)
        row["seconds"] = record.seconds
        rows.append(row)
    return rows


def comparison_markdown(metrics: RunMetrics, rows: list[dict]) -> str:
    keys = list(rows[0]) if rows else ["method", "count", "seconds"]
    reference = f" against {metrics.primary} ({metrics.references.get(metrics.primary)})" if metrics.primary else \
        " (no reference to score against)"
    out = [f"# Comparison: {metrics.source.name} ({metrics.scans.processed} scans, {metrics.segments} extracted "
           f"segments){reference}", "", markdown_table(keys, [[row.get(k) for k in keys] for row in rows]), "",
           "count = fused features (Table 1); vertex_*_m = sum of distances from a labelled building vertex to the "
           "nearest endpoints of the fused features on its two walls (Table 2); seconds = fusion time incl. corner "
           "optimisation (Table 3). Metrics as defined in EVALUATION.md."]
    return "\n".join(out) + "\n"


def comparison_csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows([{k: ("" if v is None else v) for k, v in row.items()} for row in rows])
    return buf.getvalue()


def write_comparison(metrics: RunMetrics, folder: str | Path) -> tuple[list[dict], str]:
    """Write ``comparison.csv`` and ``comparison.md`` into ``folder``; returns (rows, markdown)."""
    folder = Path(folder)
    rows = comparison_rows(metrics)
    md = comparison_markdown(metrics, rows)
    atomic_write_text(folder / "comparison.csv", comparison_csv(rows))
    atomic_write_text(folder / "comparison.md", md)
    return rows, md


class Comparison:
    name = "comparison"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return True

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        write_comparison(products.metrics, folder)
        return ["comparison.csv", "comparison.md"]
