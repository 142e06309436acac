/**
 * What a stream holds back while it reconnects: the messages sent since the connection
 * dropped, which go out on the new connection, at most `maxQueued` of them (the same
 * rule as the Python client's `ik_client/queued.py`).
 *
 * A game that keeps sending targets through an outage (a server restart, a Wi-Fi drop)
 * would otherwise grow its memory for as long as the outage lasts, then have the server
 * solve every stale target, in order, before the current one. Past the limit the oldest
 * waiting message is dropped (`MessageDropped`): what goes out on the new connection is
 * the most recent targets. Messages that went out before the drop are not held here:
 * they are sent again and answered exactly once, whatever the limit.
 */

/** At most this many messages wait for a reconnect, by default: a second of a 60 Hz
 * game's frames. A blip shorter than that loses nothing; after a longer outage the
 * server solves the last second's targets, not every stale one. */
export const DEFAULT_MAX_QUEUED = 60;

/** `value` (a `maxQueued` option; undefined: the default) checked: an integer >= 0, or
 * `Infinity` (keep every message, as the client did before the limit). */
export function maxQueuedOption(value: number | undefined): number {
  if (value === undefined) return DEFAULT_MAX_QUEUED;
  if (value === Number.POSITIVE_INFINITY || (Number.isInteger(value) && value >= 0)) return value;
  throw new RangeError(`maxQueued must be an integer >= 0 or Infinity, got ${value}`);
}

/** The messages waiting for a reconnect, oldest first, at most `max`. */
export class SendQueue<M> {
  private items: M[] = [];

  constructor(readonly max: number) {}

  get size(): number {
    return this.items.length;
  }

  /** Hold `item`; returns what no longer fits: the oldest items beyond `max` (`item`
   * itself when `max` is 0). */
  add(item: M): M[] {
    this.items.push(item);
    const over = this.items.length - this.max;
    return over > 0 ? this.items.splice(0, over) : [];
  }

  /** Forget every item: they went out, or the stream ended. */
  clear(): void {
    this.items = [];
  }
}
