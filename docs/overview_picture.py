"""Draw the README's picture from one quick study's figures: ``python docs/overview_picture.py OUT.png``.

Runs ``python -m studies arm --quick`` into a temporary folder (the study's own command line, so the
picture shows what a user's run writes) and sets its step responses beside its Monte Carlo envelopes.
The repository's copy is ``docs/_static/overview.png``; nothing is written unless OUT is given.
"""

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402

#: The study's figures, left to right.
FIGURES = ("step.png", "monte_carlo.png")


def draw(folder: Path, out: Path, height_in: float = 5.0, dpi: int = 110) -> None:
    """Set the figures `FIGURES` of the plant folder `folder` side by side at one height (in), to `out`."""
    images = [mpimg.imread(folder / name) for name in FIGURES]
    widths = [image.shape[1] / image.shape[0] for image in images]
    fig, axes = plt.subplots(1, len(images), figsize=(height_in * sum(widths), height_in), width_ratios=widths)
    for ax, image in zip(axes, images):
        ax.imshow(image, interpolation="antialiased")
        ax.set_axis_off()
    fig.subplots_adjust(left=0, right=1, top=1, bottom=0, wspace=0.01)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the PNG to write (the repository's: docs/_static/overview.png)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "studies", "arm", "--quick", "--out", tmp], check=True)
        draw(Path(tmp) / "arm", args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
