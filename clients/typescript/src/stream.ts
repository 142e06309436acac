/**
 * A session's WebSocket as a stream of frames: ids, pipelining, encodings, reconnects.
 *
 * The stream numbers its messages itself (0, 1, 2, ...): `sendFrame` / `sendClip` /
 * `sendPing` return the id, `receive()` resolves to the next answer in the order sent
 * (the server answers in order), `frame` / `clip` / `ping` send one message and resolve
 * to its answer. When the connection drops (or the server closes 1011, 1012 or 1013, or
 * answers `shutting_down`, or `not_ready` after a reconnect), the stream reconnects
 * within its `Reconnect` budget (reconnect.ts: a deadline, backoff with jitter) and
 * sends again, in order, every message that had no answer, under the id it was first
 * sent with (one counter over every connection, so the ids on a new connection still
 * increase); of the messages sent while reconnecting, at most `maxQueued` wait for the
 * new connection (queued.ts: the oldest beyond it are dropped, `MessageDropped`).
 * Answers carry the id the caller got, and each message gets exactly one (a dropped
 * one: its `MessageDropped`). A server that keeps answers (sessions in
 * Redis, docs/operations.md) answers a message it had solved, and whose answer was lost
 * in the drop, with that stored answer: on another worker too, and never solved twice.
 *
 * In a browser the stream uses the global WebSocket and sends the token as the
 * `ik.token.<token>` subprotocol (browsers cannot set headers); in Node 20, which has no
 * stable global WebSocket, it uses the `ws` package and an `Authorization` header.
 */

import { checkEncoding, encodeBody, messagePackCodec } from "./encode.js";
import {
  IKClientError,
  MessageDropped,
  RECONNECTABLE,
  StreamClosed,
  UnexpectedAnswer,
  serviceError,
  streamClosed,
} from "./errors.js";
import type {
  Answer,
  BatchEntry,
  BatchFrame,
  ClipAnswer,
  Encoding,
  FkResult,
  Frame,
  FrameResult,
  FrameResults,
  Pong,
  Target,
} from "./types.js";
import { fkResultFrom } from "./types.js";
import { framesAsSent } from "./targets.js";
import { type Envelope, type FkOptions, type FrameOptions, clipMessage, fkMessage, frameMessage } from "./messages.js";
import { Backoff, type Reconnect, type ReconnectOptions, reconnectPolicy } from "./reconnect.js";
import { SendQueue, maxQueuedOption } from "./queued.js";

/** The part of a WebSocket (browser's or `ws`'s) the stream uses. */
export interface Socket {
  binaryType: string;
  readonly readyState: number;
  readonly protocol: string;
  onopen: ((event: unknown) => void) | null;
  onmessage: ((event: { data: unknown }) => void) | null;
  onclose: ((event: { code: number; reason: string }) => void) | null;
  onerror: ((event: unknown) => void) | null;
  send(data: string | Uint8Array): void;
  close(code?: number, reason?: string): void;
}

export type SocketClass = new (
  url: string,
  protocols?: string | string[],
  options?: { headers?: Record<string, string> },
) => unknown;

export interface StreamOptions {
  /** `json` (text messages, the default) or `msgpack` (binary messages; with
   * `ik-client/json`, only after `import "ik-client/msgpack"`). */
  encoding?: Encoding | undefined;
  /** How long and how often to reconnect after a drop (`DEFAULT_RECONNECT`: for up to
   * 30 s from the drop, each new drop since an answer with the whole budget);
   * `RECONNECT_OFF` rejects what waits with the drop's `StreamClosed` instead. */
  reconnect?: ReconnectOptions | undefined;
  /** How many messages sent while reconnecting may wait for the new connection
   * (`DEFAULT_MAX_QUEUED`, 60; `Infinity`: all). One more drops the oldest of them, which
   * rejects with `MessageDropped` (it never went out). Messages sent before the drop are
   * not counted: they are sent again and answered, whatever this is. */
  maxQueued?: number | undefined;
  /** Where the token goes: `header` (`ws` only) or `subprotocol` (what browsers can do).
   * Default: `header` with `ws`, `subprotocol` with a global WebSocket. */
  auth?: "header" | "subprotocol" | undefined;
  /** A WebSocket class to use instead of the global one (or `ws` when there is none). */
  WebSocket?: SocketClass | undefined;
  /** Called with an answer to an id nothing waits for, or one that cannot be decoded
   * (not JSON or MessagePack, or not an object): an `UnexpectedAnswer` whose `id` is
   * null; no message's promise can take it, and the stream goes on. Default: such
   * answers are dropped. */
  onUnexpected?: ((error: UnexpectedAnswer) => void) | undefined;
}

