#!/usr/bin/env bash
# Exports the synthetic sample clip (examples/export_sample.rs) as glb and usda and validates
# them with the Khronos glTF validator and Pixar's USD validators; exits non-zero on any error.
# Installs pinned gltf-validator (npm, into $GLTF_VALIDATOR_DIR, default /tmp/dermis-gltf-validator)
# and usd-core (pip) when missing. Usage: bash .ci/validate-export.sh [FRAMES]
set -euo pipefail
cd "$(dirname "$0")/.."
frames="${1:-48}"
gv_dir="${GLTF_VALIDATOR_DIR:-/tmp/dermis-gltf-validator}"
if [ ! -d "$gv_dir/node_modules/gltf-validator" ]; then
  mkdir -p "$gv_dir"
  npm install --silent --no-audit --no-fund --prefix "$gv_dir" gltf-validator@2.0.0-dev.3.10
fi
if ! python3 -c "import pxr.UsdValidation" 2>/dev/null; then
  python3 -m pip install --quiet usd-core==26.11
fi
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
cargo run --quiet --example export_sample -- "$out" "$frames"
GLTF_VALIDATOR_DIR="$gv_dir" node .ci/validate-gltf.mjs "$out/arm.glb" "$out/arm_plain.glb"
python3 .ci/validate-usd.py "$out/arm.usda" "$out/arm_plain.usda"
