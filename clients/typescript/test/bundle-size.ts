/**
 * How much of a browser bundle the client takes: `entry` (module source, resolved from
 * the package's root, e.g. `export * from "./dist/src/json.js";`) bundled as
 * clients/demo/build.mjs bundles (esbuild, ES module for browsers, ES2022, minified, `ws`
 * external), measured in memory.
 *
 *     node dist/test/bundle-size.js      (npm run sizes: the table in README.md)
 */

import { fileURLToPath } from "node:url";
import { gzipSync } from "node:zlib";

import * as esbuild from "esbuild";

const PACKAGE_ROOT = fileURLToPath(new URL("../../", import.meta.url)); // from dist/test/

export interface BundleSize {
  bytes: number;
  gzipBytes: number;
  /** What of it is `@msgpack/msgpack`'s code. */
  msgpackBytes: number;
}

export async function bundleSize(entry: string): Promise<BundleSize> {
  const built = await esbuild.build({
    stdin: { contents: entry, resolveDir: PACKAGE_ROOT, loader: "js" },
    bundle: true,
    format: "esm",
    platform: "browser",
    target: ["es2022"],
    minify: true,
    external: ["ws"],
    write: false,
    metafile: true,
    logLevel: "warning",
  });
  const code = built.outputFiles[0]!.contents;
  const inputs = Object.values(built.metafile.outputs)[0]!.inputs;
  const msgpackBytes = Object.entries(inputs)
    .filter(([path]) => path.includes("@msgpack/msgpack"))
    .reduce((sum, [, input]) => sum + input.bytesInOutput, 0);
  return { bytes: code.length, gzipBytes: gzipSync(code).length, msgpackBytes };
}

const MEASURED: Record<string, string> = {
  "everything, ik-client": 'export * from "./dist/src/index.js";',
  "everything, ik-client/json": 'export * from "./dist/src/json.js";',
  "Client, ik-client": 'export { Client } from "./dist/src/index.js";',
  "Client, ik-client/json": 'export { Client } from "./dist/src/json.js";',
  "the errors alone": 'export { ServiceError, StreamClosed } from "./dist/src/errors.js";',
};

if (process.argv[1] === fileURLToPath(import.meta.url)) {
  console.log("| bundle | minified | gzipped | of it @msgpack/msgpack |\n|---|---|---|---|");
  for (const [name, entry] of Object.entries(MEASURED)) {
    const size = await bundleSize(entry);
    console.log(`| ${name} | ${size.bytes} B | ${size.gzipBytes} B | ${size.msgpackBytes} B |`);
  }
}