export type { FkOptions, FrameOptions } from "./messages.js";

/** Where a stream is (`Stream.state`). */
export const StreamState = { Open: "open", Reconnecting: "reconnecting", Closed: "closed" } as const;
export type StreamState = (typeof StreamState)[keyof typeof StreamState];

const OPEN = 1;
const CLOSED = 3;
const SUBPROTOCOL = "ik.v1";
const TOKEN_SUBPROTOCOL_PREFIX = "ik.token.";

interface Message<R> {
  id: number; // the id the caller was given
  wireId: number; // the id it carries on every connection
  // The message as first sent, id included: a reconnect sends these bytes again. A new
  // encoding of the body could differ (the caller may have changed its objects since)
  // or throw, and the server recognises a resent message by its id and content.
  data: string | Uint8Array;
  resolve: (answer: Answer<R>) => void;
  reject: (error: Error) => void;
  answer: Promise<Answer<R>>;
}

async function platformWebSocket(options: StreamOptions): Promise<[SocketClass, boolean]> {
  if (options.WebSocket !== undefined) return [options.WebSocket, false];
  if (typeof globalThis.WebSocket === "function") return [globalThis.WebSocket as SocketClass, true];
  const ws = await import("ws");
  return [ws.WebSocket as unknown as SocketClass, false];
}

export class Stream<R = FrameResult> {
  /** Connections made after the first. */
  reconnects = 0;
  private socketNow: Socket;
  private nextId = 0;
  private nextWireId = 0;
  private waiting = new Map<number, Message<R>>(); // by wire id, in the order sent
  private unread: Message<R>[] = []; // what receive() has not returned yet
  private readonly backoff: Backoff;
  private readonly held: SendQueue<Message<R>>; // sent while reconnecting: not out yet
  private failure: StreamClosed | null = null;
  private closing = false;

  private constructor(
    readonly url: string,
    private readonly connect: () => Socket,
    private readonly encoding: Encoding,
    reconnect: Reconnect,
    maxQueued: number,
    private readonly onUnexpected: ((error: UnexpectedAnswer) => void) | undefined,
    first: Socket,
  ) {
    this.backoff = new Backoff(reconnect);
    this.held = new SendQueue(maxQueued);
    this.socketNow = first;
    this.watch(first);
  }

  /** Open a stream on `url` (see `Client.stream`). */
  static async open<R = FrameResult>(url: string, token: string, options: StreamOptions = {}): Promise<Stream<R>> {
    const reconnect = reconnectPolicy(options.reconnect); // checked before anything opens
    const encoding = checkEncoding(options.encoding ?? "json");
    const maxQueued = maxQueuedOption(options.maxQueued);
    const [SocketImpl, global] = await platformWebSocket(options);
    const auth = options.auth ?? (global ? "subprotocol" : "header");
    if (auth === "header" && global) throw new IKClientError("a global WebSocket cannot send headers");
    const connect = (): Socket => {
      const socket =
        auth === "subprotocol"
          ? new SocketImpl(url, [SUBPROTOCOL, TOKEN_SUBPROTOCOL_PREFIX + token])
          : new SocketImpl(url, [SUBPROTOCOL], { headers: { Authorization: `Bearer ${token}` } });
      (socket as Socket).binaryType = "arraybuffer";
      return socket as Socket;
    };
    const first = connect();
    await opened(first);
    return new Stream<R>(url, connect, encoding, reconnect, maxQueued, options.onUnexpected, first);
  }

  /** The current socket (a test drops it: `ws`'s `terminate()`). */
  get socket(): Socket {
    return this.socketNow;
  }

  /** Messages sent that have no answer yet. */
  get inFlight(): number {
    return this.waiting.size;
  }

  /** Of those, the ones sent while reconnecting, waiting for the new connection (at most
   * `maxQueued`). */
  get queued(): number {
    return this.held.size;
  }

