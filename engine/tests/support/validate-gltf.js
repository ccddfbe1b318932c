// Validates a GLB with the Khronos glTF validator and prints its report as JSON.
// Usage: node validate-gltf.js FILE.glb   (gltf-validator resolved through NODE_PATH)
const validator = require('gltf-validator');
const fs = require('fs');
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator
  .validateBytes(data, { maxIssues: 100 })
  .then((report) => console.log(JSON.stringify(report)))
  .catch((e) => {
    console.error(String(e));
    process.exit(2);
  });
