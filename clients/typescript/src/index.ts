/**
 * Typed client of the IK service: `Client` over HTTP, and a session's WebSocket as a
 * `Stream` that numbers frames, pipelines, speaks JSON or MessagePack and reconnects
 * without losing or repeating an answer.
 *
 * ```ts
 * import { Client } from "ik-client";
 * const ik = new Client("http://127.0.0.1:8000");
 * const session = await ik.createSession({ format: "example", name: "panda_arm" });
 * const stream = await ik.stream(session, { encoding: "msgpack" });
 * const result = await stream.frame([{ effector: "tool", position: { x: 0.4, y: 0.1, z: 0.5 },
 *                                      orientation: { w: 0, x: 1, y: 0, z: 0 } }]);
 * ```
 *
 * `ik-client/json` is the same client without MessagePack (a smaller browser bundle).
 */

import "./msgpack.js"; // encoding: "msgpack" (ik-client/json, the same without it)

export * from "./json.js";
