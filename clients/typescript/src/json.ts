/**
 * The client without MessagePack: `ik-client/json`. The same `Client`, `Stream`, errors
 * and types as `ik-client`, for a page or game that speaks JSON only and should not ship
 * `@msgpack/msgpack` (measured in README.md, "Bundlers"). `encoding: "msgpack"` throws
 * here until `import "ik-client/msgpack"` has run.
 *
 * ```ts
 * import { Client } from "ik-client/json";
 * ```
 */

export type * from "./chains.js"; // types only: nothing in a bundle
export * from "./client.js";
export * from "./errors.js";
export { DEFAULT_MAX_QUEUED } from "./queued.js";
export * from "./reconnect.js";
export * from "./stream.js";
export * from "./types.js";
