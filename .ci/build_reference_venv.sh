#!/usr/bin/env bash
# Builds the dm_control reference venv: python -m venv VENV; pip install -r REQUIREMENTS; then checks that it imports
# dm_control's suite and touches VENV/.installed. On failure (e.g. no network) it removes the partial venv, prints
# one line saying so (pip's output is in a log file it names) and exits 1.
# Usage: .ci/build_reference_venv.sh PYTHON VENV REQUIREMENTS   (called by `make reference-venv` and `make test`)
set -uo pipefail
cd "$(dirname "$0")/.."
PY="$1"
VENV="$2"
REQUIREMENTS="$3"
start=$SECONDS
log="$(mktemp -t torchtasks-reference-venv-XXXXXX.log)"

fail() {
    rm -rf "$VENV"
    echo "dm_control reference venv $VENV NOT built ($1; log: $log): the dm_control reference tests will skip;" \
        "\`make reference-venv\` retries" >&2
    exit 1
}

echo "building the dm_control reference venv $VENV ($(grep -v '^#' "$REQUIREMENTS" | paste -sd ' '))"
rm -rf "$VENV"
"$PY" -m venv "$VENV" >>"$log" 2>&1 || fail "$PY -m venv failed"
"$VENV/bin/pip" install --quiet --disable-pip-version-check --retries 1 --timeout 20 -r "$REQUIREMENTS" >>"$log" 2>&1 \
    || fail "pip install failed: $(grep -E 'ERROR|Error' "$log" | tail -n 1 | cut -c1-160)"
MUJOCO_GL=disable "$VENV/bin/python" -c "import dm_control.suite" >>"$log" 2>&1 \
    || fail "the new venv does not import dm_control.suite: $(tail -n 1 "$log" | cut -c1-160)"
touch "$VENV/.installed"
rm -f "$log"
echo "built the dm_control reference venv $VENV in $((SECONDS - start)) s"
