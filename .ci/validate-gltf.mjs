// Validates glTF/glb files with the Khronos glTF validator; exits 1 if any has an error.
//
// Usage: node .ci/validate-gltf.mjs FILE.glb [FILE...]
// The npm package `gltf-validator` is looked up in $GLTF_VALIDATOR_DIR/node_modules (e.g.
// after `npm install --prefix /tmp/gv gltf-validator`), else next to this script, else in the
// current directory.
import { readFile } from 'node:fs/promises';
import { createRequire } from 'node:module';
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

function loadValidator() {
  const bases = [
    process.env.GLTF_VALIDATOR_DIR,
    dirname(fileURLToPath(import.meta.url)),
    process.cwd(),
  ].filter(Boolean);
  for (const base of bases) {
    try {
      return createRequire(join(resolve(base), 'noop.js'))('gltf-validator');
    } catch {
      // try the next place
    }
  }
  console.error('gltf-validator not found: npm install --prefix DIR gltf-validator and set GLTF_VALIDATOR_DIR=DIR');
  process.exit(2);
}

const files = process.argv.slice(2);
if (files.length === 0) {
  console.error('usage: node .ci/validate-gltf.mjs FILE.glb [FILE...]');
  process.exit(2);
}
const validator = loadValidator();
let failed = false;
for (const file of files) {
  const bytes = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(bytes, {
    uri: file,
    maxIssues: 0,
    externalResourceFunction: (uri) =>
      readFile(join(dirname(file), decodeURIComponent(uri))).then((b) => new Uint8Array(b)),
  });
  const { numErrors, numWarnings, numInfos, numHints } = report.issues;
  console.log(
    `${file}: ${numErrors} errors, ${numWarnings} warnings, ${numInfos} infos, ${numHints} hints` +
      ` (validator ${report.validatorVersion})`,
  );
  for (const m of report.issues.messages) {
    const severity = ['error', 'warning', 'info', 'hint'][m.severity] ?? m.severity;
    if (m.severity <= 1) console.log(`  ${severity} ${m.code} at ${m.pointer ?? ''}: ${m.message}`);
  }
  if (numErrors > 0) failed = true;
}
process.exit(failed ? 1 : 0);
