/**
 * `ik-client/json` (src/json.ts) leaves MessagePack out: a browser bundle of it (esbuild,
 * as clients/demo/build.mjs bundles) holds no `@msgpack/msgpack`, while `ik-client`'s
 * does; `encoding: "msgpack"` from it throws, naming the fix, until
 * `import "ik-client/msgpack"` has run. This file imports the JSON entry only (node's
 * test runner gives each file its own process, so no other file's import of
 * `ik-client` loads MessagePack here). `npm run sizes` prints the figures README.md
 * quotes.
 */

import assert from "node:assert/strict";
import { after, describe, test } from "node:test";

import { Client, IKClientError } from "../src/json.js";
import { bundleSize } from "./bundle-size.js";
import { serverUrl, stopServer } from "./server.js";

after(stopServer);

const PANDA = { format: "example", name: "panda_arm" } as const;

describe("ik-client/json", () => {
  test("its bundle holds no @msgpack/msgpack; ik-client's does", async () => {
    const json = await bundleSize('export * from "./dist/src/json.js";');
    const full = await bundleSize('export * from "./dist/src/index.js";');
    assert.equal(json.msgpackBytes, 0);
    assert.ok(full.msgpackBytes > 0);
    assert.ok(json.bytes + full.msgpackBytes <= full.bytes + 1024, `${json.bytes} + ${full.msgpackBytes} vs ${full.bytes}`);
  });

  test('encoding "msgpack" throws, naming the fix, until ik-client/msgpack is imported', async () => {
    const client = new Client(await serverUrl());
    const session = await client.createSession(PANDA);
    await assert.rejects(client.stream(session, { encoding: "msgpack" }), (error: unknown) => {
      assert.ok(error instanceof IKClientError);
      assert.match(error.message, /import "ik-client\/msgpack"/);
      return true;
    });
    await assert.rejects(client.stream(session, { encoding: "cbor" as "json" }), RangeError);
    const json = await client.stream(session);
    assert.equal((await json.ping()).type, "pong");
    json.close();
    await import("../src/msgpack.js");
    const msgpack = await client.stream(session, { encoding: "msgpack" });
    assert.equal((await msgpack.ping()).type, "pong");
    msgpack.close();
    await client.deleteSession(session);
  });
});
