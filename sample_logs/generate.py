"""Regenerate the simulated sample logs (seeded; the files in this folder came from this script).

    python sample_logs/generate.py
"""

from __future__ import annotations

from pathlib import Path

from connectors.historian import write_wide
from diagnose.simulate import sticky_loop

HERE = Path(__file__).resolve().parent

# name, S %, J %, process kind, gain, tau_s, delay_s, seed
LOOPS = [
    ("FIC101", 0.0, 0.0, "foptd", 1.2, 25.0, 3.0, 11),      # healthy valve
    ("FIC102", 4.0, 0.0, "foptd", 1.0, 20.0, 3.0, 12),      # deadband
    ("FIC103", 5.0, 2.0, "foptd", 0.8, 30.0, 4.0, 13),      # undershoot
    ("PIC104", 3.0, 3.0, "soptd", 1.5, 40.0, 5.0, 14),      # no offset
    ("TIC105", 2.0, 4.0, "foptd", 2.0, 60.0, 6.0, 15),      # overshoot
    ("LIC106", 3.0, 1.0, "integrating", 0.02, 5.0, 3.0, 16),  # undershoot on a level loop
]


def main() -> None:
    for name, S, J, kind, gain, tau, delay, seed in LOOPS:
        rec = sticky_loop(S, J, n=3000, ts_s=1.0, gain=gain, tau_s=tau, delay_s=delay, kind=kind,
                          noise_std=0.03, load_walk_std=0.02, seed=seed, name=name)
        write_wide(rec, HERE / f"{name}.csv")
        print(f"{name}.csv  S={S} J={J} {kind}")


if __name__ == "__main__":
    main()
