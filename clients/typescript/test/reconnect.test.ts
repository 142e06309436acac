/**
 * The reconnect budget (src/reconnect.ts): its rules on a clock the test moves, and for
 * real: a `python -m service` killed mid-stream and started again on its port later than
 * the old budget (6 tries, 50 ms doubling to 2 s: 3.15 s of waits) allowed. With the
 * sessions in Redis the stream resumes, every frame answered once and solved once;
 * without them, and for a deleted session, the client fails as soon as the server says
 * so, not when the budget runs out (the same as tests/live/test_slow_restart.py).
 *
 * The restart tests start their own servers (`PYTHON`, default `python3`, with the
 * service installed) and a `redis-server`; without redis-server the Redis test skips,
 * except under CI=true, where it fails.
 */

import assert from "node:assert/strict";
import type { ChildProcess } from "node:child_process";
import { after, describe, test } from "node:test";

import {
  Backoff,
  Client,
  DEFAULT_RECONNECT,
  NotFound,
  RECONNECT_OFF,
  RetryLater,
  SessionGone,
  type Target,
  delayMs,
  reconnectPolicy,
  retryAfterMs,
} from "../src/index.js";
import { Processes, freePort, redisOrSkip, serverUrl, stopServer } from "./server.js";
import { RETRY_AFTER_S, scripted } from "./scripted.js";

after(stopServer); // server.ts's shared server, if a test here started it

const PANDA = { format: "example", name: "panda_arm" } as const;
const OLD_BUDGET_MS = [0, 1, 2, 3, 4, 5].reduce((sum, n) => sum + Math.min(50 * 2 ** n, 2000), 0);
const RESTART_DELAY_MS = 5_000; // from the kill to the new process's start
const FAST_MS = 3_000; // a failure the server states is thrown within this
const N_FRAMES = 40;
const STOP_AT = 15;
const IN_FLIGHT = 4;
const FRAME_MS = 1000 / 60; // a game's pace

function tool(k: number): Target[] {
  return [{ effector: "tool", position: { x: 0.45, y: -0.1 + 0.005 * k, z: 0.45 }, orientation: { w: 0, x: 1, y: 0, z: 0 } }];
}

const sleep = (ms: number) => new Promise((resolve) => setTimeout(resolve, ms));

function waitsUntilGivenUp(backoff: Backoff, clock: { now: number }): number[] {
  const waits: number[] = [];
  for (let wait = backoff.nextWaitMs(); wait !== null; wait = backoff.nextWaitMs()) {
    waits.push(wait);
    clock.now += wait;
    assert.ok(waits.length < 10_000, "never gave up");
  }
  return waits;
}

