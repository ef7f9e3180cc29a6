#!/usr/bin/env bash
# The base install (`pip install torchtasks`, no extras) in a fresh venv: the core imports without the
# optional modules, and `torchtasks --help`, `torchtasks list` and `torchtasks demo --quick` run.
# Usage: .ci/check_base_install.sh [PYTHON]   (default: python3; called by .ci/run and `make check-base-install`)
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${1:-python3}"
start=$SECONDS
work="$(mktemp -d -t torchtasks-base-XXXXXX)"
trap 'rm -rf "$work"' EXIT

echo "== base install: fresh venv in $work"
"$PY" -m venv "$work/venv"
bin="$work/venv/bin"
# build from a copy of the checkout's files (tracked and new, not ignored): no stale build/ is reused, none is left
mkdir "$work/src"
git ls-files -z --cached --others --exclude-standard \
    | tar --null --ignore-failed-read -T - -cf - 2>/dev/null | tar -xf - -C "$work/src"
# torch first, pinned (an unpinned torch pulls a multi-GB CUDA build); then the package, no extras, not editable
"$bin/pip" install -q -c constraints.txt torch==2.13.0
"$bin/pip" install -q -c constraints.txt "$work/src"
"$bin/pip" list --format=freeze | grep -iE '^(torch|torchrl|tensordict|numpy|tqdm|torchtasks)==' | tr '\n' ' '
echo

# run from inside the temp folder so that `import torchtasks` is the installed package, not ./src
mkdir -p "$work/cwd"
cd "$work/cwd"

echo "== import torchtasks (core) without the optional modules"
"$bin/python" - <<'PY'
import sys

import torchtasks
import torchtasks.envs
import torchtasks.predefined
import torchtasks.rewards
import torchtasks.spaces
import torchtasks.tasks
import torchtasks.transforms

optional = ("gymnasium", "mujoco", "matplotlib", "ray")
imported = [name for name in optional if sys.modules.get(name) is not None]
assert not imported, f"the core import pulled optional modules: {imported}"
assert "site-packages" in torchtasks.__file__, torchtasks.__file__
print(f"ok: torchtasks {torchtasks.__version__} from {torchtasks.__file__}; none of {', '.join(optional)} imported")

try:
    torchtasks.envs.gymnasium_env
except ModuleNotFoundError as error:
    assert "pip install 'torchtasks[mujoco]'" in str(error), error
    print(f"ok: a MuJoCo preset without the extra: {error}")
else:
    raise AssertionError("torchtasks.envs.gymnasium_env imported without the mujoco extra")
PY

echo "== torchtasks --help"
"$bin/torchtasks" --help > help.txt
head -n 1 help.txt

echo "== package data: every model file of the checkout is installed"
"$bin/python" - "$work/src/src/torchtasks/envs/models" <<'PY'
import pathlib
import sys

import torchtasks

source = pathlib.Path(sys.argv[1])
installed = pathlib.Path(torchtasks.__file__).parent / "envs" / "models"


def files(root: pathlib.Path) -> set[str]:
    return {
        path.relative_to(root).as_posix()
        for path in root.rglob("*")
        if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc"
    }


expected, shipped = files(source), files(installed)
assert {"dm_control/quadruped.xml", "dm_control/common/visual.xml", "dm_control/LICENSE"} <= expected, expected
assert shipped == expected, f"not installed: {sorted(expected - shipped)}; unexpected: {sorted(shipped - expected)}"
for name in sorted(expected):
    assert (installed / name).read_bytes() == (source / name).read_bytes(), name
print(f"ok: {len(shipped)} model files installed (the shipped robots, the DeepMind Control Suite's MJCF files)")
PY

echo "== torchtasks list"
"$bin/torchtasks" list > list.txt
grep -q "gymnasium_env .*\[needs the 'mujoco' extra\]" list.txt
grep -q "HalfCheetah-v5" list.txt
echo "ok: $(grep -c '^  ' list.txt) names listed; the MuJoCo presets marked: $(tail -n 1 list.txt)"

echo "== torchtasks demo --quick --output $work/demo"
"$bin/torchtasks" demo --quick --no-progress --output "$work/demo" > demo.txt
cat demo.txt
test -s "$work/demo/torchtasks_demo.json"
test ! -e "$work/demo/torchtasks_demo.png"  # no matplotlib in the base install
grep -q "pip install 'torchtasks\[plot\]'" demo.txt
leftovers="$(ls -A | grep -vxE 'help.txt|list.txt|demo.txt' || true)"
test -z "$leftovers" || { echo "the demo wrote into the current folder: $leftovers"; exit 1; }

echo "== base install: ok ($((SECONDS - start)) s)"
