#!/usr/bin/env bash
# Install (scripts/setup.sh) and run the nightly batch on the bundled sample logs; says how long
# each part took. Options go to `stiction demo` (e.g. --explain on, --out DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$SECONDS
bash scripts/setup.sh
echo "install: $((SECONDS - t0)) s" >&2
. .venv/bin/activate
t1=$SECONDS
rc=0
stiction demo "$@" || rc=$?
echo "diagnosis and reports: $((SECONDS - t1)) s" >&2
exit $rc
