/**
 * /demo: a character whose hands and feet follow draggable targets, solved by the service
 * over a session's WebSocket (the TypeScript client's `Stream`), one frame per animation
 * frame while the socket is free.
 *
 * `window.ikDemo` exposes the page's state for tests and the browser benchmark
 * (tests/live/test_demo_browser.py, bench/demo_browser.py): answered frames, round
 * trips, where the effectors are in the scene graph, and the handles' screen positions.
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
  type SessionCreated,
  type Stream,
  StreamClosed,
  type Target,
} from "../../typescript/src/index.js";
import { Character, EFFECTORS, type EffectorName } from "./character.js";
import { ExampleChain } from "./examples.js";
import { drawPaths } from "./paths.js";
import { Readout, largestStep } from "./readout.js";

const API_KEY_STORAGE = "ik-demo-api-key";
const MAX_RECORDED_FRAMES = 600; // the server's default IK_MAX_FRAMES_PER_REQUEST
const HANDLE_COLOURS: Record<EffectorName, number> = {
  hand_L: 0xe6194b,
  hand_R: 0x4363d8,
  foot_L: 0xf58231,
  foot_R: 0x3cb44b,
};

type Vec = [number, number, number];

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
  /** Every frame since the last `resetStats()`: round trip [ms], server_us, solve_us, success. */
  samples: { roundTripMs: number[]; serverUs: number[]; solveUs: number[]; solved: number; since: number };
  last: { termination: string; solve_us: number; server_us: number; round_trip_ms: number; largest_step_rad: number } | null;
  /** Effector bones' world positions, read off the scene graph after applying the answer. */
  effectors: Record<string, Vec>;
  targets: Record<string, Vec>;
  errors: string[];
  /** The loop's view of its socket: a frame in flight, reconnects, animation frames. */
  socket: { open: boolean; inFlight: boolean; reconnects: number; ticks: number };
  clip: { recorded: number; planned: number; largest_step_rad: number; tracked_largest_step_rad: number } | null;
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
  samples: { roundTripMs: [], serverUs: [], solveUs: [], solved: 0, since: performance.now() },
  last: null,
  effectors: {},
  targets: {},
  errors: [],
  socket: { open: false, inFlight: false, reconnects: 0, ticks: 0 },
  clip: null,
};

// --- scene ---------------------------------------------------------------------------------
const view = document.getElementById("view")!;
// No antialiasing, and a frame is drawn only when something moved: without a GPU
// (headless Chromium renders WebGL in software) drawing every animation frame would take
// the main thread from the socket.
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

// Pole targets (which way a knee or elbow points) are being added to the API on another
// branch; until the field exists this handle is drawn and can be dragged, but it is not
// sent (the readout says so).
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
let session: SessionCreated;
let stream: Stream<CompactFrameResult> | null = null;
let inFlight = false;
let previousQ: number[] | null = null;
const readout = new Readout();

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
      return;
    } catch (error) {
      if (!(error instanceof AuthError)) throw error;
      sessionStorage.removeItem(API_KEY_STORAGE);
      key = await apiKey();
    }
  }
}

// Bumped by every change of socket: an open that finishes after a newer one started (two
// switches flipped at once) closes its socket instead of replacing the newer one, which
// would leave a frame in flight on a socket nobody reads.
let streamGeneration = 0;

function dropStream(): void {
  streamGeneration += 1;
  const old = stream;
  stream = null;
  old?.close();
  inFlight = false;
}

async function openStream(): Promise<void> {
  dropStream();
  const generation = streamGeneration;
  const opened = await client.stream(session, { encoding: state.encoding, compact: state.compact });
  if (generation !== streamGeneration) {
    opened.close();
    return;
  }
  stream = opened;
  inFlight = false;
  readout.status(`solving (${state.encoding}${state.compact ? ", compact" : ""})`);
}

function targets(): Target[] {
  return model.effectors.map((name) => model.target(name, handles.get(name)!.position));
}

