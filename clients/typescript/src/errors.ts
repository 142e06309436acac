/**
 * Errors the service reports, as exceptions: one class per kind of reaction.
 *
 * `ServiceError` is an HTTP error body `{detail, code, field}` or a WebSocket error answer
 * `{code, message, field, retry_after_s}`; its subclass says what a caller can do (fix the
 * request, the token, make a new session, wait). A WebSocket that closes for good rejects
 * with a `StreamClosed` subclass chosen by the close code, whose `meaning` is the server's
 * (service/errors.py, WS_CLOSE_CODES).
 */

/** The service's stable error codes (docs/api.md and docs/websocket.md, Errors). */
export const ErrorCode = {
  InvalidFormat: "invalid_format",
  InvalidProblem: "invalid_problem",
  IdReuse: "id_reuse",
  Unauthorized: "unauthorized",
  Forbidden: "forbidden",
  ForbiddenOrigin: "forbidden_origin",
  NotFound: "not_found",
  MethodNotAllowed: "method_not_allowed",
  HttpError: "http_error",
  PayloadTooLarge: "payload_too_large",
  TooManySessions: "too_many_sessions",
  KeySessionLimit: "key_session_limit",
  RateLimited: "rate_limited",
  NotReady: "not_ready",
  WarmupFailed: "warmup_failed",
  PlansBusy: "plans_busy",
  TooManyPlans: "too_many_plans",
  ServerBusy: "server_busy",
  TooMuchWork: "too_much_work",
  // Close reasons (a WebSocket close's reason is its error code).
  TooManyWebSockets: "too_many_websockets",
  SlowReader: "slow_reader",
  ShuttingDown: "shutting_down",
  StoreUnavailable: "store_unavailable",
  InternalError: "internal_error",
} as const;
export type ErrorCode = (typeof ErrorCode)[keyof typeof ErrorCode];
const ERROR_CODES: ReadonlySet<string> = new Set(Object.values(ErrorCode));

/** The close codes of the service's WebSocket (docs/websocket.md, Close codes). */
export const CloseCode = {
  Normal: 1000,
  Abnormal: 1006, // no close frame: the connection dropped (never sent by the server)
  SlowReader: 1008,
  MessageTooBig: 1009,
  InternalError: 1011,
  ServiceRestart: 1012,
  TryAgainLater: 1013,
  Unauthorized: 4401,
  Forbidden: 4403,
  NotFound: 4404,
} as const;
export type CloseCode = (typeof CloseCode)[keyof typeof CloseCode];

/** The server's explanations (service/errors.py, WS_CLOSE_CODES), plus 1006. */
export const CLOSE_CODE_MEANINGS: Readonly<Record<number, string>> = {
  1000: "normal closure",
  1006: "the connection dropped without a close frame",
  1008: "the client did not read its answers (IK_WS_SEND_TIMEOUT_S), or the handshake's query was invalid",
  1009: "message larger than IK_WS_MAX_MESSAGE_BYTES",
  1011: "unexpected server error (logged)",
  1012: "the server is shutting down; reconnect",
  1013: "too many open WebSockets, or the session store did not answer; retry later",
  4401: "no token (Authorization: Bearer, the ik.token subprotocol or ?token=)",
  4403: "wrong token for this session, or a browser Origin not allowed",
  4404: "no such session (never existed, expired or deleted)",
};

/** Base of every error this client raises. */
export class IKClientError extends Error {
  override name = "IKClientError";
}

/** An HTTP call that got no answer (ik_client's `NoAnswer`): the connection failed or
 * dropped (after the resends `reconnect` allows, for a call that is safe to send again),
 * or `timeoutMs` passed (`timedOut`; not sent again: the server may still be working on
 * it). The platform's error (fetch's `TypeError`, the timeout's `DOMException`) is the
 * `cause`. */
export class NoAnswer extends IKClientError {
  override name = "NoAnswer";

  constructor(
    message: string,
    readonly timedOut: boolean,
    options?: { cause?: unknown },
  ) {
    super(message, options);
  }
}

/** A request or stream message this client cannot write, thrown before anything is
 * sent (ik_client's `EncodeError`): a non-finite number (`field` names it, e.g.
 * `targets[0].position.x`; JSON would send it as null, and the server refuses it), or
 * a value the encoding cannot write (a BigInt, a cycle; `field` null, the encoder's
 * error as `cause`). */
export class EncodeError extends IKClientError {
  override name = "EncodeError";

