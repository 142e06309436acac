/**
 * What a stream holds while it reconnects (src/queued.ts): at most `maxQueued` messages
 * sent meanwhile wait for the new connection, the oldest beyond that reject with
 * `MessageDropped` and never go out, and every message that did go out before the drop
 * is sent again and answered exactly once. Against a scripted server that refuses
 * connections while it is "down", and a real `python -m service` (sessions in Redis)
 * killed while a game keeps sending at 60 Hz and started again 5 s later.
 */

import assert from "node:assert/strict";
import { after, describe, test } from "node:test";

import { Client, DEFAULT_MAX_QUEUED, MessageDropped, type Stream, StreamState, type Target } from "../src/index.js";
import { scripted } from "./scripted.js";
import { Processes, redisOrSkip, stopServer } from "./server.js";

after(stopServer);

const QUICK = { initialDelayMs: 10, maxDelayMs: 50 };
const sleep = (ms: number) => new Promise((resolve) => setTimeout(resolve, ms));

async function until(condition: () => boolean, limitMs = 5_000): Promise<void> {
  const deadline = performance.now() + limitMs;
  while (!condition()) {
    assert.ok(performance.now() < deadline, "timed out");
    await sleep(5);
  }
}

/** Each promise's outcome: its value's id, or the error it rejected with. */
function settle<T extends { id: number }>(answers: Promise<T>[]): Promise<(number | unknown)[]> {
  return Promise.all(answers.map((answer) => answer.then((value) => value.id, (error: unknown) => error)));
}

describe("messages sent while reconnecting", () => {
  // The server drops the connection on message 1 (it was sent: it must be answered),
  // then refuses new connections until the test lets it up again.
  async function outage(maxQueued: number, sentMeanwhile: number) {
    const fake = await scripted((conn, id) => (conn === 0 && id === 1 ? "drop" : "pong"));
    const stream = await fake.client.stream({ id: "s", token: "t" }, { reconnect: QUICK, maxQueued });
    await stream.ping();
    fake.state.down = true;
    stream.sendPing(); // id 1: goes out, and the server drops the connection
    await until(() => stream.state === StreamState.Reconnecting);
    const ids = Array.from({ length: sentMeanwhile }, () => stream.sendPing());
    const queuedPeak = stream.queued;
    fake.state.down = false;
    const answers = await settle(Array.from({ length: 1 + sentMeanwhile }, () => stream.receive()));
    stream.close();
    fake.close();
    return { fake, stream, ids, answers, queuedPeak };
  }

  test("the newest maxQueued go out; the older reject with MessageDropped and are never sent", async () => {
    const { fake, stream, ids, answers, queuedPeak } = await outage(3, 5);
    assert.deepEqual(ids, [2, 3, 4, 5, 6]);
    assert.equal(queuedPeak, 3);
    assert.equal(answers[0], 1); // sent before the drop: sent again, answered
    for (const [k, dropped] of answers.slice(1, 3).entries()) {
      assert.ok(dropped instanceof MessageDropped, String(dropped));
      assert.equal(dropped.id, 2 + k);
      assert.equal(dropped.maxQueued, 3);
    }
    assert.deepEqual(answers.slice(3), [4, 5, 6]);
    const reconnected = fake.seen.filter(([conn]) => conn === 1).map(([, id]) => id);
    assert.deepEqual(reconnected, [1, 4, 5, 6]); // 2 and 3 never reached the server
    assert.equal(stream.inFlight, 0);
    assert.equal(stream.queued, 0);
  });

  test("maxQueued 0: every message sent while reconnecting is dropped at once", async () => {
    const { fake, answers } = await outage(0, 4);
    assert.equal(answers[0], 1);
    assert.ok(answers.slice(1).every((a) => a instanceof MessageDropped));
    assert.deepEqual(fake.seen.filter(([conn]) => conn === 1), [[1, 1]]);
  });

  test("Infinity keeps every message, as before the limit", async () => {
    const { fake, answers } = await outage(Number.POSITIVE_INFINITY, 200);
    assert.deepEqual(answers, Array.from({ length: 201 }, (_, k) => 1 + k));
    assert.equal(fake.seen.filter(([conn]) => conn === 1).length, 201);
  });

  test("the default is DEFAULT_MAX_QUEUED", async () => {
    const { answers } = await outage(DEFAULT_MAX_QUEUED, DEFAULT_MAX_QUEUED + 2);
    const dropped = answers.filter((a) => a instanceof MessageDropped) as MessageDropped[];
    assert.deepEqual(dropped.map((d) => d.id), [2, 3]);
    assert.equal(DEFAULT_MAX_QUEUED, 60);
  });

  for (const bad of [-1, 1.5, Number.NaN]) {
    test(`maxQueued ${bad} is refused before anything opens`, async () => {
      const fake = await scripted(() => "pong");
      try {
        await assert.rejects(fake.client.stream({ id: "s", token: "t" }, { maxQueued: bad }), RangeError);
        assert.equal(fake.opened.length, 0);
      } finally {
        fake.close();
      }
    });
  }
});