function show(result: CompactFrameResult): void {
  model.show(result);
  needsRender = true;
  for (const name of model.effectors) state.effectors[name] = model.worldPosition(name).toArray() as Vec;
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
  if (recorded === null || stream === null) return;
  replaying = true;
  replayButton.disabled = true;
  readout.status("planning the recorded clip");
  try {
    while (inFlight) await new Promise((r) => setTimeout(r, 5));
    // The plan starts where the recording started.
    await client.setPose(session, { q: recorded.startQ });
    const clip = await stream.clip(recorded.frames, { plan: true });
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

// --- the frame loop ------------------------------------------------------------------------
async function solveOnce(current: Stream<CompactFrameResult>): Promise<void> {
  const sent = targets();
  const started = performance.now();
  const result = await current.frame(sent);
  const roundTripMs = performance.now() - started;
  if (current !== stream) return; // answered on a socket the page has since replaced
  const step = largestStep(previousQ, result.q);
  previousQ = result.q;
  show(result);
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
    recording.frames.push({ targets: sent });
    recording.tracked.push(result.q);
    if (recording.frames.length >= MAX_RECORDED_FRAMES) stopRecording();
  }
}

function reportError(error: unknown): void {
  const text = error instanceof Error ? error.message : String(error);
  state.errors.push(text);
  readout.status(`error: ${text}`);
}

let motion: ((t: number) => void) | null = null;

function tick(now: number): void {
  requestAnimationFrame(tick); // first: a throw below must not end the loop
  motion?.(now / 1000);
  for (const [name, handle] of handles) state.targets[name] = handle.position.toArray() as Vec;
  state.socket = { open: stream !== null, inFlight, reconnects: stream?.reconnects ?? 0, ticks: state.socket.ticks + 1 };
  if (needsRender) renderer.render(scene, camera);
  needsRender = false;
  // Sent after drawing, so that the answer finds the main thread free (a frame drawn
  // after sending would sit between the answer's arrival and its handling).
  const current = stream;
  if (current !== null && !inFlight && !replaying) {
    inFlight = true;
    solveOnce(current)
      .catch((error: unknown) => {
        if (current !== stream) return;
        reportError(error);
        // The client has already tried to reconnect: this socket is over (a switch or a
        // reload opens a new one).
        if (error instanceof StreamClosed) stream = null;
      })
      .finally(() => {
        if (current === stream) inFlight = false;
      });
  }
}

function wireSwitches(): void {
  for (const radio of document.querySelectorAll<HTMLInputElement>("input[name=encoding]")) {
    radio.addEventListener("change", () => {
      state.encoding = radio.value as Encoding;
      void openStream().catch(reportError);
    });
  }
  const compact = document.getElementById("compact") as HTMLInputElement;
  compact.addEventListener("change", () => {
    state.compact = compact.checked;
    void openStream().catch(reportError);
  });
  const select = document.getElementById("model") as HTMLSelectElement;
  select.add(new Option("stick figure (character.gltf)", "character"));
  for (const name of examples.keys()) select.add(new Option(`example chain: ${name}`, name));
  select.addEventListener("change", () => void switchModel(select.value).catch(reportError));
}

/** Screen position [CSS px] of a handle, for a test's mouse. */
function screenOf(name: string): { x: number; y: number } {
  const p = handles.get(name)!.position.clone().project(camera);
  const rect = renderer.domElement.getBoundingClientRect();
  return { x: rect.left + ((p.x + 1) / 2) * rect.width, y: rect.top + ((1 - p.y) / 2) * rect.height };
}

/** Move the targets along circles (the browser benchmark's steady drag). */
function startMotion(radiusM = 0.12, hz = 0.5): void {
  const rest = new Map([...handles].map(([name, h]) => [name, h.position.clone()]));
  motion = (t) => {
    for (const name of model.effectors) {
      const r = rest.get(name)!;
      const phase = 2 * Math.PI * hz * t + (name.endsWith("R") ? Math.PI : 0);
      // Up from the rest pose (limbs hang straight: nothing below it is in reach).
      handles.get(name)!.position.set(r.x, r.y + radiusM * (1 - Math.cos(phase)), r.z + radiusM * Math.sin(phase));
    }
    needsRender = true;
  };
}

function resetStats(): void {
  readout.reset();
  state.frames = 0;
  state.solved = 0;
  state.roundTripsMs = readout.roundTripsMs;
  state.samples = { roundTripMs: [], serverUs: [], solveUs: [], solved: 0, since: performance.now() };
}

const HANDLE_PALETTE = [0xe6194b, 0x4363d8, 0xf58231, 0x3cb44b];

/** Show `name` (the character or an example chain) on a session of its own. */
async function switchModel(name: string): Promise<void> {
  dropStream();
  if (model !== undefined) scene.remove(model.root);
  for (const handle of handles.values()) scene.remove(handle);
  handles.clear();
  if (session !== undefined) await client.deleteSession(session); // the page's previous one
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
  state.targets = {};
  state.model = name;
  readout.reset();
  needsRender = true;
  await openStream();
}

async function main(): Promise<void> {
  const setEncoding = (encoding: Encoding, compact: boolean): void => {
    (document.querySelector(`input[name=encoding][value=${encoding}]`) as HTMLInputElement).click();
    const box = document.getElementById("compact") as HTMLInputElement;
    if (box.checked !== compact) box.click();
  };
  Object.assign(window, {
    ikDemo: { state, screenOf, startMotion, stopMotion: () => (motion = null), resetStats, setEncoding },
  });
  character = await Character.load(`${assets}/character.gltf`);
  examples = await ExampleChain.load(`${root}/demo/examples.json`);
  polesSupported = await serverHasPoles();
  state.poles = polesSupported;
  wireSwitches();
  await switchModel("character");
  state.ready = true;
  requestAnimationFrame(tick);
}

main().catch(reportError);
