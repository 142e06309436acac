/**
 * The page's solve loop, in a dedicated worker: a 60 Hz timer sends the newest targets
 * over the session's WebSocket (the TypeScript client's `Stream`), pipelined up to
 * `MAX_IN_FLIGHT` frames without an answer, and posts each answer to the page, which
 * draws the newest one at its next animation frame.
 *
 * Why a worker: the page's main thread also draws, and without a GPU (headless Chromium
 * renders WebGL in software) a drawn frame holds it for 20-30 ms; a timer on that thread
 * then fires late or not at all (measured: 41 of 60 ticks a second on a loaded 2-core
 * machine, where a worker's timer kept 60). Here neither the ticks nor the socket wait
 * for a draw.
 */

import {
  Client,
  type CompactFrameResult,
  SessionGone,
  type Stream,
  StreamClosed,
  type Target,
} from "../../typescript/src/index.js";
import { type FromWorker, type Motion, type ToWorker, absoluteNow, motionOffset } from "./protocol.js";
import { FixedRate } from "./timing.js";

const SOLVE_HZ = 60;
// Frames sent without an answer yet: enough that a late answer does not stop the 60 Hz
// sends, few enough that what is drawn stays within ~4 frames of the targets.
const MAX_IN_FLIGHT = 4;

interface Open {
  generation: number;
  client: Client;
  session: { id: string; token: string };
  stream: Stream<CompactFrameResult>;
}

let current: Open | null = null;
let opening = 0; // the generation of the newest "open"
let targets: Target[] = [];
let motion: Motion | null = null;
let clipping = false;
let inFlight = 0;
let held = 0;
let ticks = 0;

function post(message: FromWorker): void {
  postMessage(message);
}

function errorText(error: unknown): string {
  return error instanceof Error ? error.message : String(error);
}

/** The targets to send now: as the page posted them, moved along the scripted drag. */
function targetsNow(atMs: number): Target[] {
  if (motion === null) return targets;
  const active = motion;
  return targets.map((target) => {
    const offset = motionOffset(active, target.effector, atMs);
    if (offset === null || target.position === undefined || target.position === null) return target;
    const { x, y, z } = target.position;
    return { ...target, position: { x: x + offset[0], y: y + offset[1], z: z + offset[2] } };
  });
}

async function solveOnce(open: Open, sent: Target[]): Promise<void> {
  const started = performance.now();
  const result = await open.stream.frame(sent);
  const roundTripMs = performance.now() - started;
  if (open !== current) return; // answered on a socket the page has since replaced
  post({
    kind: "answer",
    generation: open.generation,
    result,
    sent,
    roundTripMs,
    answeredAtMs: absoluteNow(),
    counters: { ticks, held, missed: loop.missed, inFlight, reconnects: open.stream.reconnects },
  });
}

function failed(open: Open, error: unknown): void {
  if (open !== current) return;
  const closed = error instanceof StreamClosed;
  // The client has already tried to reconnect: this socket is over (a switch or a reload
  // opens a new one).
  if (closed) current = null;
  const gone = error instanceof SessionGone;
  post({ kind: "error", generation: open.generation, message: errorText(error), closed, gone });
}

function tick(): void {
  ticks += 1;
  const open = current;
  if (open === null || clipping || targets.length === 0) return;
  if (inFlight >= MAX_IN_FLIGHT) {
    held += 1;
    return;
  }
  inFlight += 1;
  solveOnce(open, targetsNow(absoluteNow()))
    .catch((error: unknown) => failed(open, error))
    .finally(() => {
      if (open === current) inFlight -= 1;
    });
}

const loop = new FixedRate(SOLVE_HZ, tick);

function close(): void {
  const old = current;
  current = null;
  old?.stream.close();
  inFlight = 0;
  held = 0;
  ticks = 0;
  loop.missed = 0;
}

async function open(message: Extract<ToWorker, { kind: "open" }>): Promise<void> {
  close();
  opening = message.generation;
  const client = new Client(message.baseUrl, message.apiKey === undefined ? {} : { apiKey: message.apiKey });
  const stream: Stream<CompactFrameResult> = await client.stream(message.session, {
    encoding: message.encoding,
    compact: message.compact,
  });
  // Two opens in a row (two switches flipped at once): only the newest keeps its socket.
  if (message.generation !== opening) {
    stream.close();
    return;
  }
  current = { generation: message.generation, client, session: message.session, stream };
  post({ kind: "opened", generation: message.generation });
}

/** A planned clip on the socket, once the frames in flight are answered. */
async function clip(frames: Extract<ToWorker, { kind: "clip" }>): Promise<void> {
  const open = current;
  if (open === null) return;
  clipping = true;
  try {
    while (inFlight > 0 && open === current) await new Promise((r) => setTimeout(r, 5));
    await open.client.setPose(open.session, { q: frames.startQ }); // the plan starts where the recording did
    const answer = await open.stream.clip(frames.frames, { plan: true });
    if (open === current) post({ kind: "clip", generation: open.generation, clip: answer });
  } catch (error) {
    failed(open, error);
  } finally {
    clipping = false;
  }
}

onmessage = (event: MessageEvent<ToWorker>) => {
  const message = event.data;
  switch (message.kind) {
    case "open":
      open(message).catch((error: unknown) =>
        post({
          kind: "error",
          generation: message.generation,
          message: errorText(error),
          closed: true,
          gone: error instanceof SessionGone,
        }),
      );
      break;
    case "close":
      opening = -1; // an open still under way closes its socket (generations are >= 1)
      close();
      break;
    case "targets":
      targets = message.targets;
      break;
    case "motion":
      motion = message.motion;
      break;
    case "clip":
      void clip(message);
      break;
  }
};

loop.start();
