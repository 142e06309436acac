/**
 * MessagePack for the client (`encoding: "msgpack"`), from `@msgpack/msgpack`: importing
 * this module makes it available. `ik-client` imports it; with `ik-client/json`, which
 * leaves it out of a bundle, `import "ik-client/msgpack"` (or a dynamic `import()` of it,
 * loaded only when needed) adds it.
 */

import { decode, encode } from "@msgpack/msgpack";

import { useMessagePack } from "./encode.js";

useMessagePack({
  // A key whose value is undefined is left out, as JSON.stringify leaves it out:
  // MessagePack would write it as nil, which the server refuses for a number
  // (`position_weight: undefined`) where the same message as JSON is answered.
  encode: (value) => encode(value, { ignoreUndefined: true }),
  decode: (data) => decode(data),
});
