/**
 * /demo: a character whose hands and feet follow draggable targets, solved by the service
 * over a session's WebSocket (the TypeScript client's `Stream`).
 *
 * Solving and drawing run apart, as in a game: a worker (worker.ts) owns the socket and
 * sends the targets the page last posted on a 60 Hz timer (pipelined, at most 4 frames
 * without an answer), and each animation frame here draws the newest answer. Without a
 * GPU (headless Chromium renders WebGL in software) the page draws 30-50 frames/s; the
 * solves do not wait for it.
 *
 * `window.ikDemo` exposes the page's state for tests and the browser benchmark
 * (tests/live/test_demo_browser.py, bench/demo_browser.py): answered and drawn frames,
 * round trips, where the effectors (and the knee the pole pulls) are in the scene graph,
 * and the handles' screen positions.
 */

import * as THREE from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";

import {
  AuthError,
  Client,
  type CompactFrameResult,
  type Chain,
  type CreateSessionOptions,
  type Encoding,
  type Frame,
  type FrameResults,
  NotFound,
  RetryLater,
  type SessionCreated,
  type Target,
} from "../../typescript/src/json.js"; // HTTP only here: no MessagePack in this bundle
import { Character, EFFECTORS, type EffectorName } from "./character.js";
import { ExampleChain } from "./examples.js";
import { drawPaths } from "./paths.js";
import { Readout, largestStep } from "./readout.js";
import { type FromWorker, type LoopCounters, type Motion, type ToWorker, type Vec, absoluteNow, motionOffset } from "./protocol.js";
import { RateMeter } from "./timing.js";

const API_KEY_STORAGE = "ik-demo-api-key";
const MAX_RECORDED_FRAMES = 600; // the server's default IK_MAX_FRAMES_PER_REQUEST
const HANDLE_COLOURS: Record<EffectorName, number> = {
  hand_L: 0xe6194b,
  hand_R: 0x4363d8,
  foot_L: 0xf58231,
  foot_R: 0x3cb44b,
};

/** What the page exposes as `window.ikDemo.state`. */
interface DemoState {
  ready: boolean;
  /** Whether the left foot's target carries the pole handle (the server knows `pole`). */
  poles: boolean;
  /** "character" or an example chain's name. */
  model: string;
  encoding: Encoding;
  compact: boolean;
  frames: number;
  solved: number;
  /** Round trips [ms] (last 600 frames), as the readout's percentiles use them. */
  roundTripsMs: number[];
  /** Since the last `resetStats()`: each answer's round trip [ms], server_us, solve_us;
   * answers solved; frames drawn; the worker's timer ticks that sent nothing because 4
   * frames were waiting (`held`), and its deadlines missed (`missed`: it fired over a
   * period late, a busy machine). */
  samples: {
    roundTripMs: number[];
    serverUs: number[];
    solveUs: number[];
    solved: number;
    drawn: number;
    held: number;
    missed: number;
    since: number;
  };
  last: { termination: string; solve_us: number; server_us: number; round_trip_ms: number; largest_step_rad: number } | null;
  /** Effector bones' world positions, read off the scene graph after applying the answer. */
  effectors: Record<string, Vec>;
  /** The same for the bone the pole target pulls (the left knee: `shin_L`'s origin). */
  poleBone: Vec | null;
  targets: Record<string, Vec>;
  errors: string[];
  /** The solve worker's view of its socket: frames without an answer, reconnects, timer ticks. */
  socket: { open: boolean; inFlight: number; reconnects: number; ticks: number };
  /** Over the last second: answers handled and frames drawn, per second. */
  rates: { solvesPerS: number; drawnPerS: number };
  clip: { recorded: number; planned: number; largest_step_rad: number; tracked_largest_step_rad: number } | null;
}

function emptySamples(): DemoState["samples"] {
  return { roundTripMs: [], serverUs: [], solveUs: [], solved: 0, drawn: 0, held: 0, missed: 0, since: performance.now() };
}

const body = document.body;
const root = body.dataset["root"] ?? "";
const assets = body.dataset["assets"] ?? "/demo-assets";

