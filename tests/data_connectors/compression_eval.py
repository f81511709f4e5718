"""How often `diagnose.quality.assess` flags compression: compressed vs raw records.

    python tests/data_connectors/compression_eval.py [/path/to/shared/data]

Compressed: a clean sine (OP 50 +- 20 %, period 300 samples) and simulated loops (healthy and
sticky, noise 0.05, load walk 0.05, 3000 samples, seeds 0-5) with OP run through our
swinging-door compressor at 0.25-2 % of span and interpolated back (or box-car at 1 %, held), then written and read as a
CSV with 6 significant digits. Raw: the same simulated records uncompressed, and every real
record in the shared data folder. Prints a markdown table.
"""

from __future__ import annotations

import glob
import io
import sys
from pathlib import Path

import numpy as np

from connectors import read_records
from connectors.historian import format_wide
from diagnose.quality import boxcar, decompress, swinging_door
from diagnose.record import LoopRecord
from diagnose.simulate import sticky_loop


def flagged(rec) -> bool:
    (back,) = read_records(io.StringIO(format_wide(rec)))[:1]
    return any(f.code == "compression" for f in back.findings)


def main() -> None:
    data = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[3] / "shared/data"
    t = np.arange(3000.0)
    sine = LoopRecord("SINE", 1.0, 50 + 20 * np.sin(2 * np.pi * t / 300), 10 + 4 * np.sin(2 * np.pi * (t - 20) / 300))
    sims = {f"S={S:g}": [sticky_loop(S, S / 2, n=3000, seed=s, noise_std=0.05, load_walk_std=0.05) for s in range(6)]
            for S in (0.0, 2.0, 4.0)}
    print("| record | raw | SDT 0.25 % | SDT 0.5 % | SDT 1 % | SDT 2 % | box-car 1 % (stepped) |")
    print("|---|---|---|---|---|---|---|")
    devs = (0.25, 0.5, 1.0, 2.0)
    for name, recs in [("clean sine", [sine])] + [(f"simulated loop {k}", v) for k, v in sims.items()]:
        raw = sum(flagged(r) for r in recs)
        cells = []
        for d in devs:
            n = sum(flagged(r.replace(op=decompress(r.t_s, r.op, swinging_door(r.t_s, r.op, d)))) for r in recs)
            cells.append(f"{n}/{len(recs)}")
        n = sum(flagged(r.replace(op=decompress(r.t_s, r.op, boxcar(r.op, 1.0), kind="step"))) for r in recs)
        cells.append(f"{n}/{len(recs)}")
        print(f"| {name} | {raw}/{len(recs)} | " + " | ".join(cells) + " |")
    files = sorted(glob.glob(str(data / "plant-dcs-stictiongpt/raw/*.txt")) + glob.glob(str(data / "isdb-subset/[A-Z]*.csv"))
                   + glob.glob(str(data / "damadics-lublin/*.csv")) + glob.glob(str(data / "tennessee-eastman/d*.csv")))
    n_flag = 0
    names = []
    for f in files:
        recs = read_records(f)
        if any(x.code == "compression" for r in recs for x in r.findings):
            n_flag += 1
            names.append(Path(f).name)
    for f in sorted(glob.glob(str(data / "historian-exports/*.csv"))):
        op, pv = ("FV_211", "FT_211") if "FIC" in f else ("LV_106", "FT_115")
        recs = read_records(f, op=op, pv=pv)
        files.append(f)
        if any(x.code == "compression" for r in recs for x in r.findings):
            n_flag += 1
            names.append(Path(f).name)
    print(f"\nreal records flagged as compressed: {n_flag} of {len(files)} {names}")


if __name__ == "__main__":
    main()
