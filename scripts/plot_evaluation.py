#!/usr/bin/python3
"""Draws the paper's evaluation figures from simstack_evaluate JSON files.

    scripts/plot_evaluation.py docs/results/synthetic.json [docs/results/ycb.json ...] --output docs/figures

For every test set: Chamfer distance on the visible (VS) and full (FS) surface against the
visible share of the pile's surface (the paper's Figure 5), IoU and the share of stable piles
against the same bins, one line per method. Files of one test set under one protocol (dataset
seed, scenes, views, posed views per estimate, overhead camera, noise, sensor, image and its
intrinsics, view seed, Chamfer samples and seen pixels), such as a later run of one more method, are drawn into one figure, named after the first of them; a
method name met twice in a figure is told apart by its file's name. Files that are not
simstack_evaluate results on rendered views (a --real report, a simstack_evaluate_grasps file)
are skipped with a note. The summaries of simstack_evaluate --summary are enough (the per-view
rows are not read).
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


def methods_of(paths, sets):
    """The methods of a figure's files, in order; a name met again gets its file's name."""
    methods = {}
    for path, r in zip(paths, sets):
        stem = os.path.splitext(os.path.basename(path))[0]
        for name, method in r["methods"].items():
            shown, k = name, 1
            while shown in methods:  # met before: named by its file, then numbered
                shown = f"{name} ({stem})" if k == 1 else f"{name} ({stem} {k})"
                k += 1
            if shown != name:
                print(f"plot_evaluation: {path}: {name} is also in an earlier file; drawn as '{shown}'")
            methods[shown] = method
    return methods


def colours_of(names):
    """The fixed colour of each known method; the others take colours no method uses."""
    taken = {colour for colour, _ in STYLE.values()}
    free = [f"C{i}" for i in range(10) if f"C{i}" not in taken]
    free += ["black", "olive", "teal", "navy", "maroon"]
    others = [name for name in names if name not in STYLE]
    out = {name: free[k % len(free)] for k, name in enumerate(others)}
    out.update({name: STYLE[name][0] for name in names if name in STYLE})
    return out


def plot_set(paths, sets, out_dir, name):
    results = sets[0]
    methods = methods_of(paths, sets)
    colours = colours_of(list(methods))
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for method_name, method in methods.items():
        colour = colours[method_name]
        base = method_name.split(" (")[0]
        label = STYLE[base][1] + method_name[len(base):] if base in STYLE else method_name
        rows, x = bins_of(method)
        for key, style, suffix in (("chamfer_visible_m", "--", "VS"), ("chamfer_full_m", "-", "FS")):
            axes[0].plot(x, [value(b, key, 1000.0) for b in rows], style, marker="o", color=colour,
                         label=f"{label} {suffix}")
        axes[1].plot(x, [value(b, "iou") for b in rows], marker="o", color=colour, label=label)
        stable = [value(b, "stable", 100.0) for b in rows]
        if any(v is not None for v in stable):  # runs with --no-stability have none
            axes[2].plot(x, stable, marker="o", color=colour, label=label)
    if not axes[2].lines:
        axes[2].text(0.5, 0.5, "no stability test in these runs", ha="center", va="center",
                     transform=axes[2].transAxes)
    axes[0].set_ylabel("Chamfer distance (mm)")
    axes[1].set_ylabel("occupancy IoU")
    axes[2].set_ylabel("stable piles (%)")
    for ax in axes:
        ax.set_xlabel("visible share of the pile surface")
        ax.grid(alpha=0.3)
        if ax.lines:
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
            if "real_dir" in results:
                print(f"plot_evaluation: {path}: a --real report (no rendered views to bin), skipped")
                continue
            methods = results.get("methods")
            if not isinstance(methods, dict) or not methods or not all(
                    isinstance(m, dict) and "by_visible_ratio" in m for m in methods.values()):
                print(f"plot_evaluation: {path}: not a simstack_evaluate result on rendered views, skipped")
                continue
            # Runs of one test set under one protocol share a figure.
            key = (results["dataset_seed"], results["scenes"], results["views"],
                   results.get("views_per_estimate", 1), results.get("overhead", False),
                   results.get("noise"), results.get("sensor"), results.get("image"),
                   json.dumps(results.get("intrinsics")), results.get("seed"),
                   results.get("chamfer_points"), results.get("seen_pixels"))
        except (OSError, KeyError, ValueError) as e:  # ValueError: not JSON, not even text
            sys.exit(f"plot_evaluation: {path}: {e}")
        paths, sets = groups.setdefault(key, ([], []))
        paths.append(path)
        sets.append(results)
    if not groups:
        sys.exit("plot_evaluation: no simstack_evaluate result on rendered views among the files given: "
                 "nothing drawn")
    names = set()
    for paths, sets in groups.values():
        # Named after the first file; two test sets whose files share a name (runs/a/synthetic.json,
        # runs/b/synthetic.json) are told apart by a number, not drawn over each other.
        stem = os.path.splitext(os.path.basename(paths[0]))[0]
        name, k = stem, 2
        while name in names:
            name, k = f"{stem}_{k}", k + 1
        if name != stem:
            print(f"plot_evaluation: {paths[0]}: another test set's figure is {stem}.png; "
                  f"this one is {name}.png")
        names.add(name)
        try:
            print(plot_set(paths, sets, args.output, name))
        except KeyError as e:
            sys.exit(f"plot_evaluation: {', '.join(paths)}: missing {e}")
        except (TypeError, ValueError, AttributeError) as e:
            sys.exit(f"plot_evaluation: {', '.join(paths)}: a value of the wrong kind ({e})")


if __name__ == "__main__":
    main()