describe("reconnect budget", () => {
  test("waits double up to the cap and stop at the deadline", () => {
    const clock = { now: 100 };
    const policy = reconnectPolicy({ deadlineMs: 10_000, jitter: 0 });
    const waits = waitsUntilGivenUp(new Backoff(policy, () => clock.now), clock);
    assert.deepEqual(waits.slice(0, 6), [100, 200, 400, 800, 1600, 2000]);
    assert.ok(Math.abs(waits.reduce((a, b) => a + b, 0) - 10_000) < 1e-6);
  });

  test("the default outlasts a slow restart; a server back is tried within maxDelayMs", () => {
    assert.equal(OLD_BUDGET_MS, 3150);
    const clock = { now: 0 };
    const waits = waitsUntilGivenUp(new Backoff(reconnectPolicy(), () => clock.now), clock);
    assert.ok(Math.abs(waits.reduce((a, b) => a + b, 0) - DEFAULT_RECONNECT.deadlineMs) < 1e-6);
    assert.ok(Math.max(...waits) <= DEFAULT_RECONNECT.maxDelayMs);
  });

  test("jitter takes up to its share of each wait", () => {
    const policy = reconnectPolicy({ initialDelayMs: 1000, maxDelayMs: 1000, jitter: 0.5 });
    assert.equal(delayMs(policy, 0, () => 0), 1000);
    assert.equal(delayMs(policy, 0, () => 0.999999), 1000 * (1 - 0.5 * 0.999999));
    const draws = Array.from({ length: 2000 }, () => delayMs(policy, 0));
    assert.ok(Math.min(...draws) >= 500 && Math.max(...draws) <= 1000);
  });

  test("Retry-After is honoured within the deadline and ends it beyond", () => {
    const clock = { now: 0 };
    const backoff = new Backoff(reconnectPolicy({ deadlineMs: 10_000, jitter: 0 }), () => clock.now);
    assert.equal(backoff.nextWaitMs(3000), 3000); // longer than maxDelayMs: honoured
    clock.now += 3000;
    assert.equal(backoff.nextWaitMs(7500), null); // past the deadline: give up now
    assert.equal(retryAfterMs("1"), 1000);
    assert.equal(retryAfterMs("soon"), null);
    assert.equal(retryAfterMs(null), null);
  });

  test("an answer gives the whole budget back; off and attempts", () => {
    const clock = { now: 0 };
    const backoff = new Backoff(reconnectPolicy({ deadlineMs: 5000, jitter: 0 }), () => clock.now);
    assert.equal(backoff.nextWaitMs(), 100);
    clock.now += 4000;
    backoff.answered();
    assert.equal(backoff.recovering, false);
    assert.equal(backoff.nextWaitMs(), 100);
    assert.equal(new Backoff(reconnectPolicy(RECONNECT_OFF)).nextWaitMs(), null);
    assert.equal(new Backoff(reconnectPolicy({ attempts: 0 })).nextWaitMs(), null);
    const three = new Backoff(reconnectPolicy({ attempts: 3, jitter: 0 }), () => clock.now);
    assert.equal(waitsUntilGivenUp(three, clock).length, 3);
    assert.throws(() => reconnectPolicy({ jitter: 2 }), /reconnect\.jitter/);
    assert.throws(() => reconnectPolicy({ deadlineMs: -1 }), /reconnect\.deadlineMs/);
    assert.throws(() => reconnectPolicy({ deadlineMs: Number.NaN }), /reconnect\.deadlineMs/);
  });

  test("keeps the default of a field given as undefined", () => {
    // What a caller's own optional settings pass on: `{ deadlineMs: config.deadlineMs }`.
    const policy = reconnectPolicy({ deadlineMs: undefined, jitter: undefined, maxDelayMs: 500 });
    assert.deepEqual(policy, { ...DEFAULT_RECONNECT, maxDelayMs: 500 });
  });
});

describe("error answers that are part of an outage", () => {
  const quick = { initialDelayMs: 10, maxDelayMs: 50 };

  test("not_ready after a drop is the restart warming up: sent again, after its retry_after_s", async () => {
    const fake = await scripted((conn, id) => (conn === 0 ? (id === 0 ? "pong" : "drop") : conn === 1 ? "not_ready" : "pong"));
    try {
      const stream = await fake.client.stream({ id: "s", token: "t" }, { reconnect: quick });
      await stream.ping();
      await stream.ping(); // dropped, then not_ready, then answered
      assert.equal(stream.reconnects, 2);
      assert.deepEqual(fake.seen, [[0, 0], [0, 1], [1, 1], [2, 1]]);
      assert.ok(fake.opened[2]! - fake.answeredAt.get(1)! >= RETRY_AFTER_S * 1000 - 1);
      stream.close();
    } finally {
      fake.close();
    }
  });

  test("shutting_down is sent again on a new connection", async () => {
    const fake = await scripted((conn, id) => (conn === 0 && id === 1 ? "shutting_down" : "pong"));
    try {
      const stream = await fake.client.stream({ id: "s", token: "t" }, { reconnect: quick });
      for (let i = 0; i < 3; i++) await stream.ping();
      assert.equal(stream.reconnects, 1);
      assert.deepEqual(fake.seen, [[0, 0], [0, 1], [1, 1], [1, 2]]);
      stream.close();
    } finally {
      fake.close();
    }
  });

  for (const [code, reconnect] of [
    ["not_ready", quick], // a stream opened on a warming server: no outage of ours
    ["shutting_down", RECONNECT_OFF], // reconnecting off: the caller decides
  ] as const) {
    test(`otherwise the caller gets ${code} (${reconnect === RECONNECT_OFF ? "reconnecting off" : "no drop before"})`, async () => {
      const fake = await scripted((_, id) => (id === 0 ? code : "pong"));
      try {
        const stream = await fake.client.stream({ id: "s", token: "t" }, { reconnect });
        const refused = await stream.ping().catch((e: unknown) => e);
        assert.ok(refused instanceof RetryLater && refused.code === code && refused.retryAfterS === RETRY_AFTER_S, String(refused));
        await stream.ping();
        assert.equal(stream.reconnects, 0);
        stream.close();
      } finally {
        fake.close();
      }
    });
  }
});

