#!/usr/bin/env bash
# Creates ./.venv on first use (and again when pyproject.toml changes): torch==2.13.0 first (CPU
# build from the local wheel cache), then PhysDrape in editable mode with its dev extras.
# Idempotent; sourced by scripts/physdrape and scripts/test.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
stamp="$venv/.physdrape-stamp"
want="$(sha256sum "$root/pyproject.toml" | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "[physdrape] setting up $venv (first run only; about a minute)" >&2
  python3 -m venv "$venv"
  "$venv/bin/python" -m pip install -q --upgrade pip >&2
  "$venv/bin/python" -m pip install -q "torch==2.13.0" >&2
  "$venv/bin/python" -m pip install -q -e "$root[dev]" >&2
  echo "$want" > "$stamp"
fi
