// Bundle the demo page into service/demo_assets/: demo.js (src/main.ts, the TypeScript
// client it imports, three.js) and demo-worker.js (src/worker.ts, the solve loop, with
// the client), each one ES module, minified, the same bytes for the same inputs
// (tests/clients/test_demo_bundle.py rebuilds them and compares). The third-party licence
// comments go to <bundle>.LEGAL.txt next to a bundle that has any (three.js's), and that
// bundle ends with a comment that points there.
//
//     node build.mjs [folder]      (default: ../../service/demo_assets)
import { fileURLToPath } from "node:url";
import path from "node:path";

import * as esbuild from "esbuild";

const here = path.dirname(fileURLToPath(import.meta.url));
const outdir = process.argv[2] ?? path.join(here, "..", "..", "service", "demo_assets");

await esbuild.build({
  entryPoints: { demo: path.join(here, "src", "main.ts"), "demo-worker": path.join(here, "src", "worker.ts") },
  outdir,
  bundle: true,
  format: "esm",
  platform: "browser",
  target: ["es2022"],
  minify: process.env.DEMO_MINIFY !== "0", // DEMO_MINIFY=0: readable stack traces while debugging
  // Template literals written as ordinary strings: three.js keeps its GLSL shaders in
  // template literals, whose line breaks minifying keeps (~4,000 lines of shader source
  // in an otherwise one-line bundle). As "...\n..." strings they are the same values,
  // the bundle is all long lines (0.9% larger), and `duplicates` no longer reads
  // three.js's shader chunks, which repeat each other, as this project's code.
  supported: { "template-literal": false },
  legalComments: "linked",
  // The client imports `ws` only where there is no global WebSocket (Node): never here.
  external: ["ws"],
  // The client's source lives in ../typescript: its imports resolve from this package's
  // node_modules, so the demo builds without installing the client's own.
  nodePaths: [path.join(here, "node_modules")],
  logLevel: "warning",
});