const PANDA = { format: "example", name: "panda_arm" } as const;
const FRAME_MS = 1000 / 60;
const RESTART_DELAY_MS = 5_000;

function tool(k: number): Target[] {
  const y = -0.1 + 0.0005 * (k % 400);
  return [{ effector: "tool", position: { x: 0.45, y, z: 0.45 }, orientation: { w: 0, x: 1, y: 0, z: 0 } }];
}

interface Sent {
  id: number;
  state: StreamState; // when it was sent
  outcome: Promise<number | unknown>; // the answer's id, or the rejection
}

/** A game's loop: a frame every FRAME_MS whatever the stream's state, until `stop()`. */
function game(stream: Stream): { sent: Sent[]; queuedPeak: () => number; stop: () => void } {
  const sent: Sent[] = [];
  let peak = 0;
  const timer = setInterval(() => {
    const state = stream.state;
    if (state === StreamState.Closed) return;
    const k = sent.length;
    const outcome = stream.frame(tool(k)).then((result) => result.id, (error: unknown) => error);
    sent.push({ id: k, state, outcome });
    peak = Math.max(peak, stream.queued);
  }, FRAME_MS);
  return { sent, queuedPeak: () => peak, stop: () => clearInterval(timer) };
}

describe("a game that keeps sending through a server restart", { timeout: 180_000 }, () => {
  test("at most maxQueued wait; every frame that went out is answered once and solved once", async (t) => {
    if (!redisOrSkip(t)) return;
    const processes = new Processes();
    try {
      const { port, env, first } = await processes.serviceWithRedis();
      const client = new Client(`http://127.0.0.1:${port}`);
      const session = await client.createSession(PANDA);
      const stream = await client.stream(session); // the default budget and maxQueued
      const loop = game(stream);
      await sleep(500);
      first.kill("SIGKILL");
      await sleep(RESTART_DELAY_MS);
      await processes.service(port, env);
      await until(() => stream.state === StreamState.Open && stream.queued === 0, 30_000);
      await sleep(500);
      loop.stop();
      const outcomes = await Promise.all(loop.sent.map((s) => s.outcome));
      stream.close();

      const answered = loop.sent.filter((s, k) => outcomes[k] === s.id);
      const dropped = loop.sent.filter((_, k) => outcomes[k] instanceof MessageDropped);
      const other = outcomes.filter((o, k) => o !== loop.sent[k]!.id && !(o instanceof MessageDropped));
      assert.deepEqual(other, [], "every frame answered or dropped, nothing else");
      assert.ok(dropped.every((s) => s.state === StreamState.Reconnecting), "only frames held back are dropped");
      assert.ok(loop.queuedPeak() <= DEFAULT_MAX_QUEUED, `${loop.queuedPeak()} held at once`);
      // Five seconds and more of a 60 Hz game: far more than the limit, most dropped;
      // the newest held went out on the new connection.
      const held = loop.sent.filter((s) => s.state === StreamState.Reconnecting);
      assert.ok(dropped.length > held.length / 2, `${dropped.length} of ${held.length} dropped`);
      assert.ok(held.length - dropped.length <= DEFAULT_MAX_QUEUED * stream.reconnects);
      assert.equal(outcomes[held.at(-1)!.id], held.at(-1)!.id);
      // Solved once each (the stored answers of a frame solved before the kill).
      assert.equal((await client.getSession(session)).counters.frames, answered.length);
      t.diagnostic(
        `sent ${loop.sent.length}, while reconnecting ${held.length}, dropped ${dropped.length}, ` +
          `answered ${answered.length}, held at most ${loop.queuedPeak()}, reconnects ${stream.reconnects}`,
      );
    } finally {
      processes.stop();
    }
  });
});
