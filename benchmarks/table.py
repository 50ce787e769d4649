"""Printing and saving the benchmarks' tables (rows of dicts)."""

import csv


def markdown(rows, keys=None, missing="-"):
    """The lines of rows as a markdown table (floats to 3 significant digits); keys
    default to every key in order of first appearance."""
    keys = keys or list(dict.fromkeys(k for r in rows for k in r))
    return [" | ".join(keys), " | ".join("---" for _ in keys)] + [
        " | ".join(f"{r[k]:.3g}" if isinstance(r.get(k), float) else str(r.get(k, missing))
                   for k in keys) for r in rows]


def report(rows, keys=None, csv_path=None, missing="-"):
    """Print rows as a markdown table (markdown()); optionally save a CSV."""
    keys = keys or list(dict.fromkeys(k for r in rows for k in r))
    print("\n".join(markdown(rows, keys, missing)))
    if csv_path:
        with open(csv_path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=keys, restval="")
            w.writeheader()
            w.writerows(rows)
