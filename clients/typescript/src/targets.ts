/**
 * Targets as they are sent: every point and direction `{x, y, z}`, every rotation
 * `{w, x, y, z}`, as plain objects.
 *
 * `Vec3` and `Quaternion` are structural types, so an engine's own objects satisfy them:
 * three.js's `Vector3` and `Quaternion` have `x`, `y`, `z` (and `w`). They are not
 * written as such, though: JSON.stringify writes a `THREE.Quaternion` by its `toJSON`,
 * `[x, y, z, w]`, which the server refuses as ambiguous, and MessagePack by its own
 * fields (`_x`, `_y`, ...), which the server answered "orientation.w: Field required".
 * Here such an object (one with a number `x` that is not a plain object or an array) is
 * read by its properties; plain objects and arrays go as they are (the server says what
 * is wrong with them), and a frame without such objects is not copied.
 */

import type { Frame, Quaternion, Target, Vec3 } from "./types.js";

/** An object of a class (not a plain object or an array) with a number `x`. */
function isEngineObject(value: unknown): value is Record<"x" | "y" | "z" | "w", unknown> {
  if (value === null || typeof value !== "object" || Array.isArray(value)) return false;
  const prototype: unknown = Object.getPrototypeOf(value);
  return prototype !== Object.prototype && prototype !== null && typeof (value as { x?: unknown }).x === "number";
}

function vec3<V extends Vec3 | null | undefined>(value: V): V {
  return isEngineObject(value) ? ({ x: value.x, y: value.y, z: value.z } as V) : value;
}

function quaternion<Q extends Quaternion | null | undefined>(value: Q): Q {
  return isEngineObject(value) ? ({ w: value.w, x: value.x, y: value.y, z: value.z } as Q) : value;
}

/** `target` with its vectors and quaternion as plain objects (itself if they are). */
export function targetAsSent(target: Target): Target {
  const position = vec3(target.position);
  const orientation = quaternion(target.orientation);
  const direction = vec3(target.direction);
  const polePosition = vec3(target.pole?.position);
  if (
    position === target.position &&
    orientation === target.orientation &&
    direction === target.direction &&
    polePosition === target.pole?.position
  ) {
    return target;
  }
  const sent: Target = { ...target, position, orientation, direction }; // undefined: not sent
  if (target.pole && polePosition !== undefined) sent.pole = { ...target.pole, position: polePosition };
  return sent;
}

/** `targets` as sent (the same array when nothing needs reading). */
export function targetsAsSent(targets: Target[]): Target[] {
  const sent = targets.map(targetAsSent);
  return sent.every((target, i) => target === targets[i]) ? targets : sent;
}

/** `frames` with their targets as sent (a clip's, a batch's). */
export function framesAsSent<F extends Frame>(frames: F[]): F[] {
  return frames.map((frame) => {
    const targets = targetsAsSent(frame.targets);
    return targets === frame.targets ? frame : { ...frame, targets };
  });
}
