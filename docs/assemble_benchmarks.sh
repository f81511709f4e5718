#!/bin/bash
# Rebuild docs/benchmarks.md from the fragments docs/_bench_<area>.md (run from anywhere).
cd "$(dirname "$0")/.."
{
cat <<'HDR'
# Benchmarks

What each benchmark measures, the command that measures it, the machine and its load, the current
figures, and each target with whether it is met. Unless a section says otherwise the machine is the
2-CPU development machine (`Intel(R) Xeon(R) Processor`, AVX-512; the same kind CI uses), shared
with other jobs: each section gives the load average it ran at. Speed targets are judged against a
baseline measured in the same run (a ratio), or on CPU time, because wall times move with the load;
accuracy figures are deterministic (seeded). Current accuracy on fresh seeds and real data is in
[validation.md](validation.md); how figures moved across versions is in [changelog.md](changelog.md).

This page is assembled from the fragments `docs/_bench_<area>.md` (engine, fit, speed, narx,
connectors, service, physics) by `bash docs/assemble_benchmarks.sh`; several benchmark scripts
print their fragment with `--md`.

HDR
for f in engine fit speed narx connectors service physics; do
  if [ -f docs/_bench_$f.md ]; then
    # demote any top-level heading of the fragment to a second-level one
    sed -e 's/^# /## /' docs/_bench_$f.md
    echo
  fi
done
} > docs/benchmarks.md
