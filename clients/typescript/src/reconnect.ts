/**
 * How patiently the client gets an answer back after a failure: `Reconnect` (the policy
 * a caller sets) and `Backoff` (one outage's clock), without I/O; the same rules as the
 * Python client's `ik_client/reconnect.py`.
 *
 * A policy is a deadline, not a count: a worker that restarts (loads its compiled solver,
 * reconnects to Redis) or a balancer that routes around a dead backend takes a time, not
 * a number of tries, and the tries that fit in it depend on how fast each one fails. The
 * waits grow exponentially with random jitter (so that the clients of a worker that died
 * do not all come back in the same millisecond), up to `maxDelayMs` (so that a server
 * that is back is found again within about that long), never sooner than a `Retry-After`
 * the server or the balancer sent, and never past the deadline: a `Retry-After` that
 * would end after it ends the wait at once (the caller decides). Only failures that
 * waiting can mend use the budget; a session that is gone (404, close 4404) or a refused
 * token fails at once. Why 30 s: docs/websocket.md, "Reconnecting".
 */

/** How long and how often a failed connection or call is tried again.
 *
 * The wait before try `n` (0, 1, ...) is `min(initialDelayMs * 2 ** n, maxDelayMs)`,
 * less a random part of up to `jitter` of it (1: "full jitter", anywhere between zero
 * and the whole wait; 0: none), and at least a `Retry-After` sent with the failure. The
 * tries stop `deadlineMs` after the first failure since the last answer (or after
 * `attempts` tries). `RECONNECT_OFF` (or `deadlineMs: 0`) never tries again. */
export interface Reconnect {
  /** How long after the first failure the last try may start [ms]. */
  deadlineMs: number;
  /** The wait before the first try, before jitter [ms]. */
  initialDelayMs: number;
  /** The longest wait between tries, before jitter [ms]. */
  maxDelayMs: number;
  /** The random share of each wait, in [0, 1]. */
  jitter: number;
  /** At most this many tries as well (`Infinity`: as many as fit in the deadline). */
  attempts: number;
}

export const DEFAULT_RECONNECT: Readonly<Reconnect> = Object.freeze({
  deadlineMs: 30_000,
  initialDelayMs: 100,
  maxDelayMs: 2_000,
  jitter: 1,
  attempts: Number.POSITIVE_INFINITY,
});

/** The fields of a `Reconnect` a caller sets; one left out or `undefined` keeps its default. */
export type ReconnectOptions = { [K in keyof Reconnect]?: Reconnect[K] | undefined };

/** Never try again: the failure is thrown at once. */
export const RECONNECT_OFF: Readonly<ReconnectOptions> = Object.freeze({ deadlineMs: 0 });

/** `DEFAULT_RECONNECT` with `options` over it, checked (a `RangeError` names the field).
 * A field given as `undefined` keeps its default, as if it were left out: a caller's own
 * optional settings (`{ deadlineMs: config.deadlineMs }`) pass through unchanged. */
export function reconnectPolicy(options: ReconnectOptions = {}): Reconnect {
  const given = Object.entries(options).filter(([, value]) => value !== undefined);
  const policy: Reconnect = { ...DEFAULT_RECONNECT, ...Object.fromEntries(given) };
  for (const name of ["deadlineMs", "initialDelayMs", "maxDelayMs"] as const) {
    const value = policy[name];
    if (!(Number.isFinite(value) && value >= 0)) throw new RangeError(`reconnect.${name} must be a finite number >= 0, got ${value}`);
  }
  if (!(policy.jitter >= 0 && policy.jitter <= 1)) throw new RangeError(`reconnect.jitter must be in [0, 1], got ${policy.jitter}`);
  if (!(policy.attempts >= 0)) throw new RangeError(`reconnect.attempts must be >= 0, got ${policy.attempts}`);
  return policy;
}

/** The wait before try `attempt` (0, 1, ...), jitter included [ms]. */
export function delayMs(policy: Reconnect, attempt: number, random: () => number = Math.random): number {
  const delay = Math.min(policy.initialDelayMs * 2 ** Math.min(attempt, 64), policy.maxDelayMs);
  return policy.jitter === 0 ? delay : delay * (1 - policy.jitter * random());
}

/** One outage's clock under a `Reconnect` policy: started by the first failure, cleared
 * by an answer. `nextWaitMs` says how long to wait before the next try, or null when
 * the budget is spent. */
export class Backoff {
  /** Tries since the last answer. */
  tries = 0;
  private started: number | null = null;

  constructor(
    readonly policy: Reconnect,
    private readonly clock: () => number = () => performance.now(),
    private readonly random: () => number = Math.random,
  ) {}

  /** Whether the policy tries again at all (not `RECONNECT_OFF`, not `attempts: 0`). */
  get enabled(): boolean {
    return this.policy.deadlineMs > 0 && this.policy.attempts > 0;
  }

  /** A failure came and no answer since. */
  get recovering(): boolean {
    return this.started !== null;
  }

  /** Note a failure; the first since the last answer starts the clock. */
  failed(): void {
    this.started ??= this.clock();
  }

  /** An answer came: the next failure starts a new outage, with the whole budget. */
  answered(): void {
    this.started = null;
    this.tries = 0;
  }

  /** The wait before the next try [ms], counting it; null: give up (the deadline or the
   * attempts are spent, or `retryAfterMs` would end after the deadline). */
  nextWaitMs(retryAfterMs: number | null = null): number | null {
    this.failed();
    const policy = this.policy;
    if (!this.enabled || this.tries >= policy.attempts) return null;
    const left = (this.started ?? 0) + policy.deadlineMs - this.clock();
    let wait = delayMs(policy, this.tries, this.random);
    if (retryAfterMs !== null && retryAfterMs > 0) {
      if (retryAfterMs > left) return null; // the server asks for more time than the caller gives
      wait = Math.max(wait, retryAfterMs);
    }
    if (left <= 0) return null;
    this.tries += 1;
    return Math.min(wait, left);
  }
}

/** An HTTP `Retry-After` in milliseconds (its date form is not used by the service or
 * the balancer: null, as for a missing or unreadable one). */
export function retryAfterMs(header: string | null): number | null {
  if (header === null || header.trim() === "") return null;
  const seconds = Number(header);
  return Number.isFinite(seconds) && seconds >= 0 ? 1000 * seconds : null;
}
