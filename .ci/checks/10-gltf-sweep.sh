#!/usr/bin/env bash
# Third-party rigged glTF models (../shared/fixtures/gltf) through `dermis inspect` and `pose`.
set -euo pipefail
cd "$(dirname "$0")/../.."
if [ ! -d ../shared/fixtures/gltf ]; then
  echo "no ../shared/fixtures/gltf here: sweep skipped"
  exit 0
fi
cargo build --release --quiet
bash .ci/gltf-sweep.sh target/release/dermis ../shared/fixtures/gltf