  /** `open`, `reconnecting` (the connection dropped and the stream connects again: what
   * is sent meanwhile waits, up to `maxQueued` of it, and goes out on the new connection) or `closed` (the stream
   * ended, `closedBy` says why, or `close()` was called). A game that sends targets every
   * frame can skip its sends while reconnecting, rather than queue targets that will be
   * stale when they are solved, and show it; and learn that the stream ended without a
   * send (a reconnect refused 4404 while nothing was in flight rejects no message). */
  get state(): StreamState {
    if (this.failure !== null || this.closing) return StreamState.Closed;
    return this.socketNow.readyState === OPEN ? StreamState.Open : StreamState.Reconnecting;
  }

  /** What ended the stream (`SessionGone`, `StreamAuthError`, `ConnectionLost` once the
   * reconnect budget is spent, a `StreamClosed` 1000 after `close()`, ...), which every
   * later send throws; null while it goes on. */
  get closedBy(): StreamClosed | null {
    return this.failure;
  }

  /** `options.bones` overrides the session's bone output for this frame only;
   * `options.pose` is the animated pose it starts from. */
  sendFrame(targets: Target[], options: FrameOptions = {}): number {
    return this.send(frameMessage(targets, options)).id;
  }

  sendClip(frames: Frame[], options: { plan?: boolean | undefined } = {}): number {
    return this.send(clipMessage(frames, options)).id;
  }

  sendPing(): number {
    return this.send({ type: "ping" }).id;
  }

  /** One frame for each of several sessions (a game server's characters), each with its
   * session's id and token: answered by one `batch_result`, an entry per frame, in order. */
  sendBatch(frames: BatchFrame[]): number {
    return this.send({ type: "batch", frames: framesAsSent(frames) }).id;
  }

  /** Forward kinematics of `options.q`, of `options.joints` by name, or of neither (the
   * session's current pose), in the session's conventions; the pose does not change. */
  sendFk(options: FkOptions = {}): number {
    return this.send(fkMessage(options)).id;
  }

  /** The next answer, in the order sent; rejects with the message's `ServiceError`. */
  receive(): Promise<Answer<R>> {
    const next = this.unread.shift();
    if (next === undefined) return Promise.reject(new IKClientError("no message is waiting for an answer"));
    return next.answer;
  }

  async frame(targets: Target[], options: FrameOptions = {}): Promise<R> {
    const answer = await this.answerOf(this.send(frameMessage(targets, options)));
    if (answer.type !== "result") throw new IKClientError(`expected a frame result, got ${answer.type}`);
    return answer.result;
  }

  async clip(frames: Frame[], options: { plan?: boolean | undefined } = {}): Promise<FrameResults<R>> {
    const answer = await this.answerOf(this.send(clipMessage(frames, options)));
    if (answer.type !== "clip_result") throw new IKClientError(`expected a clip result, got ${answer.type}`);
    return { results: (answer as ClipAnswer<R>).results, plan: (answer as ClipAnswer<R>).plan };
  }

  /** Each entry's result or its own error (an entry's error does not reject: the other
   * entries were solved). */
  async batch(frames: BatchFrame[]): Promise<BatchEntry<R>[]> {
    const answer = await this.answerOf(this.send({ type: "batch", frames: framesAsSent(frames) }));
    if (answer.type !== "batch_result") throw new IKClientError(`expected a batch result, got ${answer.type}`);
    return answer.results;
  }

  async fk(options: FkOptions = {}): Promise<FkResult> {
    const answer = await this.answerOf(this.send(fkMessage(options)));
    if (answer.type !== "fk_result") throw new IKClientError(`expected an fk result, got ${answer.type}`);
    return answer.result;
  }

  async ping(): Promise<Pong> {
    const answer = await this.answerOf(this.send({ type: "ping" }));
    if (answer.type !== "pong") throw new IKClientError(`expected a pong, got ${answer.type}`);
    return answer;
  }

  /** Close the stream: messages still waiting when the socket has closed reject with
   * `StreamClosed` (1000), also while a reconnect is pending or under way (which is then
   * abandoned). Answers that arrive before the server's close frame are still delivered
   * (of 50 frames in flight at `close()`, 31 to 50 were answered here, 3 runs); `state` is
   * `closed` at once, and nothing sent after `close()` goes out. */
  close(): void {
    if (this.closing) return;
    this.closing = true;
    const socket = this.socketNow;
    if (socket.readyState === CLOSED) this.closed(1000, "");
    else socket.close(1000); // its close event settles what waits
  }

