/**
 * `Client`: the IK service over HTTP (the platform's `fetch`), and `stream()` for a
 * session's WebSocket. Every call resolves to a typed answer or rejects with a
 * `ServiceError` subclass carrying the server's `code`, `field` and `retryAfterS`, or
 * with `NoAnswer` when no answer came (the connection failed, or `timeoutMs`). A call
 * that got no answer (fetch failed: the connection failed or dropped, not the timeout; or
 * a balancer's or the server's 502 or 503) is sent again when it is repeatable (reads, a
 * pose or options set, a stateless solve, a frame with an `id`: behind a balancer with a
 * shared store a frame sent again is answered once; without one, a frame whose answer
 * was lost after it was solved is solved again), as `reconnect` says (reconnect.ts:
 * backoff with jitter until a deadline from the call's first failure), no sooner than a
 * `Retry-After` and not at all when that would end after the deadline.
 */

import type { Chain } from "./chains.js";
import { encodeBody } from "./encode.js";
import { NoAnswer, serviceError } from "./errors.js";
import { Backoff, type Reconnect, type ReconnectOptions, reconnectPolicy, retryAfterMs } from "./reconnect.js";
import { type FkOptions, Stream, type StreamOptions } from "./stream.js";
import type {
  BatchEntry,
  BatchFrame,
  BatchResults,
  BoneOutput,
  Conventions,
  CompactFrameResult,
  FkResult,
  Frame,
  FrameResult,
  FrameResults,
  OptionsPatch,
  Pose,
  PoseIn,
  SessionCreated,
  SessionInfo,
  SessionRef,
  Target,
} from "./types.js";
import { fkResultFrom } from "./types.js";
import { framesAsSent, targetsAsSent } from "./targets.js";

export interface ClientOptions {
  /** Sent as `X-API-Key` when the server has API keys (`IK_API_KEYS`). */
  apiKey?: string | undefined;
  /** Per-request timeout [ms]. */
  timeoutMs?: number | undefined;
  /** How long and how often a repeatable HTTP call that got no answer is sent again
   * (`DEFAULT_RECONNECT`: for up to 30 s; `RECONNECT_OFF`: never, the error is thrown
   * at once); `timeoutMs` bounds each attempt. A stream's reconnects are `stream()`'s
   * own option. */
  reconnect?: ReconnectOptions | undefined;
}

// What a balancer answers for a worker it cannot reach, and the server for a store or
// solver it cannot reach yet: the call itself was not answered. (Not 504: the worker may
// still be solving it.)
const NO_ANSWER_STATUSES = new Set([502, 503]);

function sleep(ms: number): Promise<void> {
  return new Promise((resolve) => setTimeout(resolve, ms));
}

export interface CreateSessionOptions {
  options?: OptionsPatch | undefined;
  initialPose?: PoseIn | undefined;
  /** The client's coordinates (docs/engines.md): targets in, bone output out. */
  conventions?: Conventions | undefined;
  /** Bone output on every answer (skeleton chains). */
  bones?: BoneOutput | undefined;
}

export interface SolveOptions {
  seed?: PoseIn | undefined;
  options?: OptionsPatch | undefined;
  id?: number | undefined;
  /** The client's coordinates (docs/engines.md): targets in, bone output out. */
  conventions?: Conventions | undefined;
  /** Bone output on the answer (skeleton chains). */
  bones?: BoneOutput | undefined;
}



type Json = Record<string, unknown>;

/** `?results=compact` on a call picks the compact result type. */
type Result<C extends boolean> = C extends true ? CompactFrameResult : FrameResult;

function withoutUndefined(values: Json): Json {
  return Object.fromEntries(Object.entries(values).filter(([, v]) => v !== undefined));
}

/** Raise the `ServiceError` subclass of an error answer `{detail, code, field}`. */
/** Throws the `ServiceError` of an answer that is not 2xx (`text`: its body, read). */
function raiseForError(response: Response, text: string): void {
  if (response.ok) return;
  let body: Json = { detail: text };
  try {
    const parsed: unknown = JSON.parse(text);
    if (parsed !== null && typeof parsed === "object") body = parsed as Json;
  } catch {
    // not JSON: keep the text as the detail
  }
  const detail = body["detail"];
  // invalid_format's detail is pydantic's list of {loc, msg, type}: the first says most.
  const first = Array.isArray(detail) ? (detail[0] as Json | undefined) : undefined;
  const message = first !== undefined ? String(first["msg"] ?? "") : String(detail ?? "");
  const retryAfter = Number(response.headers.get("Retry-After") ?? Number.NaN);
  throw serviceError(String(body["code"] ?? `http_${response.status}`), message, {
    field: (body["field"] as string | undefined) ?? null,
    retryAfterS: Number.isFinite(retryAfter) ? retryAfter : null,
    status: response.status,
    detail,
  });
}

