// The client imports `ws` only in Node (no global WebSocket); the page never does.
export declare const WebSocket: unknown;