  private answerOf(message: Message<R>): Promise<Answer<R>> {
    this.unread.splice(this.unread.indexOf(message), 1);
    return message.answer;
  }

  private send(body: Record<string, unknown>): Message<R> {
    if (this.failure !== null) throw this.failure;
    // Encoded before it counts: a message that cannot be written throws here, and
    // nothing waits for an answer to it or holds its id.
    const data = this.encode(body, this.nextWireId);
    let resolve!: (answer: Answer<R>) => void;
    let reject!: (error: Error) => void;
    const answer = new Promise<Answer<R>>((res, rej) => {
      resolve = res;
      reject = rej;
    });
    answer.catch(() => {}); // an answer nobody awaits must not be an unhandled rejection
    const message: Message<R> = { id: this.nextId++, wireId: this.nextWireId++, data, resolve, reject, answer };
    this.waiting.set(message.wireId, message);
    this.unread.push(message);
    // While reconnecting it waits: the new connection gets it with the others.
    if (this.socketNow.readyState === OPEN) this.socketNow.send(data);
    else this.hold(message);
    return message;
  }

  /** Keep `message` for the new connection; the oldest held beyond `maxQueued` is dropped. */
  private hold(message: Message<R>): void {
    for (const dropped of this.held.add(message)) {
      this.waiting.delete(dropped.wireId);
      dropped.reject(new MessageDropped(dropped.id, this.held.max));
    }
  }

  /** `body` with its id, as sent; throws an `EncodeError` for a non-finite number
   * (naming its field) and for what the encoding cannot write (a BigInt, a cycle). */
  private encode(body: Record<string, unknown>, wireId: number): string | Uint8Array {
    return encodeBody({ ...body, id: wireId }, this.encoding);
  }

  /** The answer `data` carries; an `UnexpectedAnswer` (`id` null) for one that is not
   * JSON or MessagePack, or not an object. */
  private decode(data: unknown): Envelope | UnexpectedAnswer {
    let envelope: unknown;
    try {
      envelope = typeof data === "string" ? JSON.parse(data) : messagePackCodec().decode(data as ArrayBuffer);
    } catch (error) {
      const reason = error instanceof Error ? error.message : String(error);
      return new UnexpectedAnswer(`an answer that cannot be decoded (${reason})`, null, {}, data);
    }
    if (envelope !== null && typeof envelope === "object" && !Array.isArray(envelope)) return envelope as Envelope;
    return new UnexpectedAnswer(`an answer that is not an object: ${JSON.stringify(envelope)}`, null, {}, data);
  }

  private watch(socket: Socket): void {
    socket.onerror = () => {}; // the close that follows says why (and ws throws without a listener)
    socket.onmessage = (event) => {
      if (socket !== this.socketNow) return;
      const envelope = this.decode(event.data);
      // Garbled: no message can be told it is answered (its id is unreadable); the caller
      // learns of it as of an answer to an id nothing waits for, and the stream goes on.
      if (envelope instanceof UnexpectedAnswer) this.onUnexpected?.(envelope);
      else this.answered(envelope);
    };
    socket.onclose = (event) => {
      if (socket === this.socketNow) this.closed(event.code, event.reason);
    };
  }