export class Client {
  readonly baseUrl: string;
  private readonly apiKey: string | undefined;
  private readonly timeoutMs: number;
  readonly reconnect: Reconnect;

  /** @param baseUrl The service, e.g. `http://127.0.0.1:8000`. */
  constructor(baseUrl: string, options: ClientOptions = {}) {
    this.baseUrl = baseUrl.replace(/\/+$/, "");
    this.apiKey = options.apiKey;
    this.timeoutMs = options.timeoutMs ?? 30_000;
    this.reconnect = reconnectPolicy(options.reconnect);
  }

  /** A new session on `chain` (e.g. `{format: "example", name: "panda_arm"}`). */
  createSession(chain: Chain, options: CreateSessionOptions = {}): Promise<SessionCreated> {
    const body = withoutUndefined({
      chain,
      options: options.options,
      initial_pose: options.initialPose,
      conventions: options.conventions,
      bones: options.bones,
    });
    return this.request("POST", "/v1/sessions", { body });
  }

  getSession(session: SessionRef): Promise<SessionInfo> {
    return this.request("GET", `/v1/sessions/${session.id}`, { session, repeatable: true });
  }

  /** Change solver options; the options left out keep their value. */
  patchSession(session: SessionRef, options: OptionsPatch): Promise<SessionInfo> {
    return this.request("PATCH", `/v1/sessions/${session.id}`, {
      session,
      body: options as Json,
      repeatable: true,
    });
  }

  /** Set the pose the next frame starts from: `{q}` (every DOF) or `{joints}` (some, by name). */
  setPose(session: SessionRef, pose: PoseIn): Promise<Pose> {
    return this.request("PUT", `/v1/sessions/${session.id}/pose`, {
      session,
      body: pose as Json,
      repeatable: true,
    });
  }

  async deleteSession(session: SessionRef): Promise<void> {
    await this.request("DELETE", `/v1/sessions/${session.id}`, { session });
  }

  /** Solve one frame from the session's pose (`compact`: no joints by name, no effector
   * errors; `bones`: this frame's bone output, in place of the session's; `pose`: the
   * animated pose it starts from, as `setPose` then the frame in one step). With an `id`
   * a frame that got no answer is sent again, same id (`reconnect`). */
  async frame<C extends boolean = false>(
    session: SessionRef,
    targets: Target[],
    options: {
      id?: number | undefined;
      compact?: C | undefined;
      bones?: BoneOutput | undefined;
      pose?: PoseIn | undefined;
    } = {},
  ): Promise<Result<C>> {
    const body = { id: options.id, targets: targetsAsSent(targets), bones: options.bones, pose: options.pose };
    const out: FrameResults<Result<C>> = await this.request("POST", `/v1/sessions/${session.id}/frames`, {
      session,
      body: withoutUndefined(body),
      compact: options.compact ?? false,
      repeatable: options.id !== undefined,
    });
    return out.results[0] as Result<C>;
  }

  /** Solve frames in order, each from the previous answer, or with `plan` as a whole. */
  async clip<C extends boolean = false>(
    session: SessionRef,
    frames: Frame[],
    options: { plan?: boolean | undefined; compact?: C | undefined } = {},
  ): Promise<FrameResults<Result<C>>> {
    const out: FrameResults<Result<C>> = await this.request("POST", `/v1/sessions/${session.id}/frames`, {
      session,
      body: { frames: framesAsSent(frames), plan: options.plan ?? false },
      compact: options.compact ?? false,
    });
    return { results: out.results, plan: out.plan ?? null }; // no `plan` key when not planned
  }

  /**
   * One frame for each of several sessions (a game server's characters) in one request,
   * each frame with its session's id and token: one entry per frame, in order, each its
   * result or its own error (an entry's error does not reject: the others were solved).
   */
  async batch<C extends boolean = false>(
    frames: BatchFrame[],
    options: { compact?: C | undefined } = {},
  ): Promise<BatchEntry<Result<C>>[]> {
    const out: BatchResults<Result<C>> = await this.request("POST", "/v1/batch", {
      body: { frames: framesAsSent(frames) },
      compact: options.compact ?? false,
    });
    return out.results;
  }

