/**
 * The service the tests talk to: `IK_BASE_URL` when set (the pytest wrapper,
 * tests/clients/test_typescript_client.py, passes its live server's), else a
 * `python -m service` started here from the repository root on a free 127.0.0.1 port,
 * polled on /readyz (bounded) and stopped when the tests end.
 */

import assert from "node:assert/strict";
import { type ChildProcess, execFileSync, spawn } from "node:child_process";
import { connect, createServer } from "node:net";
import type { TestContext } from "node:test";
import { fileURLToPath } from "node:url";

const READY_TIMEOUT_MS = 240_000;
const REPO_ROOT = fileURLToPath(new URL("../../../../", import.meta.url)); // from dist/test/

/** A TCP port on 127.0.0.1 that nothing listens on right now. */
export function freePort(): Promise<number> {
  return new Promise((resolve, reject) => {
    const probe = createServer();
    probe.once("error", reject);
    probe.listen(0, "127.0.0.1", () => {
      const address = probe.address();
      probe.close(() => (typeof address === "object" && address ? resolve(address.port) : reject(new Error("no port"))));
    });
  });
}

/** Poll `${base}/readyz` until it answers 200 (bounded); throws if `child` exits first. */
export async function waitReady(base: string, child: ChildProcess): Promise<void> {
  const deadline = Date.now() + READY_TIMEOUT_MS;
  while (Date.now() < deadline) {
    if (child.exitCode !== null) throw new Error(`python -m service exited with ${child.exitCode}`);
    try {
      if ((await fetch(`${base}/readyz`, { signal: AbortSignal.timeout(2000) })).ok) return;
    } catch {
      // not listening yet
    }
    await new Promise((r) => setTimeout(r, 200));
  }
  throw new Error(`python -m service not ready in ${READY_TIMEOUT_MS} ms`);
}

/** `python -m service` on 127.0.0.1:`port` with `env` added (`PYTHON`: the interpreter,
 * default `python3`), its output on this process's. */
export function spawnService(port: number, env: Record<string, string> = {}): ChildProcess {
  return spawn(process.env["PYTHON"] ?? "python3", ["-m", "service"], {
    cwd: REPO_ROOT,
    env: { ...process.env, IK_HOST: "127.0.0.1", IK_PORT: String(port), ...env },
    stdio: ["ignore", "inherit", "inherit"],
  });
}

let started: Promise<string> | undefined;
let child: ChildProcess | undefined;

/** Stop the server started here, if any (the test file's `after` hook). */
export function stopServer(): void {
  child?.kill("SIGTERM");
}

/** The base URL, e.g. `http://127.0.0.1:8123`. */
export function serverUrl(): Promise<string> {
  const given = process.env["IK_BASE_URL"];
  if (given) return Promise.resolve(given);
  started ??= (async () => {
    const port = await freePort();
    child = spawnService(port);
    const server = child;
    process.on("exit", () => server.kill("SIGTERM")); // also when a test throws
    const base = `http://127.0.0.1:${port}`;
    await waitReady(base, server);
    return base;
  })();
  return started;
}

/** Whether a `redis-server` can be started here. */
export function hasRedis(): boolean {
  try {
    execFileSync("redis-server", ["--version"], { stdio: "ignore" });
    return true;
  } catch {
    return false;
  }
}

/** Whether the test can go on: false after skipping it where `redis-server` is missing
 * (a failure under CI=true, whose runner installs it). */
export function redisOrSkip(t: TestContext): boolean {
  if (hasRedis()) return true;
  if (process.env["CI"] === "true") assert.fail("redis-server is not installed (CI=true)");
  t.skip("redis-server is not installed");
  return false;
}

/** Wait (bounded) until something listens on 127.0.0.1:`port`. */
export async function waitPort(port: number, limitMs = 10_000): Promise<void> {
  const deadline = Date.now() + limitMs;
  while (Date.now() < deadline) {
    const open = await new Promise<boolean>((resolve) => {
      const socket = connect(port, "127.0.0.1");
      socket.once("connect", () => (socket.destroy(), resolve(true)));
      socket.once("error", () => resolve(false));
    });
    if (open) return;
    await new Promise((r) => setTimeout(r, 50));
  }
  throw new Error(`nothing listens on 127.0.0.1:${port}`);
}

/** Every process a test started, stopped when the test ends. */
export class Processes {
  private all: ChildProcess[] = [];

  add(child: ChildProcess): ChildProcess {
    this.all.push(child);
    return child;
  }

  /** A `redis-server` on a free 127.0.0.1 port, no persistence: its URL. */
  async redis(): Promise<string> {
    const port = await freePort();
    const args = ["--port", String(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no"];
    this.add(spawn("redis-server", args, { stdio: "ignore" }));
    await waitPort(port);
    return `redis://127.0.0.1:${port}/0`;
  }

  async service(port: number, env: Record<string, string>): Promise<ChildProcess> {
    const child = this.add(spawnService(port, env));
    await waitReady(`http://127.0.0.1:${port}`, child);
    return child;
  }

  /** A service on a free port with its sessions in a Redis of its own: the port, the
   * environment to start it again with, and its process. */
  async serviceWithRedis(): Promise<{ port: number; env: Record<string, string>; first: ChildProcess }> {
    const env = { IK_REDIS_URL: await this.redis() };
    const port = await freePort();
    return { port, env, first: await this.service(port, env) };
  }

  stop(): void {
    for (const child of this.all) if (child.exitCode === null && child.signalCode === null) child.kill("SIGKILL");
  }
}
