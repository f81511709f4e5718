#!/bin/bash
# Rebuild docs/benchmarks.md from the fragments docs/_bench_<area>.md (run from anywhere).
cd "$(dirname "$0")/.."
{
cat <<'HDR'
# Benchmarks

What each benchmark measures, the command that measures it, the machine and its load, the current
figures, and each target with whether it is met. Unless a section says otherwise the machine is the
2-CPU development machine (`Intel(R) Xeon(R) Processor`, AVX-512; the same kind CI uses), shared
with other jobs: each section gives the load average it ran at and when the figures were recorded.
Wall times move with the load, so a comparison of speeds is always measured in one run, and an
absolute speed target is judged with the load it was measured at; accuracy figures are
deterministic (seeded). Current accuracy on fresh seeds and real data is in
[validation.md](validation.md); how figures moved across versions, and what each change did to
them against the tree before it, is in [changelog.md](changelog.md).

This page is assembled from the fragments `docs/_bench_<area>.md` (engine, fit, speed, narx,
connectors, service, physics) by `bash docs/assemble_benchmarks.sh`. The benchmark scripts print
their tables; `--md`/`--out` write them to a file, replacing it, so write elsewhere and merge the
figures into the fragment by hand.

HDR
for f in engine fit speed narx connectors service physics; do
  if [ -f docs/_bench_$f.md ]; then
    # demote any top-level heading of the fragment to a second-level one
    sed -e 's/^# /## /' docs/_bench_$f.md
    echo
  fi
done
} > docs/benchmarks.md
