// Validate one glTF / GLB file with the Khronos glTF validator and print its report as JSON.
// Usage: node .ci/node/validate.js FILE.glb  (after `npm install --prefix .ci/node`)
// tests/test_orm.py runs it and asserts the report has no errors; exit 2 if it cannot run.
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

const file = process.argv[2];
const bytes = new Uint8Array(fs.readFileSync(file));
validator.validateBytes(bytes, {
  uri: path.basename(file),
  externalResourceFunction: (uri) => new Promise((resolve, reject) => {
    fs.readFile(path.join(path.dirname(file), decodeURIComponent(uri)), (err, data) => {
      if (err) { reject(err.toString()); return; }
      resolve(new Uint8Array(data));
    });
  }),
}).then((report) => {
  process.stdout.write(JSON.stringify(report) + '\n');
}).catch((error) => {
  process.stderr.write(String(error) + '\n');
  process.exit(2);
});
