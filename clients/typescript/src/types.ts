/**
 * What the service takes and gives, typed after its OpenAPI schema (`/openapi.json`):
 * each interface carries the name of the schema component it mirrors, and
 * test/client.test.ts checks their property names against a live server's schema.
 */

import type { Chain } from "./chains.js";

/** How the optimizer's last pass ended (docs/api.md, Termination codes). */
export const Termination = {
  GoalReached: "goal_reached",
  Gtol: "gtol",
  StepSmall: "step_small",
  Stalled: "stalled",
  LineSearchFailed: "line_search_failed",
  MaxIter: "max_iter",
  MaxFev: "max_fev",
  Deadline: "deadline",
  Nonfinite: "nonfinite",
} as const;
export type Termination = (typeof Termination)[keyof typeof Termination];

/** Whether a frame reached its targets, and if not, why. */
export const Status = {
  Solved: "solved",
  NotReached: "not_reached",
  BudgetExhausted: "budget_exhausted",
  Nonfinite: "nonfinite",
} as const;
export type Status = (typeof Status)[keyof typeof Status];

export type EffectorMode = "position" | "pose" | "aim";

/** A session's continuity policy: `smooth` never steps a joint more than
 * `max_joint_step_rad` per frame; `reach` solves every frame, jumping if it must. */
export const Continuity = { Smooth: "smooth", Reach: "reach" } as const;
export type Continuity = (typeof Continuity)[keyof typeof Continuity];

/** How a stream's messages travel: JSON text or MessagePack binary messages. */
export const Encoding = { Json: "json", MessagePack: "msgpack" } as const;
export type Encoding = (typeof Encoding)[keyof typeof Encoding];

// --- requests ------------------------------------------------------------------------------
// The types a game fills every frame (Target, Pole, Frame, BoneOutput) take `undefined`
// for an optional field, as if it were left out (it is not sent, in either encoding):
// under `exactOptionalPropertyTypes`, `{ position_weight: settings.weight }` compiles.
/** Schema `Vec3`: a point [m] or a direction. */
export interface Vec3 {
  x: number;
  y: number;
  z: number;
}

/** Schema `Quaternion`: a unit quaternion, w the scalar part. */
export interface Quaternion {
  w: number;
  x: number;
  y: number;
  z: number;
}

/**
 * Schema `Pole`: a point the knee or elbow bone bends towards (session conventions);
 * `bone` names it (default: the middle of the limb). Soft: never fails a reachable frame.
 */
export interface Pole {
  position: Vec3;
  bone?: string | null | undefined;
}

/**
 * Schema `Target`: what one effector should reach. `position_weight` and
 * `rotation_weight` in [0, 1] blend IK in and out (0 free, 1 exact, in between a soft
 * pull that never fails the frame); `pole` chooses where the limb bends.
 */
export interface Target {
  effector: string;
  position?: Vec3 | null | undefined;
  orientation?: Quaternion | null | undefined;
  direction?: Vec3 | null | undefined;
  position_weight?: number | undefined;
  rotation_weight?: number | undefined;
  pole?: Pole | null | undefined;
}

/** Schema `Frame`: one frame of a clip; `id` is echoed in its result. */
export interface Frame {
  id?: number | null | undefined;
  targets: Target[];
  /** Bone output for this frame (skeleton chains; default: the session's). */
  bones?: BoneOutput | null | undefined;
  /** The animated pose this frame starts from (IK on top of an animation): as `setPose`
   * then the frame, in one step; not in a planned clip. */
  pose?: PoseIn | null | undefined;
}

/** Schema `BatchFrame`: one session's frame in a batch, with that session's id and token. */
export interface BatchFrame extends Frame {
  session: string;
  token: string;
}

/** Schema `BoneOutput`: which bone data an answer carries (docs/engines.md). */
export interface BoneOutput {
  local_rotations?: boolean | undefined;
  world?: string[] | undefined;
}

/** Schema `Conventions`: the client's coordinates (a preset, or up / handedness / unit). */
export interface Conventions {
  preset?: "unity" | "unreal" | "godot" | "gltf" | "threejs" | "ros" | null;
  up?: "y" | "z" | null;
  handedness?: "right" | "left" | null;
  unit?: "m" | "cm" | null;
}

/** Schema `ConventionsOut`: the conventions a session speaks. */
export interface ConventionsOut {
  up: "y" | "z";
  handedness: "right" | "left";
  unit_m: number;
}

/** Schema `BonesOut`: bone local rotations and world transforms, when asked for. */
export interface BonesOut {
  local?: Record<string, Quaternion> | null;
  world?: Record<string, { position: Vec3; rotation: Quaternion }> | null;
}

