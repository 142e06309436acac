/**
 * Writing what the client sends, for the HTTP `Client` and the `Stream` alike: a
 * non-finite number or a value the encoding cannot write throws an `EncodeError`
 * before anything is sent.
 */

import { encode } from "@msgpack/msgpack";

import { EncodeError } from "./errors.js";

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
  try {
    // A key whose value is undefined is left out, as JSON.stringify leaves it out:
    // MessagePack would write it as nil, which the server refuses for a number
    // (`position_weight: undefined`) where the same message as JSON is answered.
    return encoding === "msgpack" ? encode(body, { ignoreUndefined: true }) : JSON.stringify(body);
  } catch (error) {
    const reason = error instanceof Error ? error.message : String(error);
    throw new EncodeError(`the message cannot be written as ${encoding}: ${reason}`, null, { cause: error });
  }
}