/** Kill `child` now, and start a service on `port` RESTART_DELAY_MS later: the time it is ready. */
async function restartLater(processes: Processes, child: ChildProcess, port: number, env: Record<string, string>): Promise<number> {
  child.kill("SIGKILL");
  await sleep(RESTART_DELAY_MS);
  await processes.service(port, env);
  return performance.now();
}

/** Stream N_FRAMES frames, IN_FLIGHT at a time at FRAME_MS, calling `stop` after STOP_AT answers. */
async function streamAcross(
  client: Client,
  session: { id: string; token: string },
  stop: () => void,
): Promise<{ answered: Map<number, number>; at: number[] }> {
  const stream = await client.stream(session); // the default budget
  const answered = new Map<number, number>();
  const at: number[] = [];
  try {
    let sent = 0;
    while (answered.size < N_FRAMES) {
      while (sent < N_FRAMES && sent - answered.size < IN_FLIGHT) {
        stream.sendFrame(tool(sent));
        sent += 1;
      }
      const answer = await stream.receive();
      await sleep(FRAME_MS);
      answered.set(answer.id, (answered.get(answer.id) ?? 0) + 1);
      at.push(performance.now());
      if (answered.size === STOP_AT) stop();
    }
  } finally {
    stream.close();
  }
  return { answered, at };
}

describe("a restart slower than the old budget", { timeout: 180_000 }, () => {
  test("with the sessions in Redis the stream resumes: every frame answered once, solved once", async (t) => {
    if (!redisOrSkip(t)) return;
    const processes = new Processes();
    try {
      const { port, env, first } = await processes.serviceWithRedis();
      const client = new Client(`http://127.0.0.1:${port}`);
      const session = await client.createSession(PANDA);
      let restarted: Promise<number> | undefined;
      let stoppedAt = 0;
      const { answered, at } = await streamAcross(client, session, () => {
        stoppedAt = performance.now();
        restarted = restartLater(processes, first, port, env);
      });
      const readyAt = await restarted!;
      assert.deepEqual([...answered.keys()].sort((a, b) => a - b), Array.from({ length: N_FRAMES }, (_, i) => i));
      assert.deepEqual(new Set(answered.values()), new Set([1]), "a frame answered twice");
      const gap = Math.max(...at.slice(1).map((t1, i) => t1 - at[i]!));
      assert.ok(gap > OLD_BUDGET_MS, `the longest wait for an answer, ${gap} ms`);
      assert.ok(readyAt - stoppedAt > OLD_BUDGET_MS);
      assert.equal((await client.getSession(session)).counters.frames, N_FRAMES); // solved once each
    } finally {
      processes.stop();
    }
  });

  test("without Redis the session is gone after the restart: SessionGone as soon as the server is back", async () => {
    const processes = new Processes();
    try {
      const port = await freePort();
      const first = await processes.service(port, {});
      const client = new Client(`http://127.0.0.1:${port}`);
      const session = await client.createSession(PANDA);
      let restarted: Promise<number> | undefined;
      const gone = await streamAcross(client, session, () => {
        restarted = restartLater(processes, first, port, {});
      }).catch((e: unknown) => e);
      const raisedAt = performance.now();
      const readyAt = await restarted!;
      assert.ok(gone instanceof SessionGone && gone.closeCode === 4404, String(gone));
      assert.ok(raisedAt - readyAt < FAST_MS, `thrown ${raisedAt - readyAt} ms after the server was ready`);
    } finally {
      processes.stop();
    }
  });

  test("a deleted session fails fast, over the stream and over HTTP", async () => {
    const client = new Client(await serverUrl());
    const session = await client.createSession(PANDA);
    const stream = await client.stream(session);
    await stream.frame(tool(0));
    await client.deleteSession(session);
    const t0 = performance.now();
    const gone = await stream.frame(tool(1)).catch((e: unknown) => e);
    assert.ok(gone instanceof SessionGone, String(gone));
    assert.equal(stream.reconnects, 0);
    const missing = await client.frame(session, tool(2), { id: 2 }).catch((e: unknown) => e);
    assert.ok(missing instanceof NotFound, String(missing));
    assert.ok(performance.now() - t0 < FAST_MS);
  });
});