/** Schema `EffectorPoseOut`: an effector's world pose in the session's conventions (the
 * tip frame its targets are compared with); `direction`: where an aim effector's aim axis
 * points (null for position and pose effectors). */
export interface EffectorPoseOut {
  /** As targets address it (`effector`). */
  name: string;
  position: Vec3;
  orientation: Quaternion;
  direction?: Vec3 | null;
}

/** Schema `FkResult`: where a pose puts the chain (`POST .../fk`): every effector's world
 * pose and, on skeleton chains, the bone data asked for. */
export interface FkResult {
  /** The pose used, in DOF order. */
  q: number[];
  /** Every effector, in the chain's order. */
  effectors: EffectorPoseOut[];
  /** Skeleton chains (gltf, bvh) only; null on chains without bones. */
  bones: BonesOut | null;
  /** The DOFs the pose sent had outside their limits (set to the nearest limit in `q`). */
  clipped: string[];
}

/** An `fk` answer as the client hands it on, over HTTP or the stream alike: `bones`
 * null where the server sends none, `effectors` and `clipped` empty from a server older
 * than them. */
export function fkResultFrom(json: {
  q: number[];
  effectors?: EffectorPoseOut[];
  bones?: BonesOut | null;
  clipped?: string[];
}): FkResult {
  return { q: json.q, effectors: json.effectors ?? [], bones: json.bones ?? null, clipped: json.clipped ?? [] };
}

/** Schema `PoseIn`: exactly one of `q` (every DOF, in order) or `joints` (some, by name). */
export type PoseIn =
  | { q: number[]; joints?: null }
  | { joints: Record<string, number>; q?: null };

/** Schema `OptionsPatch`: solver options to change (`SolverOptions`'s); left out: unchanged. */
export type OptionsPatch = { [Option in keyof SolverOptions]?: SolverOptions[Option] | null };

/** Schema `SessionCreate`. */
export interface SessionCreate {
  chain: Chain;
  options?: OptionsPatch | null;
  initial_pose?: PoseIn | null;
  conventions?: Conventions | null;
  bones?: BoneOutput | null;
}

/** Schema `ClipRequest`. */
export interface ClipRequest {
  frames: Frame[];
  plan?: boolean;
}

/** Schema `SolveRequest`: a stateless one-shot solve. */
export interface SolveRequest {
  chain: Chain;
  targets: Target[];
  seed?: PoseIn | null;
  options?: OptionsPatch | null;
  id?: number | null;
  conventions?: Conventions | null;
  bones?: BoneOutput | null;
}

// --- answers -------------------------------------------------------------------------------
/** Schema `EffectorErrorOut`: the pose error of one targeted effector. */
export interface EffectorErrorOut {
  name: string;
  position_error_m: number | null;
  rotation_error_rad: number | null;
  within_tolerance: boolean;
}

/** Schema `CompactFrameResult`: a result without joints by name or per-effector errors. */
export interface CompactFrameResult {
  id: number | null;
  success: boolean;
  status: Status;
  termination: Termination;
  q: number[];
  iterations: number;
  function_evals: number;
  passes: number;
  restarts: number;
  solve_us: number;
  server_us: number;
  /** Largest joint step from the session's previous answer; null for one-shot solves. */
  largest_step_rad: number | null;
  /** `largest_step_rad` is over the session's `max_joint_step_rad` (a jump). */
  jumped: boolean;
  bones?: BonesOut | null;
}

/** Schema `FrameResult`: the answer to one frame (not reaching it is `success: false`). */
export interface FrameResult extends CompactFrameResult {
  joints: Record<string, number>;
  effectors: EffectorErrorOut[];
}

/** Schema `PlanSummary`: what planning a clip achieved. */
export interface PlanSummary {
  largest_step_rad: number;
  tracked_largest_step_rad: number;
  candidates: number;
  plan_us: number;
}

/** Schemas `FrameResults` / `CompactFrameResults`: one result per frame, in order. */
export interface FrameResults<R = FrameResult> {
  results: R[];
  plan: PlanSummary | null;
}

/** Schema `Pose`. */
export interface Pose {
  q: number[];
  joints: Record<string, number>;
  /** The DOFs whose value the client sent (`setPose`, `initialPose`) was outside the
   * limits and was set to the nearest limit; empty otherwise. */
  clipped: string[];
}

/** Schema `DofInfo`: one degree of freedom; null limits are unbounded. */
export interface DofInfo {
  name: string;
  lower: number | null;
  upper: number | null;
}