  /** A stateless one-shot solve (no session), in `conventions`, answering with `bones`. */
  solve(chain: Chain, targets: Target[], options: SolveOptions = {}): Promise<FrameResult> {
    const body = withoutUndefined({
      chain,
      targets: targetsAsSent(targets),
      seed: options.seed,
      options: options.options,
      id: options.id,
      conventions: options.conventions,
      bones: options.bones,
    });
    return this.request("POST", "/v1/solve", { body, repeatable: true });
  }

  /** Forward kinematics of any chain: every effector's world pose for a pose (and, on
   * skeleton chains, its bone data) in the session's conventions; the session's pose
   * does not change. */
  async fk(session: SessionRef, options: FkOptions = {}): Promise<FkResult> {
    const body = withoutUndefined({ q: options.q, joints: options.joints, bones: options.bones });
    const json = await this.request<FkResult>("POST", `/v1/sessions/${session.id}/fk`, { session, body, repeatable: true });
    return fkResultFrom(json);
  }

  /** The session's WebSocket, open (see `Stream`). The server accepts the handshake and
   * then closes a socket whose token or session is wrong (4401, 4403, 4404): that
   * rejects the first message (`StreamAuthError`, `SessionGone`), not this call; `await
   * stream.ping()` checks at once. */
  stream<C extends boolean = false>(
    session: SessionRef,
    options: StreamOptions & { compact?: C | undefined } = {},
  ): Promise<Stream<Result<C>>> {
    const url = new URL(`${this.baseUrl}/v1/sessions/${session.id}/ws`);
    url.protocol = url.protocol === "https:" ? "wss:" : "ws:";
    if (options.compact) url.searchParams.set("results", "compact");
    return Stream.open<Result<C>>(url.toString(), session.token, options);
  }

  private async request<T>(
    method: string,
    path: string,
    init: { session?: SessionRef; body?: Json; compact?: boolean; repeatable?: boolean },
  ): Promise<T> {
    // Written first: a body that cannot be (NaN, a BigInt) throws an EncodeError, unsent.
    const body = init.body === undefined ? null : encodeBody(init.body, "json");
    const headers: Record<string, string> = {};
    if (this.apiKey !== undefined) headers["X-API-Key"] = this.apiKey;
    if (init.session !== undefined) headers["Authorization"] = `Bearer ${init.session.token}`;
    if (init.body !== undefined) headers["Content-Type"] = "application/json";
    const query = init.compact ? "?results=compact" : "";
    const backoff = new Backoff(this.reconnect); // this call's own clock, from its first failure
    for (;;) {
      let response: Response;
      let text: string;
      let wait: number | null;
      try {
        response = await fetch(`${this.baseUrl}${path}${query}`, {
          method,
          headers,
          body,
          signal: AbortSignal.timeout(this.timeoutMs),
        });
        wait = this.waitBeforeResending(init.repeatable ?? false, backoff, response);
        // The body is read here too: a connection that drops, or a timeout that passes,
        // while it arrives is no answer either.
        text = wait === null ? await response.text() : "";
        if (wait !== null) await response.body?.cancel();
      } catch (error) {
        // fetch rejects with a TypeError when the network fails; the timeout is a
        // DOMException, not sent again (the server may still be solving the call).
        const failed = error instanceof TypeError;
        const again = failed ? this.waitBeforeResending(init.repeatable ?? false, backoff, null) : null;
        if (again === null) {
          const what = failed ? `the connection failed: ${String(error.cause ?? error.message)}` : "timed out";
          throw new NoAnswer(`${method} ${path}: no answer (${what})`, !failed, { cause: error });
        }
        await sleep(again);
        continue;
      }
      if (wait === null) {
        raiseForError(response, text);
        return (response.status === 204 || text === "" ? undefined : JSON.parse(text)) as T;
      }
      await sleep(wait);
    }
  }

  /** Milliseconds to wait before sending a call again after a send that got `response`
   * (null: the connection failed), or null: do not send it again (not repeatable,
   * answered, or `backoff`'s deadline spent or shorter than the answer's `Retry-After`:
   * the caller decides). */
  private waitBeforeResending(repeatable: boolean, backoff: Backoff, response: Response | null): number | null {
    if (!repeatable) return null;
    if (response === null) return backoff.nextWaitMs();
    if (!NO_ANSWER_STATUSES.has(response.status)) return null;
    return backoff.nextWaitMs(retryAfterMs(response.headers.get("Retry-After")));
  }
}