  constructor(
    message: string,
    readonly field: string | null = null,
    options?: { cause?: unknown },
  ) {
    super(message, options);
  }
}

/** A stream message dropped before it went out (ik_client's `MessageDropped`): it was
 * sent while the stream was reconnecting, more than `maxQueued` (`StreamOptions`) such
 * messages waited for the new connection, and it was the oldest of them. The server
 * never saw it. `id` is the id `send*` returned for it. */
export class MessageDropped extends IKClientError {
  override name = "MessageDropped";

  constructor(
    readonly id: number,
    readonly maxQueued: number,
  ) {
    super(
      `message ${id} was dropped unsent: more than ${maxQueued} messages waited for the ` +
        "stream to reconnect, and it was the oldest",
    );
  }
}

/** A stream's answer that this client cannot read (ik_client's `UnexpectedAnswer`): one
 * of a type it does not know, which rejects the message it answers (`id`: that
 * message's id; it counts as answered), or an answer to an id that nothing waits for
 * (`id` null: nothing is taken off the messages in flight), which the stream hands to
 * its `onUnexpected` option, as it does an answer it cannot decode (not JSON or
 * MessagePack, or not an object; `data` holds it as received). `envelope` is the answer
 * as decoded. */
export class UnexpectedAnswer extends IKClientError {
  override name = "UnexpectedAnswer";

  constructor(
    message: string,
    readonly id: number | null,
    readonly envelope: Readonly<Record<string, unknown>>,
    /** The answer as received (text or bytes) when it could not be decoded to an object
     * (`envelope` is then empty); undefined otherwise. */
    readonly data?: unknown,
  ) {
    super(message);
  }
}

export interface ServiceErrorInit {
  field?: string | null | undefined;
  retryAfterS?: number | null | undefined;
  /** The HTTP status (undefined for a WebSocket answer). */
  status?: number | undefined;
  /** The stream message id the error answers (undefined over HTTP). */
  id?: number | undefined;
  /** The HTTP body's `detail` as sent (a list for `invalid_format`). */
  detail?: unknown;
}

/** An error the service answered with: `code`, `field`, `retryAfterS`. Its subclass says
 * what a caller can do about it, and lists the `codes` it stands for. */
export class ServiceError extends IKClientError {
  override name = "ServiceError";
  static readonly codes: readonly ErrorCode[] = [];
  readonly field: string | null;
  readonly retryAfterS: number | null;
  readonly status: number | undefined;
  readonly id: number | undefined;
  readonly detail: unknown;

  constructor(
    readonly code: ErrorCode | string,
    readonly serverMessage: string,
    init: ServiceErrorInit = {},
  ) {
    super(`${code}: ${serverMessage}`);
    this.field = init.field ?? null;
    this.retryAfterS = init.retryAfterS ?? null;
    this.status = init.status;
    this.id = init.id;
    this.detail = init.detail;
  }
}

/** The request is wrong; `field` says where. */
export class InvalidRequest extends ServiceError {
  override name = "InvalidRequest";
  static override readonly codes: readonly ErrorCode[] = [
    ErrorCode.InvalidFormat,
    ErrorCode.InvalidProblem,
    ErrorCode.IdReuse,
    ErrorCode.PayloadTooLarge,
    ErrorCode.MethodNotAllowed,
    ErrorCode.HttpError,
  ];
}
/** No or wrong token or API key, or a browser origin not allowed. */
export class AuthError extends ServiceError {
  override name = "AuthError";
  static override readonly codes: readonly ErrorCode[] = [
    ErrorCode.Unauthorized,
    ErrorCode.Forbidden,
    ErrorCode.ForbiddenOrigin,
  ];
}
/** The session never existed, expired or was deleted. */
export class NotFound extends ServiceError {
  override name = "NotFound";
  static override readonly codes: readonly ErrorCode[] = [ErrorCode.NotFound];
}
/** Wait, and try again (after `retryAfterS` when given). */
export class RetryLater extends ServiceError {
  override name = "RetryLater";
  static override readonly codes: readonly ErrorCode[] = [
    ErrorCode.TooManySessions,
    ErrorCode.KeySessionLimit,
    ErrorCode.RateLimited,
    ErrorCode.NotReady,
    ErrorCode.WarmupFailed,
    ErrorCode.PlansBusy,
    ErrorCode.TooManyPlans,
    ErrorCode.ServerBusy,
    ErrorCode.TooMuchWork,
    ErrorCode.TooManyWebSockets,
    ErrorCode.ShuttingDown,
    ErrorCode.StoreUnavailable,
  ];
}
/** The server failed, or it sent a code this client does not know. */
export class ServerFault extends ServiceError {
  override name = "ServerFault";
  static override readonly codes: readonly ErrorCode[] = [ErrorCode.InternalError, ErrorCode.SlowReader];
}