/** Schema `EffectorInfo`. */
export interface EffectorInfo {
  name: string;
  mode: EffectorMode;
}

/** Schema `FollowerInfo`: a mimic joint, `multiplier * leader + offset`; not a DOF (not in `q`),
 * its value is in results' `joints`. */
export interface FollowerInfo {
  name: string;
  leader: string;
  multiplier: number;
  offset: number;
}

/** Schema `ModelWarning`: the chain's file read by a convention or a default. */
export interface ModelWarning {
  code:
    | "unlimited_by_convention"
    | "default_limit"
    | "mimic_narrows_leader"
    | "mimic_limits_ignored"
    | "unlikely_units";
  joint: string;
  field: string;
  message: string;
}

/** Schema `SolverOptions`: the effective options of a session. */
export interface SolverOptions {
  position_tolerance_m: number;
  rotation_tolerance_rad: number;
  time_budget_us: number;
  max_iter: number;
  max_restarts: number;
  restart_radius_rad: number;
  max_step_rad: number;
  posture_weight: number;
  limit_weight: number;
  limit_margin: number;
  continuity: Continuity;
  max_joint_step_rad: number;
}

/** What `SessionCreated` and `SessionInfo` both carry: the chain's summary, the options,
 * the pose and the conventions. */
export interface SessionSummary {
  id: string;
  n_dof: number;
  dof: DofInfo[];
  effectors: EffectorInfo[];
  followers: FollowerInfo[];
  warnings: ModelWarning[];
  options: SolverOptions;
  pose: Pose;
  idle_ttl_s: number;
  conventions: ConventionsOut;
}

/** Schema `SessionCreated`: `token` is shown only here. */
export interface SessionCreated extends SessionSummary {
  token: string;
}

/** Schema `SessionCounters`. */
export interface SessionCounters {
  frames: number;
  solved: number;
  not_solved: number;
}

/** Schema `SessionInfo`. */
export interface SessionInfo extends SessionSummary {
  counters: SessionCounters;
  created_at: number;
  idle_s: number;
  websockets: number;
}

/** Schema `ErrorBody`: every HTTP error. */
export interface ErrorBody {
  detail: string | Array<Record<string, unknown>>;
  code: string;
  field?: string | null;
}

/** Schema `ErrorPayload`: an error in an answer (a WebSocket message's, a batch entry's). */
export interface ErrorPayload {
  code: string;
  message: string;
  field?: string | null;
  retry_after_s?: number | null;
}

/** Schema `BatchEntryResult`: a batch entry's result. */
export interface BatchEntryResult<R = FrameResult> {
  session: string;
  id: number | null;
  success: boolean;
  result: R;
}

/** Schema `BatchEntryError`: a batch entry's own error (the other entries were answered). */
export interface BatchEntryError {
  session: string | null;
  id: number | null;
  success: false;
  error: ErrorPayload;
}

/** One entry of a batch's answer: `"result" in entry` or `"error" in entry` says which. */
export type BatchEntry<R = FrameResult> = BatchEntryResult<R> | BatchEntryError;

/** Schema `BatchResults`: one entry per frame sent, in order. */
export interface BatchResults<R = FrameResult> {
  results: BatchEntry<R>[];
}

/** What a call on a session needs: a `SessionCreated`, or any object with `id` and `token`. */
export interface SessionRef {
  id: string;
  token: string;
}

// --- stream answers (docs/websocket.md) -------------------------------------------------------
/** A `result` message: the answer to the stream's frame `id`. */
export interface FrameAnswer<R = FrameResult> {
  type: "result";
  id: number;
  /** The frame's success (as `result.success`). */
  success: boolean;
  result: R;
}

/** A `clip_result` message: the answer to the stream's clip `id`. */
export interface ClipAnswer<R = FrameResult> {
  type: "clip_result";
  id: number;
  success: boolean;
  results: R[];
  plan: PlanSummary | null;
}

/** A `pong` message: the answer to the stream's ping `id`. */
export interface Pong {
  type: "pong";
  id: number;
}

/** A `batch_result` message: the answer to the stream's batch `id`, one entry per frame
 * sent, in order, each a result or that entry's own error. */
export interface BatchAnswer<R = FrameResult> {
  type: "batch_result";
  id: number;
  /** Every entry's success. */
  success: boolean;
  results: BatchEntry<R>[];
}

/** An `fk_result` message: the answer to the stream's fk `id`. */
export interface FkAnswer {
  type: "fk_result";
  id: number;
  result: FkResult;
}

export type Answer<R = FrameResult> = FrameAnswer<R> | ClipAnswer<R> | BatchAnswer<R> | FkAnswer | Pong;
