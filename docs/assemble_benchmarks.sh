#!/bin/bash
# Rebuild docs/benchmarks.md from the fragments docs/_bench_<area>.md (run from anywhere).
cd "$(dirname "$0")/.."
{
cat <<'HDR'
# Benchmarks

Every figure below was measured on the 2-core development machine (the same kind CI uses) with the
command shown beside it (one labelled exception in the service section, taken on another host). During this work the machine was shared with other jobs for most of the
runs; each section says its load, and every speed target is compared against a baseline measured
in the same run. Accuracy figures are deterministic (seeded). Targets and whether they are met are
stated in each section and summarised in the closing notes of the issues. Each section below is
assembled from a fragment `docs/_bench_<area>.md` that the benchmark scripts write (`--md`) by
`bash docs/assemble_benchmarks.sh`.

## Stiction model kernel (issue 2)

Measured with the single compiled kernel (issue 24): see "One engine" below
(`python benchmarks/bench_stiction_model.py`: 189 / 328 / 682 M candidate-samples per second on
the baseline / AVX2 / AVX-512 variants, 155-559x the pure-Python loop; targets >= 50 M and >= 50x).

HDR
for f in engine fit speed narx connectors service physics; do
  if [ -f docs/_bench_$f.md ]; then
    # demote any top-level heading of the fragment to a second-level one
    sed -e 's/^# /## /' docs/_bench_$f.md
    echo
  fi
done
} > docs/benchmarks.md
