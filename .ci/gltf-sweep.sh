#!/usr/bin/env bash
# Sweep the third-party glTF fixtures with `dermis inspect` and `dermis pose`; fail on any error
# or panic. Usage: .ci/gltf-sweep.sh path/to/dermis [fixtures-dir]
set -u
bin=${1:?usage: $0 path/to/dermis [fixtures-dir]}
root=$(cd "$(dirname "$0")/.." && pwd)
dir=${2:-$root/../shared/fixtures/gltf}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
fail=0
count=0
while IFS= read -r -d '' model; do
    count=$((count + 1))
    name=$(basename "$model")
    if ! "$bin" inspect "$model" --json >"$out/inspect.json" 2>"$out/err"; then
        echo "FAIL inspect $model: $(cat "$out/err")"; fail=1; continue
    fi
    # Every clip at its start, middle and end, or the static scene when there is none.
    clips=$(python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(" ".join("%d:%r" % (c["clip"], c["duration_s"]) for c in d["clips"]))' "$out/inspect.json")
    [ -z "$clips" ] && clips="-:0"
    for c in $clips; do
        idx=${c%%:*}; dur=${c#*:}
        for t in 0 $(python3 -c "print($dur/2, $dur)"); do
            args=(pose "$model" --time "$t" --out "$out/$name.obj")
            [ "$idx" != "-" ] && args+=(--clip "$idx")
            if ! "$bin" "${args[@]}" >/dev/null 2>"$out/err"; then
                echo "FAIL pose $model clip $idx t=$t: $(cat "$out/err")"; fail=1
            elif ! python3 -c 'import sys,math
for l in open(sys.argv[1]):
    if l.startswith(("v ","vn ")) and not all(math.isfinite(float(x)) for x in l.split()[1:]): sys.exit(1)' "$out/$name.obj"; then
                echo "FAIL pose $model clip $idx t=$t: non-finite coordinates"; fail=1
            fi
        done
    done
done < <(find "$dir" \( -name '*.gltf' -o -name '*.glb' \) -print0 | sort -z)
echo "swept $count models"
[ "$count" -gt 0 ] || { echo "no models found under $dir"; exit 1; }
exit $fail
