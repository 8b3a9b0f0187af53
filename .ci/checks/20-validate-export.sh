#!/usr/bin/env bash
# Exported glb and usda through the Khronos glTF validator and Pixar's USD validators.
set -euo pipefail
cd "$(dirname "$0")/../.."
bash .ci/validate-export.sh 24
