#!/usr/bin/env bash
# Exported glb and usda through the Khronos glTF validator and Pixar's USD validators.
set -euo pipefail
cd "$(dirname "$0")/../.."
bash .ci/validate-export.sh 24
# The bundled arm, as the README's main command exports it (glb) and as USD with colliders.
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cargo run --release --quiet -- export assets/arm.glb --out "$out/arm.glb"
cargo run --release --quiet -- export assets/arm.glb --out "$out/arm.usda" --with-colliders
GLTF_VALIDATOR_DIR="${GLTF_VALIDATOR_DIR:-/tmp/dermis-gltf-validator}" node .ci/validate-gltf.mjs "$out/arm.glb"
python3 .ci/validate-usd.py "$out/arm.usda"
# The jaw (muscles and bones through the ECS, skin sleeve), as `dermis anatomy jaw` writes it.
cargo run --release --quiet -- anatomy jaw --frames 12 --out "$out/jaw.glb"
cargo run --release --quiet -- anatomy jaw --frames 12 --out "$out/jaw.usda"
GLTF_VALIDATOR_DIR="${GLTF_VALIDATOR_DIR:-/tmp/dermis-gltf-validator}" node .ci/validate-gltf.mjs "$out/jaw.glb"
python3 .ci/validate-usd.py "$out/jaw.usda"
