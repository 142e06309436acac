/**
 * Writing what the client sends, for the HTTP `Client` and the `Stream` alike: a
 * non-finite number or a value the encoding cannot write throws an `EncodeError`
 * before anything is sent.
 *
 * MessagePack is not imported here: `msgpack.ts` hands its codec over
 * (`useMessagePack`) when an entry point imports it (`ik-client` does;
 * `ik-client/json` does not, and a bundle of it holds no `@msgpack/msgpack`, which is
 * over half of the whole client's minified size).
 */

import { EncodeError, IKClientError } from "./errors.js";
import type { Encoding } from "./types.js";

/** What the client needs of a MessagePack library (`@msgpack/msgpack`'s `encode`,
 * `decode`). */
export interface MessagePackCodec {
  /** `value` as MessagePack; a key whose value is undefined left out (as JSON leaves it). */
  encode(value: unknown): Uint8Array;
  decode(data: ArrayBuffer | Uint8Array): unknown;
}

let messagePack: MessagePackCodec | null = null;

/** Make `encoding: "msgpack"` available (what `import "ik-client/msgpack"` does). */
export function useMessagePack(codec: MessagePackCodec): void {
  messagePack = codec;
}

/** The MessagePack codec; throws naming the way to get it when no entry point brought it. */
export function messagePackCodec(): MessagePackCodec {
  if (messagePack !== null) return messagePack;
  throw new IKClientError(
    'encoding "msgpack": MessagePack is not loaded, as "ik-client/json" leaves it out; ' +
      'import the client from "ik-client", or import "ik-client/msgpack" once',
  );
}

/** `encoding` checked: one the client speaks, and its codec loaded (throws otherwise,
 * before anything is sent or opened). */
export function checkEncoding(encoding: unknown): Encoding {
  if (encoding === "msgpack") messagePackCodec();
  else if (encoding !== "json") throw new RangeError(`encoding must be "json" or "msgpack", got ${String(encoding)}`);
  return encoding;
}

/**
 * Throw naming the first NaN or infinity in `value` (a body, or its part at `field`):
 * JSON.stringify would send it as null and MessagePack as a float, and the server
 * refuses both; here the caller learns which field. An object met again inside itself
 * (`ancestors`) is left to the encoder, which throws for the cycle.
 */
function refuseNonFinite(value: unknown, field: string, ancestors: Set<object>): void {
  if (typeof value === "number") {
    if (Number.isFinite(value)) return;
    throw new EncodeError(`${field} is ${value}: the service takes finite numbers only`, field);
  }
  if (value === null || typeof value !== "object" || ancestors.has(value)) return;
  ancestors.add(value);
  if (Array.isArray(value)) {
    value.forEach((item, index) => refuseNonFinite(item, `${field}[${index}]`, ancestors));
  } else {
    for (const [key, item] of Object.entries(value)) {
      refuseNonFinite(item, field ? `${field}.${key}` : key, ancestors);
    }
  }
  ancestors.delete(value);
}

/** `body` as JSON text (`json`) or MessagePack bytes (`msgpack`), keys whose value is
 * undefined left out in both; throws an `EncodeError` for a non-finite number (naming
 * its field) or what the encoding cannot write. */
export function encodeBody(body: Record<string, unknown>, encoding: "json"): string;
export function encodeBody(body: Record<string, unknown>, encoding: "json" | "msgpack"): string | Uint8Array;
export function encodeBody(body: Record<string, unknown>, encoding: "json" | "msgpack"): string | Uint8Array {
  refuseNonFinite(body, "", new Set());
  const codec = encoding === "msgpack" ? messagePackCodec() : null;
  try {
    // A key whose value is undefined is left out in both (msgpack.ts says why).
    return codec !== null ? codec.encode(body) : JSON.stringify(body);
  } catch (error) {
    const reason = error instanceof Error ? error.message : String(error);
    throw new EncodeError(`the message cannot be written as ${encoding}: ${reason}`, null, { cause: error });
  }
}
