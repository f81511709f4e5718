"""Draw the phase plot (OP -> MV) of each stiction class for docs/model.md.

    python docs/figures/make_model_figures.py
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from diagnose.stiction_model import simulate_valve

CASES = [("none", 0.0, 0.0), ("deadband", 4.0, 0.0), ("undershoot", 4.0, 1.5),
         ("no_offset", 4.0, 4.0), ("overshoot", 2.0, 4.0)]


def main() -> None:
    t = np.arange(3000)
    x = 50 + 10 * np.sin(2 * np.pi * t / 1000)
    fig, axes = plt.subplots(1, len(CASES), figsize=(15, 3.2), sharex=True, sharey=True)
    for ax, (name, S, J) in zip(axes, CASES):
        y = simulate_valve(x, S, J, 1)
        k = slice(1000, None)
        ax.plot(x[k], x[k], color="0.8", lw=1, label="ideal valve")
        ax.plot(x[k], y[k], color="C3", lw=1.5, label="sticky valve")
        ax.set_title(f"{name}  S={S:g} J={J:g}")
        ax.set_xlabel("OP (valve input), % span")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("MV (stem position), % span")
    axes[0].legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    out = Path(__file__).with_name("model_classes.png")
    fig.savefig(out, dpi=90)
    print(out)


if __name__ == "__main__":
    main()