const state: DemoState = {
  ready: false,
  poles: false,
  model: "character",
  encoding: "json",
  compact: false,
  frames: 0,
  solved: 0,
  roundTripsMs: [],
  samples: emptySamples(),
  last: null,
  effectors: {},
  poleBone: null,
  targets: {},
  errors: [],
  socket: { open: false, inFlight: 0, reconnects: 0, ticks: 0 },
  rates: { solvesPerS: 0, drawnPerS: 0 },
  clip: null,
};

// --- scene ---------------------------------------------------------------------------------
const view = document.getElementById("view")!;
// No antialiasing, and a frame is drawn only when something moved: without a GPU
// (headless Chromium renders WebGL in software) a drawn frame costs 20-30 ms of CPU, which
// the server and the solve worker share on a small machine.
const renderer = new THREE.WebGLRenderer({ antialias: false });
renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
let needsRender = true;
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xf4f5f7);
scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8f99, 2.0));
const sun = new THREE.DirectionalLight(0xffffff, 1.5);
sun.position.set(2, 4, 3);
scene.add(sun);
scene.add(new THREE.GridHelper(4, 20, 0xb0b4bc, 0xd8dbe0));
const camera = new THREE.PerspectiveCamera(40, 1, 0.05, 50);
camera.position.set(1.2, 1.5, 3.2);
const orbit = new OrbitControls(camera, renderer.domElement);
orbit.target.set(0, 0.9, 0);
orbit.update();
orbit.addEventListener("change", () => (needsRender = true));

function resize(): void {
  const { clientWidth: width, clientHeight: height } = view;
  renderer.setSize(width, height);
  camera.aspect = width / Math.max(1, height);
  camera.updateProjectionMatrix();
  needsRender = true;
}
window.addEventListener("resize", resize);
resize();

// --- handles -------------------------------------------------------------------------------
const handles = new Map<string, THREE.Mesh>();
const handleGeometry = new THREE.SphereGeometry(0.05, 20, 14);

function addHandle(name: string, colour: number, at: THREE.Vector3, opacity = 0.85): THREE.Mesh {
  const material = new THREE.MeshStandardMaterial({ color: colour, transparent: true, opacity });
  const mesh = new THREE.Mesh(handleGeometry, material);
  mesh.name = name;
  mesh.position.copy(at);
  scene.add(mesh);
  handles.set(name, mesh);
  return mesh;
}

// The pole target (which way the left knee points): a target's `pole` field, sent only when
// the server's schema has it (it came with a later version of the API); otherwise the
// handle is drawn but not sent, and the readout says so.
const POLE = "pole_knee_L";
const POLE_BONE = "shin_L";
let polesSupported = false;

async function serverHasPoles(): Promise<boolean> {
  const response = await fetch(`${root}/openapi.json`);
  if (!response.ok) return false;
  const spec = (await response.json()) as { components?: { schemas?: Record<string, { properties?: object }> } };
  return "pole" in (spec.components?.schemas?.["Target"]?.properties ?? {});
}

// --- dragging ------------------------------------------------------------------------------
const pointer = new THREE.Vector2();
const raycaster = new THREE.Raycaster();
const dragPlane = new THREE.Plane();
let dragging: THREE.Mesh | null = null;

