#!/usr/bin/env bash
# Install (scripts/setup.sh) and run the nightly batch on the bundled sample logs.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. .venv/bin/activate
stiction demo "$@"
