/**
 * The messages between the page (main.ts) and its solve worker (worker.ts), and the
 * scripted drag both of them compute (the worker for the targets it sends, the page for
 * where it draws the handles).
 *
 * Times are absolute (`performance.timeOrigin + performance.now()`, ms): a worker's
 * `performance.now()` counts from the worker's own start, not the page's.
 */

import type { CompactFrameResult, Encoding, Frame, FrameResults, SessionCreated, Target } from "../../typescript/src/index.js";

export type Vec = [number, number, number];

/** Milliseconds since the epoch, comparable between the page and the worker. */
export function absoluteNow(): number {
  return performance.timeOrigin + performance.now();
}

/** A drag of every effector along a circle, up from where it rests and back (the
 * benchmark's steady motion): per effector, the circle's `up` and `forward` directions in
 * the frame targets are sent in, and its phase. */
export interface Motion {
  startMs: number;
  radiusM: number;
  hz: number;
  circles: Record<string, { up: Vec; forward: Vec; phase: number }>;
}

/** Where a moving effector is, relative to its rest, `atMs` into `motion`. */
export function motionOffset(motion: Motion, name: string, atMs: number): Vec | null {
  const circle = motion.circles[name];
  if (circle === undefined) return null;
  const angle = 2 * Math.PI * motion.hz * ((atMs - motion.startMs) / 1000) + circle.phase;
  const along = motion.radiusM * (1 - Math.cos(angle));
  const across = motion.radiusM * Math.sin(angle);
  return [0, 1, 2].map((i) => along * circle.up[i]! + across * circle.forward[i]!) as Vec;
}

export type ToWorker =
  /** Open a stream on `session` (closing the one before); its answers carry `generation`. */
  | {
      kind: "open";
      generation: number;
      baseUrl: string;
      apiKey: string | undefined;
      session: SessionCreated;
      encoding: Encoding;
      compact: boolean;
    }
  | { kind: "close" }
  /** The targets as the handles stand: sent at every tick until the next ones. */
  | { kind: "targets"; targets: Target[] }
  /** Move the targets along circles from where they stand now (null: stop). */
  | { kind: "motion"; motion: Motion | null }
  /** Set the pose to `startQ` and solve `frames` as one planned clip, ticks held meanwhile. */
  | { kind: "clip"; frames: Frame[]; startQ: number[] };

/** The solve loop's counters since its stream opened. */
export interface LoopCounters {
  /** Timer ticks; ticks that sent nothing because the window was full; deadlines the
   * timer missed (fired over a period late). */
  ticks: number;
  held: number;
  missed: number;
  inFlight: number;
  reconnects: number;
}

export type FromWorker =
  | {
      kind: "answer";
      generation: number;
      result: CompactFrameResult;
      sent: Target[];
      roundTripMs: number;
      answeredAtMs: number;
      counters: LoopCounters;
    }
  | { kind: "opened"; generation: number }
  | { kind: "clip"; generation: number; clip: FrameResults<CompactFrameResult> }
  /** `closed`: the stream is over (the client gave up reconnecting); `gone`: because the
   * session is (the server restarted with sessions in memory, or it expired). */
  | { kind: "error"; generation: number; message: string; closed: boolean; gone: boolean };