function pointerRay(event: PointerEvent): void {
  const rect = renderer.domElement.getBoundingClientRect();
  pointer.set(((event.clientX - rect.left) / rect.width) * 2 - 1, -((event.clientY - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(pointer, camera);
}

renderer.domElement.addEventListener("pointerdown", (event) => {
  pointerRay(event);
  const hit = raycaster.intersectObjects([...handles.values()], false)[0];
  if (hit === undefined) return;
  dragging = hit.object as THREE.Mesh;
  orbit.enabled = false;
  // Drag in the plane through the handle that faces the camera.
  dragPlane.setFromNormalAndCoplanarPoint(camera.getWorldDirection(new THREE.Vector3()), dragging.position);
  renderer.domElement.setPointerCapture(event.pointerId);
});
renderer.domElement.addEventListener("pointermove", (event) => {
  if (dragging === null) return;
  pointerRay(event);
  const at = raycaster.ray.intersectPlane(dragPlane, new THREE.Vector3());
  if (at !== null) dragging.position.copy(at);
  needsRender = true;
  postTargets();
});
renderer.domElement.addEventListener("pointerup", () => {
  dragging = null;
  orbit.enabled = true;
});

// --- the session and its stream --------------------------------------------------------------
/** What the page shows: the character (bone rotations) or an example chain (joint values). */
interface Model {
  readonly root: THREE.Object3D;
  readonly effectors: readonly string[];
  readonly chain: Chain;
  readonly sessionOptions: CreateSessionOptions;
  show(result: CompactFrameResult): void;
  worldPosition(name: string): THREE.Vector3;
  target(name: string, world: THREE.Vector3): Target;
}

function characterModel(character: Character): Model {
  return {
    root: character.root,
    effectors: EFFECTORS,
    chain: character.chain(),
    sessionOptions: {
      conventions: { preset: "threejs" },
      bones: { local_rotations: true },
      // No pull towards the middle of the joint ranges: a limb at rest stays at rest.
      options: { posture_weight: 0 },
    },
    show: (result) => {
      if (result.bones?.local) character.apply(result.bones.local);
    },
    worldPosition: (name) => character.worldPosition(name),
    target: (name, world) => {
      const target: Target & { pole?: { position: { x: number; y: number; z: number }; bone: string } } = {
        effector: name,
        position: { x: world.x, y: world.y, z: world.z },
      };
      const pole = handles.get(POLE)?.position;
      if (polesSupported && name === "foot_L" && pole !== undefined) {
        target.pole = { position: { x: pole.x, y: pole.y, z: pole.z }, bone: POLE_BONE };
      }
      return target;
    },
  };
}

function exampleModel(example: ExampleChain): Model {
  return {
    root: example.root,
    effectors: example.effectors,
    chain: { format: "example", name: example.name as "panda_arm" },
    sessionOptions: {},
    show: (result) => example.setQ(result.q, session.dof),
    worldPosition: (name) => example.worldPosition(name),
    target: (name, world) => example.target(name, world),
  };
}

let character: Character;
let examples = new Map<string, ExampleChain>();
let model: Model;
let client: Client;
let apiKeyInUse: string | undefined;
let session: SessionCreated;
let previousQ: number[] | null = null;
let newest: CompactFrameResult | null = null; // the newest answer, until it is drawn
const readout = new Readout();
const solveRate = new RateMeter();
const drawRate = new RateMeter();

function apiKey(): Promise<string> {
  const form = document.getElementById("api-key") as HTMLFormElement;
  const input = document.getElementById("api-key-input") as HTMLInputElement;
  form.hidden = false;
  readout.status("this server needs an API key");
  return new Promise((resolve) => {
    form.addEventListener(
      "submit",
      (event) => {
        event.preventDefault();
        form.hidden = true;
        sessionStorage.setItem(API_KEY_STORAGE, input.value);
        resolve(input.value);
      },
      { once: true },
    );
  });
}

async function createSession(): Promise<void> {
  let key = sessionStorage.getItem(API_KEY_STORAGE) ?? undefined;
  for (;;) {
    client = new Client(window.location.origin + root, key === undefined ? {} : { apiKey: key });
    try {
      session = await client.createSession(model.chain, model.sessionOptions);
      apiKeyInUse = key;
      return;
    } catch (error) {
      if (!(error instanceof AuthError)) throw error;
      sessionStorage.removeItem(API_KEY_STORAGE);
      key = await apiKey();
    }
  }
}

// --- the solve worker ------------------------------------------------------------------------
const worker = new Worker(`${assets}/demo-worker.js`, { type: "module" });
// Bumped by every change of socket: what the worker says about an older one (an answer
// still on its way, an error) is dropped.
let generation = 0;
let streamOpen = false;
let counters: LoopCounters = { ticks: 0, held: 0, missed: 0, inFlight: 0, reconnects: 0 };
let countersAtReset = { held: 0, missed: 0 };
let pendingClip: { resolve: (clip: FrameResults<CompactFrameResult>) => void; reject: (e: Error) => void } | null = null;

function toWorker(message: ToWorker): void {
  worker.postMessage(message);
}

worker.onmessage = (event: MessageEvent<FromWorker>) => {
  const message = event.data;
  if (message.generation !== generation) return; // about a socket the page has since replaced
  switch (message.kind) {
    case "opened":
      streamOpen = true;
      readout.status(`solving (${state.encoding}${state.compact ? ", compact" : ""})`);
      break;
    case "answer":
      answeredSinceRecovery = true;
      answered(message);
      break;
    case "clip":
      pendingClip?.resolve(message.clip);
      pendingClip = null;
      break;
    case "error":
      if (message.closed) streamOpen = false;
      pendingClip?.reject(new Error(message.message));
      pendingClip = null;
      reportError(message.message);
      // The session is gone (a server restarted with sessions in memory): a new one for
      // the model on show, once until an answer comes on it (a session lost again
      // before that, by a balancer without a shared store, say, leaves the error on
      // screen) and at most one per RECOVERY_SPACING_MS.
      if (message.gone && !recovering && answeredSinceRecovery) {
        recovering = true;
        answeredSinceRecovery = false;
        void recoverSession()
          .catch(reportError)
          .finally(() => {
            recovering = false;
          });
      }
      break;
  }
};
worker.onerror = (event) => reportError(`solve worker: ${event.message}`);

function dropStream(): void {
  generation += 1;
  streamOpen = false;
  newest = null;
  counters = { ticks: 0, held: 0, missed: 0, inFlight: 0, reconnects: 0 };
  countersAtReset = { held: 0, missed: 0 };
  toWorker({ kind: "close" });
}

function openStream(): void {
  dropStream();
  postTargets();
  toWorker({
    kind: "open",
    generation,
    baseUrl: window.location.origin + root,
    apiKey: apiKeyInUse,
    session,
    encoding: state.encoding,
    compact: state.compact,
  });
}

function targets(): Target[] {
  return model.effectors.map((name) => model.target(name, handles.get(name)!.position));
}

/** Give the worker the targets as the handles stand (it sends them at its next ticks). */
function postTargets(): void {
  toWorker({ kind: "targets", targets: targets() });
}

function show(result: CompactFrameResult): void {
  model.show(result);
  needsRender = true;
  for (const name of model.effectors) state.effectors[name] = model.worldPosition(name).toArray() as Vec;
  state.poleBone = handles.has(POLE) ? (character.worldPosition(POLE_BONE).toArray() as Vec) : null;
}

/** An answer from the worker: counted now, drawn at the next animation frame. */
function answered(answer: Extract<FromWorker, { kind: "answer" }>): void {
  const { result, roundTripMs } = answer;
  const step = largestStep(previousQ, result.q);
  previousQ = result.q;
  if (!replaying) newest = result; // a later answer replaces it before it is drawn
  counters = answer.counters;
  solveRate.mark(answer.answeredAtMs);
  readout.frame(result, roundTripMs, step);
  state.frames = readout.frames;
  state.solved = readout.solved;
  state.roundTripsMs = readout.roundTripsMs;
  state.samples.roundTripMs.push(roundTripMs);
  state.samples.serverUs.push(result.server_us);
  state.samples.solveUs.push(result.solve_us);
  if (result.success) state.samples.solved += 1;
  state.last = {
    termination: result.termination,
    solve_us: result.solve_us,
    server_us: result.server_us,
    round_trip_ms: roundTripMs,
    largest_step_rad: step,
  };
  if (recording !== null) {
    recording.frames.push({ targets: answer.sent });
    recording.tracked.push(result.q);
    if (recording.frames.length >= MAX_RECORDED_FRAMES) stopRecording();
  }
}

// --- recording and planned replay ----------------------------------------------------------------
let recording: { frames: Frame[]; tracked: number[][]; startQ: number[] } | null = null;
let recorded: { frames: Frame[]; tracked: number[][]; startQ: number[] } | null = null;
let replaying = false;
const recordButton = document.getElementById("record") as HTMLButtonElement;
const replayButton = document.getElementById("replay") as HTMLButtonElement;

recordButton.addEventListener("click", () => {
  if (recording === null) {
    recording = { frames: [], tracked: [], startQ: previousQ ?? [] };
    recordButton.textContent = "Stop recording";
    replayButton.disabled = true;
  } else {
    stopRecording();
  }
});

function stopRecording(): void {
  if (recording !== null && recording.frames.length > 1) recorded = recording;
  recording = null;
  recordButton.textContent = "Record a drag";
  replayButton.disabled = recorded === null;
}

replayButton.addEventListener("click", () => {
  void replayPlanned().catch(reportError);
});

async function replayPlanned(): Promise<void> {
  if (recorded === null || !streamOpen) return;
  const { frames, startQ } = recorded;
  replaying = true;
  replayButton.disabled = true;
  readout.status("planning the recorded clip");
  try {
    // On the worker's socket, once its frames in flight are answered, from the pose the
    // recording started at.
    const clip = await new Promise<FrameResults<CompactFrameResult>>((resolve, reject) => {
      pendingClip = { resolve, reject };
      toWorker({ kind: "clip", frames, startQ });
    });
    const planned = clip.results.map((r) => r.q);
    drawPaths(document.getElementById("paths") as HTMLCanvasElement, recorded.tracked, planned);
    const plan = clip.plan;
    state.clip = {
      recorded: recorded.frames.length,
      planned: planned.length,
      largest_step_rad: plan?.largest_step_rad ?? Number.NaN,
      tracked_largest_step_rad: plan?.tracked_largest_step_rad ?? Number.NaN,
    };
    document.getElementById("clip-summary")!.textContent =
      `${planned.length} frames; largest joint step planned ${state.clip.largest_step_rad.toFixed(3)} rad, ` +
      `tracked ${state.clip.tracked_largest_step_rad.toFixed(3)} rad (solid: tracked live, dashed: planned)`;
    for (const result of clip.results) {
      show(result);
      await new Promise((r) => requestAnimationFrame(r));
    }
    previousQ = planned[planned.length - 1] ?? previousQ;
  } finally {
    replaying = false;
    replayButton.disabled = false;
    readout.status(`solving (${state.encoding}${state.compact ? ", compact" : ""})`);
  }
}

// --- drawing (animation frames) -------------------------------------------------------------
function reportError(error: unknown): void {
  const text = error instanceof Error ? error.message : String(error);
  state.errors.push(text);
  readout.status(`error: ${text}`);
}

// The scripted drag (`startMotion`) in scene coordinates, and where each handle rests.
let motion: Motion | null = null;
const rests = new Map<string, THREE.Vector3>();

/** One animation frame: move the scripted handles, apply the newest answer, draw if
 * anything moved, update the readout. */
function draw(now: number): void {
  requestAnimationFrame(draw); // first: a throw below must not end the loop
  if (motion !== null) {
    const at = absoluteNow();
    for (const [name, rest] of rests) {
      const offset = motionOffset(motion, name, at);
      if (offset !== null) handles.get(name)?.position.copy(rest).add(new THREE.Vector3(...offset));
    }
    needsRender = true;
  }
  if (newest !== null) {
    show(newest);
    newest = null;
  }
  for (const [name, handle] of handles) state.targets[name] = handle.position.toArray() as Vec;
  if (needsRender) {
    renderer.render(scene, camera);
    drawRate.mark(performance.timeOrigin + now);
    state.samples.drawn += 1;
  }
  needsRender = false;
  state.socket = { open: streamOpen, inFlight: counters.inFlight, reconnects: counters.reconnects, ticks: counters.ticks };
  state.samples.held = counters.held - countersAtReset.held;
  state.samples.missed = counters.missed - countersAtReset.missed;
  const at = absoluteNow();
  state.rates = { solvesPerS: solveRate.perSecond(at), drawnPerS: drawRate.perSecond(at) };
  readout.render(state.rates.solvesPerS, state.rates.drawnPerS);
}

function wireSwitches(): void {
  for (const radio of document.querySelectorAll<HTMLInputElement>("input[name=encoding]")) {
    radio.addEventListener("change", () => {
      state.encoding = radio.value as Encoding;
      openStream();
    });
  }
  const compact = document.getElementById("compact") as HTMLInputElement;
  compact.addEventListener("change", () => {
    state.compact = compact.checked;
    openStream();
  });
  const select = document.getElementById("model") as HTMLSelectElement;
  select.add(new Option("stick figure (character.gltf)", "character"));
  for (const name of examples.keys()) select.add(new Option(`example chain: ${name}`, name));
  select.addEventListener("change", () => {
    userSwitches += 1;
    void showModel(select.value, userSwitches).catch(reportError);
  });
}

/** Screen position [CSS px] of a handle, for a test's mouse. */
function screenOf(name: string): { x: number; y: number } {
  const p = handles.get(name)!.position.clone().project(camera);
  const rect = renderer.domElement.getBoundingClientRect();
  return { x: rect.left + ((p.x + 1) / 2) * rect.width, y: rect.top + ((1 - p.y) / 2) * rect.height };
}

const UP = new THREE.Vector3(0, 1, 0);
const FORWARD = new THREE.Vector3(0, 0, 1);

/** Move the targets along circles (the browser benchmark's steady drag): up from where
 * they rest (limbs hang straight: nothing below is in reach) and forward, the right ones
 * half a turn behind. The worker moves the targets it sends; the page, the handles. */
function startMotion(radiusM = 0.12, hz = 0.5): void {
  const startMs = absoluteNow();
  const inScene: Motion = { startMs, radiusM, hz, circles: {} };
  const sent: Motion = { startMs, radiusM, hz, circles: {} };
  // A direction in the frame targets are sent in (the example chains' is not the scene's).
  const along = (name: string, rest: THREE.Vector3, direction: THREE.Vector3): Vec => {
    const from = model.target(name, rest).position!;
    const to = model.target(name, rest.clone().add(direction)).position!;
    return [to.x - from.x, to.y - from.y, to.z - from.z];
  };
  rests.clear();
  for (const name of model.effectors) {
    const rest = handles.get(name)!.position.clone();
    rests.set(name, rest);
    const phase = name.endsWith("R") ? Math.PI : 0;
    inScene.circles[name] = { up: UP.toArray(), forward: FORWARD.toArray(), phase };
    sent.circles[name] = { up: along(name, rest, UP), forward: along(name, rest, FORWARD), phase };
  }
  postTargets(); // the rests, which the worker moves
  motion = inScene;
  toWorker({ kind: "motion", motion: sent });
}

function stopMotion(): void {
  motion = null;
  toWorker({ kind: "motion", motion: null });
  postTargets();
}

function resetStats(): void {
  readout.reset();
  state.frames = 0;
  state.solved = 0;
  state.roundTripsMs = readout.roundTripsMs;
  state.samples = emptySamples();
  countersAtReset = { held: counters.held, missed: counters.missed };
}

const HANDLE_PALETTE = [0xe6194b, 0x4363d8, 0xf58231, 0x3cb44b];

function ignoreNotFound(error: unknown): void {
  if (!(error instanceof NotFound)) throw error;
}

// A new session is being made after the old one was gone (one recovery at a time), and
// whether an answer came since the last one (no second recovery before it does).
let recovering = false;
let answeredSinceRecovery = true;
// Model switches, the user's and a recovery's, one after another (each awaits the server
// several times and rebuilds the scene); `userSwitches` counts the user's.
let switches: Promise<unknown> = Promise.resolve();
let userSwitches = 0;

function serially<T>(task: () => Promise<T>): Promise<T> {
  const run = switches.then(task, task);
  switches = run.catch(() => undefined);
  return run;
}
// How long a switch waits for a restarted server to be ready (it answers not_ready,
// with Retry-After, while it loads its compiled solver).
const RECOVERY_ATTEMPTS = 30;
// A server that keeps losing sessions gets at most one new one from this page this often.
const RECOVERY_SPACING_MS = 5_000;
let lastRecoveryMs = -Infinity;

/** The model again on a new session, after the server lost the old one. */
async function recoverSession(): Promise<void> {
  const asked = userSwitches;
  const waitMs = lastRecoveryMs + RECOVERY_SPACING_MS - performance.now();
  if (waitMs > 0) {
    readout.status(`the session is gone: a new one in ${(waitMs / 1000).toFixed(1)} s`);
    await new Promise((resolve) => setTimeout(resolve, waitMs));
  }
  lastRecoveryMs = performance.now();
  readout.status("the session is gone: creating a new one");
  await showModel(state.model, asked);
}

/** `switchModel(name)` in turn with the other switches; a server still warming up (a
 * restart: not_ready with Retry-After) is waited for, unless the user picks another
 * model meanwhile (`asked`: the user's switches so far). */
async function showModel(name: string, asked: number): Promise<void> {
  for (let attempt = 1; ; attempt++) {
    if (userSwitches !== asked) return; // a newer pick stands
    try {
      await serially(() => switchModel(name));
      return;
    } catch (error) {
      if (!(error instanceof RetryLater) || attempt >= RECOVERY_ATTEMPTS) throw error;
      const waitS = Math.min(Math.max(error.retryAfterS ?? 1, 0.5), 5);
      readout.status(`the server is not ready (${error.code}): trying again in ${waitS} s`);
      await new Promise((resolve) => setTimeout(resolve, 1000 * waitS));
    }
  }
}

/** Show `name` (the character or an example chain) on a session of its own. */
async function switchModel(name: string): Promise<void> {
  dropStream();
  if (motion !== null) stopMotion();
  if (model !== undefined) scene.remove(model.root);
  for (const handle of handles.values()) scene.remove(handle);
  handles.clear();
  // The page's previous session; one the server no longer has (restarted, expired) is fine.
  if (session !== undefined) await client.deleteSession(session).catch(ignoreNotFound);
  previousQ = null;
  recording = null;
  recorded = null;
  recordButton.textContent = "Record a drag";
  replayButton.disabled = true;
  const example = examples.get(name);
  model = example === undefined ? characterModel(character) : exampleModel(example);
  scene.add(model.root);
  readout.status("creating a session");
  await createSession();
  if (example === undefined) {
    // The rest pose: every DOF 0 (a session starts in the middle of the joint ranges).
    await client.setPose(session, { q: new Array<number>(session.n_dof).fill(0) });
  } else {
    example.setQ(session.pose.q, session.dof);
    example.holdOrientations();
  }
  model.effectors.forEach((effector, i) => {
    const colour = HANDLE_COLOURS[effector as EffectorName] ?? HANDLE_PALETTE[i % HANDLE_PALETTE.length]!;
    addHandle(effector, colour, model.worldPosition(effector));
  });
  if (example === undefined) {
    const knee = character.worldPosition("shin_L");
    addHandle(POLE, 0x9aa0a6, knee.add(new THREE.Vector3(0, 0, 0.4)), 0.5);
    document.getElementById("r-pole")!.textContent = polesSupported
      ? `sent with foot_L (bone ${POLE_BONE})`
      : "this server has no pole field: shown, not sent";
  } else {
    document.getElementById("r-pole")!.textContent = "";
  }
  state.effectors = {};
  state.poleBone = null;
  state.targets = {};
  state.model = name;
  readout.reset();
  needsRender = true;
  openStream();
}

async function main(): Promise<void> {
  const setEncoding = (encoding: Encoding, compact: boolean): void => {
    (document.querySelector(`input[name=encoding][value=${encoding}]`) as HTMLInputElement).click();
    const box = document.getElementById("compact") as HTMLInputElement;
    if (box.checked !== compact) box.click();
  };
  Object.assign(window, {
    ikDemo: { state, screenOf, startMotion, stopMotion, resetStats, setEncoding },
  });
  character = await Character.load(`${assets}/character.gltf`);
  examples = await ExampleChain.load(`${root}/demo/examples.json`);
  polesSupported = await serverHasPoles();
  state.poles = polesSupported;
  wireSwitches();
  await serially(() => switchModel("character"));
  state.ready = true;
  requestAnimationFrame(draw);
}

main().catch(reportError);