const ERROR_CLASSES = new Map<string, typeof ServiceError>(
  [InvalidRequest, AuthError, NotFound, RetryLater, ServerFault].flatMap((Class) =>
    Class.codes.map((code) => [code, Class] as const),
  ),
);

/** The `ServiceError` subclass for `code`. */
export function serviceError(code: string, message: string, init: ServiceErrorInit = {}): ServiceError {
  const Class = ERROR_CLASSES.get(code) ?? ServerFault;
  return new Class(code, message, init);
}

/** The WebSocket closed and the stream cannot go on; `reason` is the server's error code.
 * Its subclasses list the `closeCodes` they stand for. */
export class StreamClosed extends IKClientError {
  override name = "StreamClosed";
  static readonly closeCodes: readonly CloseCode[] = [];
  readonly meaning: string;
  /** The server's close reason when it is an error code (`not_found`, `forbidden`, ...),
   * as `ServiceError.code` names it over HTTP; null when the close has none (1000, 1006,
   * or the WebSocket library's text). */
  readonly code: ErrorCode | null;

  constructor(
    readonly closeCode: number,
    readonly reason = "",
  ) {
    const meaning = CLOSE_CODE_MEANINGS[closeCode] ?? "unknown close code";
    super(`WebSocket closed ${closeCode} (${meaning})${reason ? `: ${reason}` : ""}`);
    this.meaning = meaning;
    this.code = ERROR_CODES.has(reason) ? (reason as ErrorCode) : null;
  }
}

/** No token, or the wrong one. */
export class StreamAuthError extends StreamClosed {
  override name = "StreamAuthError";
  static override readonly closeCodes: readonly CloseCode[] = [CloseCode.Unauthorized, CloseCode.Forbidden];
}
/** The session does not exist (any more); create a new one. */
export class SessionGone extends StreamClosed {
  override name = "SessionGone";
  static override readonly closeCodes: readonly CloseCode[] = [CloseCode.NotFound];
}
/** A message was larger than the server accepts. */
export class MessageTooBig extends StreamClosed {
  override name = "MessageTooBig";
  static override readonly closeCodes: readonly CloseCode[] = [CloseCode.MessageTooBig];
}
/** The client did not read its answers in time (or a bad handshake query). */
export class SlowReader extends StreamClosed {
  override name = "SlowReader";
  static override readonly closeCodes: readonly CloseCode[] = [CloseCode.SlowReader];
}
/** The server shut down; only when reconnecting did not succeed. */
export class ServerRestarting extends StreamClosed {
  override name = "ServerRestarting";
  static override readonly closeCodes: readonly CloseCode[] = [CloseCode.ServiceRestart];
}
/** The server holds its maximum of WebSockets. */
export class TooManyWebSockets extends StreamClosed {
  override name = "TooManyWebSockets";
  static override readonly closeCodes: readonly CloseCode[] = [CloseCode.TryAgainLater];
}
/** The connection dropped or the server failed; reconnecting did not help. */
export class ConnectionLost extends StreamClosed {
  override name = "ConnectionLost";
  static override readonly closeCodes: readonly CloseCode[] = [CloseCode.Abnormal, CloseCode.InternalError];
}

const RECONNECTING = [ServerRestarting, TooManyWebSockets, ConnectionLost];
const CLOSE_CLASSES = new Map<number, typeof StreamClosed>(
  [StreamAuthError, SessionGone, MessageTooBig, SlowReader, ...RECONNECTING].flatMap((Class) =>
    Class.closeCodes.map((code) => [code, Class] as const),
  ),
);

/** Closes after which reconnecting and resending can succeed. */
export const RECONNECTABLE: ReadonlySet<number> = new Set(RECONNECTING.flatMap((Class) => Class.closeCodes));

/** The `StreamClosed` subclass for `closeCode`. */
export function streamClosed(closeCode: number, reason = ""): StreamClosed {
  const Class = CLOSE_CLASSES.get(closeCode) ?? StreamClosed;
  return new Class(closeCode, reason);
}
