"""Draws a contact sheet of the procedural categories: one row per category, one render per style.

    python data/category_sheet.py [--categories chair 04379243 mug ...] [--per-category 6]
                                  [--view 3] [--seed 0] [--out docs/procedural_categories.png]

Object j of a row is ``make_shape(category, [seed, j], style=styles[j % len(styles)])``, so a
row shows every style once before it repeats one. Each object is rendered like the dataset, in its
own colours (``svr.data.procedural.generator.render_shape``, at 128 px) from one NMR view (3 by default: azimuth -45
degrees, a three-quarter view of the front). Prints the path of the PNG.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional, Sequence

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from sdfcommon.tooling.checks import check_int  # noqa: E402
from sdfcommon.tooling.outputs import atomic_write  # noqa: E402
from svr.data.procedural.categories import NMR_PROCEDURAL_CATEGORIES, make_shape, procedural_category  # noqa: E402
from svr.data.procedural.appearance import colour_rng, draw_colours  # noqa: E402
from svr.data.procedural.generator import render_shape  # noqa: E402

DEFAULT_OUT = REPO / "docs" / "procedural_categories.png"
IMAGE_SIZE = 128


def category_sheet(out: str | Path = DEFAULT_OUT, categories: Optional[Sequence[str]] = None, per_category: int = 6,
                   view: int = 3, seed: int = 0) -> Path:
    """Renders the sheet and writes it atomically as a PNG.

    Args:
        out: the PNG's path (its folder is created).
        categories: names or ids (default: the 13 NMR categories, in their order).
        per_category: objects per row, cycling through the category's styles.
        view: NMR view index (0..23; view 0 looks from -z at the front).
        seed: the first element of every object's seed.
    Returns:
        the path written.
    """
    import matplotlib  # heavy: only the sheet needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: as above

    check_int(per_category, "per_category", minimum=1)
    check_int(view, "view", 0, 23)
    cats = [procedural_category(c) for c in categories] if categories else list(NMR_PROCEDURAL_CATEGORIES)
    if not cats:
        raise ValueError("categories must name at least one category")
    fig, axes = plt.subplots(len(cats), per_category, figsize=(1.55 * per_category + 0.6, 1.65 * len(cats)),
                             squeeze=False)
    for row, cat in zip(axes, cats):
        for j, ax in enumerate(row):
            style = cat.styles[j % len(cat.styles)]
            shape = make_shape(cat.category_id, [seed, j], style=style)
            colours = draw_colours(colour_rng([seed, j, int(cat.category_id)]), shape.parts)
            rgba = render_shape(shape, colours, image_size=IMAGE_SIZE, num_views=view + 1)[view]
            ax.imshow(rgba[:3].transpose(1, 2, 0))
            ax.set_title(style, fontsize=8, pad=2)
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_visible(False)
        row[0].set_ylabel(f"{cat.name}\n{cat.category_id}", fontsize=9)
    fig.tight_layout(pad=0.3, h_pad=0.4, w_pad=0.2)
    try:
        return atomic_write(out, lambda f: fig.savefig(f, format="png", dpi=100))
    finally:
        plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--categories", nargs="*", default=None,
                        help=f"names or ids (default: {[c.name for c in NMR_PROCEDURAL_CATEGORIES]})")
    parser.add_argument("--per-category", type=int, default=6, help="objects per row")
    parser.add_argument("--view", type=int, default=3, help="NMR view index, 0..23")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(DEFAULT_OUT))
    args = parser.parse_args(argv)
    try:
        path = category_sheet(args.out, args.categories, args.per_category, args.view, args.seed)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
