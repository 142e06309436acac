/**
 * A scripted WebSocket server on 127.0.0.1 for the stream's tests: it acts on each
 * message as told, notes what it saw and when, and refuses new connections (503) while
 * `down` is set, as a balancer with no worker up does.
 */

import { WebSocketServer, type WebSocket as NodeWebSocket } from "ws";

import { Client } from "../src/index.js";

export const RETRY_AFTER_S = 0.3;

/** A WebSocket server on 127.0.0.1 that acts on each message as `script` says (for a
 * connection number and a message id: "pong", "drop" the connection, or an error code
 * with `retry_after_s` RETRY_AFTER_S), noting what it saw and when; while `state.down`
 * it refuses new connections with a 503. */
export async function scripted(script: (conn: number, id: number) => string) {
  const state = { down: false };
  const server = new WebSocketServer({
    host: "127.0.0.1",
    port: 0,
    verifyClient: (_info, accept) => (state.down ? accept(false, 503) : accept(true)),
  });
  const seen: [number, number][] = [];
  const opened: number[] = [];
  const answeredAt = new Map<number, number>();
  server.on("connection", (socket: NodeWebSocket) => {
    const conn = opened.length;
    opened.push(performance.now());
    socket.on("message", (data) => {
      const id = (JSON.parse(String(data)) as { id: number }).id;
      seen.push([conn, id]);
      const action = script(conn, id);
      if (action === "drop") socket.terminate();
      else if (action === "pong") socket.send(JSON.stringify({ id, type: "pong" }));
      else {
        socket.send(JSON.stringify({ id, type: "result", success: false, error: { code: action, message: action, retry_after_s: RETRY_AFTER_S } }));
        answeredAt.set(conn, performance.now());
      }
    });
  });
  await new Promise((resolve) => server.once("listening", resolve));
  const { port } = server.address() as { port: number };
  return { client: new Client(`http://127.0.0.1:${port}`), state, seen, opened, answeredAt, close: () => server.close() };
}

