#!/usr/bin/python3
"""Draws the paper's evaluation figures from simstack_evaluate JSON files.

    scripts/plot_evaluation.py docs/results/synthetic.json [docs/results/ycb.json ...] --output docs/figures

For every test set: Chamfer distance on the visible (VS) and full (FS) surface against the
visible share of the pile's surface (the paper's Figure 5), IoU and the share of stable piles
against the same bins, one line per method. Files of the same test set (dataset seed, scenes and
views), such as a later run of one more method, are drawn into one figure, named after the
first of them; files without methods (the real-data report) are skipped. The summaries of
simstack_evaluate --summary are enough (the per-view rows are not read).
"""
import argparse
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STYLE = {
    "cvae": ("C0", "C-VAE (ours)"),
    "fc": ("C1", "C-VAE without its code"),
    "fc_plain": ("C3", "FC baseline (paper)"),
    "classical": ("C2", "classical"),
}


def bins_of(method):
    rows = [b for b in method["by_visible_ratio"] if b["views"] > 0]
    centres = [0.5 * (b["visible_from"] + b["visible_to"]) for b in rows]
    return rows, centres


def value(b, key, scale=1.0):
    v = b.get(key)
    return None if v is None else v * scale


def plot_set(paths, sets, out_dir):
    results = sets[0]
    name = os.path.splitext(os.path.basename(paths[0]))[0]
    methods = {}
    for r in sets:
        methods.update(r["methods"])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for method_name, method in methods.items():
        colour, label = STYLE.get(method_name, (None, method_name))
        rows, x = bins_of(method)
        for key, style, suffix in (("chamfer_visible_m", "--", "VS"), ("chamfer_full_m", "-", "FS")):
            axes[0].plot(x, [value(b, key, 1000.0) for b in rows], style, marker="o", color=colour,
                         label=f"{label} {suffix}")
        axes[1].plot(x, [value(b, "iou") for b in rows], marker="o", color=colour, label=label)
        axes[2].plot(x, [value(b, "stable", 100.0) for b in rows], marker="o", color=colour, label=label)
    axes[0].set_ylabel("Chamfer distance (mm)")
    axes[1].set_ylabel("occupancy IoU")
    axes[2].set_ylabel("stable piles (%)")
    for ax in axes:
        ax.set_xlabel("visible share of the pile surface")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    per = results.get("views_per_estimate", 1)
    fig.suptitle(f"{name}: {results['scenes']} scenes x {results['views']} views"
                 + (f" of {per} posed views each" if per > 1 else "")
                 + (" from above" if results.get("overhead", False) else "")
                 + f", dataset seed {results['dataset_seed']}")
    fig.tight_layout()
    out = os.path.join(out_dir, f"{name}.png")
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", nargs="+", help="JSON files written by simstack_evaluate")
    parser.add_argument("--output", default=".", help="directory for the PNG figures")
    args = parser.parse_args()
    try:
        os.makedirs(args.output, exist_ok=True)
    except OSError as e:
        sys.exit(f"plot_evaluation: --output {args.output}: {e}")
    groups = {}  # test set -> (paths, results), in the order given
    for path in args.results:
        try:
            with open(path) as f:
                results = json.load(f)
            if not isinstance(results, dict):
                sys.exit(f"plot_evaluation: {path}: not a simstack_evaluate result (a JSON object)")
            if "methods" not in results:
                print(f"plot_evaluation: {path}: no methods (real-data report?), skipped")
                continue
            # Runs of one test set under one protocol share a figure.
            key = (results["dataset_seed"], results["scenes"], results["views"],
                   results.get("views_per_estimate", 1), results.get("overhead", False))
        except (OSError, KeyError, json.JSONDecodeError) as e:
            sys.exit(f"plot_evaluation: {path}: {e}")
        paths, sets = groups.setdefault(key, ([], []))
        paths.append(path)
        sets.append(results)
    for paths, sets in groups.values():
        try:
            print(plot_set(paths, sets, args.output))
        except KeyError as e:
            sys.exit(f"plot_evaluation: {', '.join(paths)}: missing {e}")


if __name__ == "__main__":
    main()
