// Bundle the demo page (src/main.ts, the TypeScript client it imports, three.js) into
// service/demo_assets/demo.js: one ES module, minified, the same bytes for the same
// inputs (tests/live/test_demo_browser.py rebuilds it and compares). The third-party
// licence comments go to demo.js.LEGAL.txt next to it.
import { fileURLToPath } from "node:url";
import path from "node:path";

import * as esbuild from "esbuild";

const here = path.dirname(fileURLToPath(import.meta.url));
const out = process.argv[2] ?? path.join(here, "..", "..", "service", "demo_assets", "demo.js");

await esbuild.build({
  entryPoints: [path.join(here, "src", "main.ts")],
  outfile: out,
  bundle: true,
  format: "esm",
  platform: "browser",
  target: ["es2022"],
  minify: process.env.DEMO_MINIFY !== "0", // DEMO_MINIFY=0: readable stack traces while debugging
  legalComments: "linked",
  // The client imports `ws` only where there is no global WebSocket (Node): never here.
  external: ["ws"],
  // The client's source lives in ../typescript: its imports resolve from this package's
  // node_modules, so the demo builds without installing the client's own.
  nodePaths: [path.join(here, "node_modules")],
  logLevel: "warning",
});
