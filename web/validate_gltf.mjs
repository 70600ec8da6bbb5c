// Validate glTF/GLB files with the Khronos glTF validator; prints one JSON report per file:
// {"file", "errors", "warnings", "messages": [{code, severity, message, pointer}]}.
// Usage: node web/validate_gltf.mjs FILE...
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";

const require = createRequire(import.meta.url);
const validator = require("gltf-validator");
const SEVERITY = ["error", "warning", "info", "hint"];

const reports = [];
for (const file of process.argv.slice(2)) {
  const data = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(data, { maxIssues: 100 });
  reports.push({
    file,
    errors: report.issues.numErrors,
    warnings: report.issues.numWarnings,
    messages: report.issues.messages.map((m) => ({
      code: m.code,
      severity: SEVERITY[m.severity] ?? m.severity,
      message: m.message,
      pointer: m.pointer,
    })),
  });
}
process.stdout.write(JSON.stringify(reports) + "\n");