  private answered(envelope: Envelope): void {
    let wireId = envelope["id"] as number | null | undefined;
    if (wireId === null || wireId === undefined) wireId = this.waiting.keys().next().value; // in order
    const message = wireId === undefined ? undefined : this.waiting.get(wireId);
    if (message === undefined) {
      const text = `an answer (${String(envelope["type"])}) to id ${String(envelope["id"])}, which is not waiting`;
      this.onUnexpected?.(new UnexpectedAnswer(text, null, envelope));
      return;
    }
    const id = message.id;
    const error = envelope["error"] as Record<string, unknown> | undefined;
    if (error !== undefined && this.notServing(error)) return;
    this.waiting.delete(message.wireId);
    this.backoff.answered(); // error answers included: the server answered
    if (error !== undefined) {
      message.reject(
        serviceError(String(error["code"]), String(error["message"] ?? ""), {
          field: error["field"] as string | null | undefined,
          retryAfterS: error["retry_after_s"] as number | null | undefined,
          id,
        }),
      );
    } else if (envelope["type"] === "result") {
      const success = envelope["success"] as boolean;
      message.resolve({ type: "result", id, success, result: { ...(envelope["result"] as R), id } });
    } else if (envelope["type"] === "clip_result") {
      const clip = envelope as unknown as ClipAnswer<R>;
      message.resolve({ type: "clip_result", id, success: clip.success, results: clip.results, plan: clip.plan ?? null });
    } else if (envelope["type"] === "batch_result") {
      const success = envelope["success"] as boolean;
      message.resolve({ type: "batch_result", id, success, results: envelope["results"] as BatchEntry<R>[] });
    } else if (envelope["type"] === "fk_result") {
      message.resolve({ type: "fk_result", id, result: fkResultFrom(envelope as unknown as FkResult) });
    } else if (envelope["type"] === "pong") {
      message.resolve({ type: "pong", id });
    } else {
      const text = `an answer of unknown type ${String(envelope["type"])} to id ${message.wireId}`;
      message.reject(new UnexpectedAnswer(text, id, envelope));
    }
  }

  /** An error answer that is part of an outage: `shutting_down` (the message was being
   * solved when the server began to stop; it closes 1012 next) always, and `not_ready`
   * while recovering from a lost connection (a restarted worker listens before its
   * solver is loaded; a stream opened on a warming server gets `not_ready` as before, as
   * its opening fails at once). The message stays waiting; this socket is left and the
   * stream reconnects, no sooner than the error's `retry_after_s`. With reconnecting off
   * the caller gets such answers as they are. */
  private notServing(error: Record<string, unknown>): boolean {
    if (!this.backoff.enabled) return false;
    const code = error["code"];
    let close: number;
    if (code === "shutting_down") close = 1012;
    else if (code === "not_ready" && this.backoff.recovering) close = 1013;
    else return false;
    const socket = this.socketNow;
    socket.onmessage = null; // its later answers are asked for again on the new socket
    socket.onclose = null;
    socket.close(1000);
    const retryAfterS = error["retry_after_s"];
    this.closed(close, String(code), typeof retryAfterS === "number" ? 1000 * retryAfterS : null);
    return true;
  }

  private closed(code: number, reason: string, retryAfterMs: number | null = null): void {
    if (this.failure !== null) return; // settled already (a close between reconnects)
    // Closed by the caller: a socket cut while connecting says 1006, but the stream ended
    // as asked.
    if (this.closing) [code, reason] = [1000, ""];
    const wait = !this.closing && RECONNECTABLE.has(code) ? this.backoff.nextWaitMs(retryAfterMs) : null;
    if (wait !== null) {
      setTimeout(() => this.reopen(), wait);
      return;
    }
    this.failure = streamClosed(code, reason);
    for (const message of this.waiting.values()) message.reject(this.failure);
    this.waiting.clear();
    this.held.clear();
  }

  private reopen(): void {
    if (this.closing) return; // closed while the reconnect waited: nothing to reopen
    const socket = this.connect();
    this.socketNow = socket;
    this.watch(socket);
    socket.onopen = () => {
      this.reconnects += 1;
      this.held.clear(); // they go out now, with what had gone out before
      // Every waiting message, in order, as first sent: a server that stored its answer
      // recognises it (same id, same content) and does not solve it twice.
      for (const message of [...this.waiting.values()]) this.resend(socket, message);
    };
  }

  /** Send `message` again on `socket`; one the socket refuses gets that error as its
   * answer, and the messages after it are still sent. */
  private resend(socket: Socket, message: Message<R>): void {
    try {
      socket.send(message.data);
    } catch (error) {
      this.waiting.delete(message.wireId);
      message.reject(error instanceof Error ? error : new IKClientError(String(error)));
    }
  }
}

/** Resolves when `socket` opens; rejects with its close if it closes first. */
function opened(socket: Socket): Promise<void> {
  return new Promise((resolve, reject) => {
    socket.onopen = () => resolve();
    socket.onerror = () => {}; // the close that follows says why
    socket.onclose = (event) => reject(streamClosed(event.code, event.reason));
  });
}
